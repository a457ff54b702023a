"""Blenders' derived arrays mapped from shared files (engine/motion_space/derived.py)."""

import os

import numpy as np
import pytest

from engine.motion_space import Container, DerivedStore, MotionSpace, SourceClip, build_motion_space
from engine.synthetic import animate, build_body, gait

WEIGHTS = ([1.0, 0.0], [0.3, 0.7], [0.5, 0.5])
PHASES = (0.0, 0.37, 0.9)


def build(path, speeds):
    body = build_body(1000)
    clips = [SourceClip(f"gait_{v}", animate(body, gait(body.skeleton, v, cycles=2.0, fps=15)), 15, True)
             for v in speeds]
    build_motion_space(path, clips, body.F, name="gait", n_phases=6, epsilon=0.004, rest=body.V)
    return path


@pytest.fixture(scope="module")
def space_path(tmp_path_factory):
    return build(tmp_path_factory.mktemp("spaces") / "gait.mspace", (0.9, 2.6))


def blends(space):
    return {(mode, tuple(w), t): space.blend(w, t, mode)
            for mode in ("hybrid", "nonlinear") for w in WEIGHTS for t in PHASES}


def mapped(array):
    """True when ``array`` is a read-only view whose memory is a file mapping."""
    base = array
    while isinstance(base, np.ndarray) and base.base is not None:
        base = base.base
    return not array.flags.writeable and not array.flags.owndata and not isinstance(base, np.ndarray)


def test_blends_from_derived_files_are_the_same_bits(space_path, tmp_path):
    with MotionSpace.open(space_path) as plain:
        expected = blends(plain)
    store = DerivedStore(tmp_path / "derived")
    with MotionSpace.open(space_path, derived=store) as space:
        got = blends(space)
        hybrid = space.blender("hybrid")
        inner = space.blender("nonlinear").blender
        assert mapped(hybrid._flat_index) and all(mapped(row) for row in hybrid._dense.values())
        assert mapped(inner._q) and mapped(inner._s) and mapped(inner._d)
    for key, value in expected.items():
        np.testing.assert_array_equal(got[key], value, err_msg=str(key))
    names = sorted(p.name for p in (tmp_path / "derived").glob("*.mspace"))
    checksum = Container.open(space_path).checksum[:16]
    assert names == [f"gait.{checksum}.hybrid.mspace", f"gait.{checksum}.nonlinear.mspace"]


def test_a_second_opening_maps_the_same_file_without_building(space_path, tmp_path):
    store = DerivedStore(tmp_path / "derived")
    with MotionSpace.open(space_path, derived=store) as first:
        first.blender("nonlinear")
    path = next((tmp_path / "derived").glob("*.nonlinear.mspace"))
    stamp = os.stat(path).st_ino, os.stat(path).st_mtime_ns

    def refuse():
        raise AssertionError("built again")

    with Container.open(space_path) as container:
        layout = store.load(container, "nonlinear", {"version": 1}, refuse)
        assert layout.path == path and (os.stat(path).st_ino, os.stat(path).st_mtime_ns) == stamp
        assert layout.metadata["source_checksum"] == container.checksum


def test_a_damaged_or_foreign_derived_file_is_built_again(space_path, tmp_path):
    store = DerivedStore(tmp_path / "derived")
    with Container.open(space_path) as container:
        path = store.path(container, "nonlinear")
        path.parent.mkdir()
        path.write_bytes(b"not a container")
        calls = []

        def make():
            calls.append(1)
            return {"x": np.arange(4.0)}

        assert store.load(container, "nonlinear", {"version": 1}, make)["x"].tolist() == [0, 1, 2, 3]
        assert store.load(container, "nonlinear", {"version": 2}, make)["x"].tolist() == [0, 1, 2, 3]
        assert len(calls) == 2  # other parameters: built again
        assert store.load(container, "nonlinear", {"version": 2}, make) is not None and len(calls) == 2


def test_a_rebuilt_space_gets_new_derived_files_and_the_old_ones_go(space_path, tmp_path):
    directory = tmp_path / "spaces"
    directory.mkdir()
    path = directory / "gait.mspace"
    path.write_bytes(space_path.read_bytes())
    store = DerivedStore(tmp_path / "derived")
    with MotionSpace.open(path, derived=store) as space:
        old = space.blend([0.4, 0.6], 0.2, "hybrid")
    before = sorted((tmp_path / "derived").glob("gait.*.hybrid.mspace"))
    build(path, (0.9, 2.0))  # another space under the same name
    with MotionSpace.open(path, derived=store) as space, MotionSpace.open(path) as plain:
        new = space.blend([0.4, 0.6], 0.2, "hybrid")
        np.testing.assert_array_equal(new, plain.blend([0.4, 0.6], 0.2, "hybrid"))
    after = sorted((tmp_path / "derived").glob("gait.*.hybrid.mspace"))
    assert len(before) == len(after) == 1 and before != after
    assert not np.array_equal(old, new)
