"""Building, writing and opening motion spaces."""

import numpy as np
import pytest

from engine.blend.corrections import Corrections
from engine.motion_space import (
    Container,
    MotionSpace,
    MotionSpaceError,
    SourceClip,
    build_motion_space,
    prepare_sources,
    write_container,
)
from engine.synthetic import animate, build_body, gait, jump


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


@pytest.fixture(scope="module")
def space_path(body, tmp_path_factory):
    clips = []
    for name, speed, phase in (("slow", 0.9, 0.0), ("fast", 2.6, 0.4)):
        motion = gait(body.skeleton, speed, cycles=2.0, start_phase=phase, fps=15)
        clips.append(SourceClip(name, animate(body, motion), motion.fps, True))
    path = tmp_path_factory.mktemp("spaces") / "gait.mspace"
    build_motion_space(path, clips, body.F, name="gait", n_phases=10, epsilon=0.006, rest=body.V)
    return path


def test_the_same_build_gives_the_same_bytes(body, space_path, tmp_path):
    """Built again from the same clips (in another directory, at another time): the file is the
    same, byte for byte; the timings are in the returned report only."""
    clips = []
    for name, speed, phase in (("slow", 0.9, 0.0), ("fast", 2.6, 0.4)):
        motion = gait(body.skeleton, speed, cycles=2.0, start_phase=phase, fps=15)
        clips.append(SourceClip(name, animate(body, motion), motion.fps, True))
    again = tmp_path / "gait.mspace"
    report = build_motion_space(again, clips, body.F, name="gait", n_phases=10, epsilon=0.006, rest=body.V)
    assert again.read_bytes() == space_path.read_bytes()
    assert report["timings"]["total_s"] > 0
    with MotionSpace.open(again) as space:
        assert "timings" not in space.metadata


def test_prepared_sources_are_root_local_aligned_cycles(body):
    """Two walks captured from different start phases and places end up on the same poses."""
    clips = []
    for name, phase, offset in (("a", 0.0, (0.0, 0.0)), ("b", 0.55, (3.0, -2.0))):
        motion = gait(body.skeleton, 1.4, cycles=2.0, start_phase=phase)
        V = animate(body, motion) + np.array([offset[0], 0.0, offset[1]])
        clips.append(SourceClip(name, V, motion.fps, True))
    prepared = prepare_sources(clips, body.F, body.V, 24)
    a, b = prepared.samples[:, 0], prepared.samples[:, 1]
    assert np.abs(a - b).max() < 0.01  # same motion: same root-local cycle, phase aligned
    np.testing.assert_allclose(prepared.durations, clips[0].vertices.shape[0] / 2 / 30.0, rtol=0.01)
    # The root moves forward at the walking speed: displacement per unit phase / duration.
    speed = prepared.root_rate[:, :, 2].mean(axis=0) / prepared.durations
    np.testing.assert_allclose(speed, 1.4, rtol=0.01)
    assert np.abs(prepared.root_rate[:, :, 0]).max() < 0.05 * 1.4 * prepared.durations[0]
    assert np.abs(prepared.samples[..., [0, 2]].mean(axis=(0, 2))).max() < 0.1  # centred on the root


@pytest.mark.parametrize("degrees", [6.0, -9.0])
def test_a_rest_facing_off_the_travel_does_not_make_the_space_walk_sideways(body, degrees):
    """An aligned capture's rest is a captured pose that may face a few degrees off the way the body
    walks; heading 0 follows the sources' travel, not that facing (a space built from the tiny walk
    and run aligned walked 5.6 degrees to the side; a docs-only user). The generator's own rest,
    facing forward, is left as it is."""
    from engine.rotations import rot_y

    clips = []
    for name, speed in (("a", 1.0), ("b", 1.8)):
        motion = gait(body.skeleton, speed, cycles=2.0)
        clips.append(SourceClip(name, animate(body, motion), motion.fps, True))

    def travel(prepared):  # the mean root velocity's angle from +Z, per source, degrees
        v = prepared.root_rate.mean(axis=0)
        return np.degrees(np.arctan2(v[:, 0], v[:, 2]))

    straight = prepare_sources(clips, body.F, body.V, 16)
    assert straight.heading_turn == 0.0 and np.abs(travel(straight)).max() < 1.0
    centre = body.V.mean(axis=0)
    turned = (body.V - centre) @ rot_y(np.radians(degrees)).T + centre   # a rest facing off the walk
    prepared = prepare_sources(clips, body.F, turned, 16)
    # (the turn measured before it was taken out: how far to the side of heading 0 they travelled)
    assert np.degrees(prepared.heading_turn) == pytest.approx(degrees, abs=1.0)
    assert np.abs(travel(prepared)).max() < 1.0, travel(prepared)


def test_a_capture_travels_one_way_for_all_its_spaces(body):
    """An aligned capture's heading 0 is taken once from all its takes (``capture_travel_turn``):
    the walks say where forward is, a take standing still says nothing, and a space whose sources
    do not travel (a reach) is given it, so spaces built on one rest face one way."""
    from engine.motion_space.roots import capture_travel_turn
    from engine.rotations import rot_y

    centre = body.V.mean(axis=0)
    turned = (body.V - centre) @ rot_y(np.radians(6.0)).T + centre   # a root frame facing 6 degrees off the walk
    takes = []
    for speed in (1.0, 1.8):
        motion = gait(body.skeleton, speed, cycles=2.0)
        takes.append(SourceClip(f"walk {speed}", animate(body, motion), motion.fps, True))
    standing = SourceClip("stand", np.repeat(body.V[None], 12, axis=0), 30.0, False)
    short = SourceClip("short", takes[0].vertices[:5], 30.0, True)   # no whole cycle: says nothing
    turn = capture_travel_turn(takes + [standing, short], body.F, turned, body.size)
    assert np.degrees(turn) == pytest.approx(6.0, abs=1.0)
    assert capture_travel_turn([standing, short], body.F, turned, body.size) == 0.0
    standing = standing.vertices
    # a space of two takes that do not travel: its own sources say nothing, the capture's turn is taken
    still = [SourceClip(name, standing + [0.0, 0.01 * k, 0.0], 30.0, False) for k, name in enumerate("ab")]
    assert prepare_sources(still, body.F, turned, 8).heading_turn == 0.0
    assert prepare_sources(still, body.F, turned, 8, heading_turn=turn).heading_turn == turn


def test_clip_too_short_for_its_cycle_is_refused(body):
    V = np.repeat(body.V[None], 10, axis=0)
    with pytest.raises(ValueError, match="do not hold a whole cycle"):
        prepare_sources([SourceClip("x", V, 30.0, True, frames_per_cycle=20),
                         SourceClip("y", V, 30.0, True, frames_per_cycle=20)], body.F, body.V, 8)


def test_space_round_trip_matches_the_sources(space_path):
    with MotionSpace.open(space_path) as space:
        assert (space.n_sources, space.n_phases, space.cyclic) == (2, 10, True)
        assert space.source_names == ["slow", "fast"]
        assert not space.sources.flags.writeable  # memory-mapped, read-only
        for mode in ("linear", "hybrid", "nonlinear"):
            V = space.blend([1.0, 0.0], 0.3, mode)
            np.testing.assert_allclose(V, space.sources[3, 0], atol=2e-4 * space.model_size)
        # The epsilon bound holds on the phase grid and, since every mode interpolates linearly
        # in phase between samples, between them too.
        hybrid = space.blend([0.5, 0.5], 0.4, "hybrid")
        exact = space.blend([0.5, 0.5], 0.4, "nonlinear")
        assert np.linalg.norm(hybrid - exact, axis=1).max() <= space.metadata["epsilon"] * 1.05
        durations = space.durations()
        assert durations[0] > durations[1]  # the slow gait has the longer cycle


def test_a_new_blender_is_the_callers_own_and_blends_alike(space_path):
    with MotionSpace.open(space_path) as space:
        for mode in ("linear", "hybrid", "nonlinear"):
            own = space.new_blender(mode)
            assert own is not space.blender(mode) and own is not space.new_blender(mode)
            np.testing.assert_array_equal(own.blend(np.array([0.3, 0.7]), 0.45),
                                          space.blender(mode).blend(np.array([0.3, 0.7]), 0.45))
        with pytest.raises(ValueError, match="unknown blend mode"):
            space.new_blender("cubic")


@pytest.mark.parametrize("weights,phase,match", [
    ([1.0], 0.1, "expected 2 weights"), ([np.nan, 1.0], 0.1, "finite"), ([-1.0, 2.0], 0.1, "non-negative"),
    ([0.0, 0.0], 0.1, "not all zero"), ([0.5, 0.5], np.inf, "phase must be finite")])
def test_bad_blend_requests_are_clear_errors(space_path, weights, phase, match):
    with MotionSpace.open(space_path) as space:
        with pytest.raises(ValueError, match=match):
            space.blend(weights, phase)
        with pytest.raises(ValueError, match="unknown blend mode"):
            space.blender("cubic")


def test_corrections_round_trip_through_the_file_exactly(space_path, tmp_path):
    with MotionSpace.open(space_path) as space:
        corrections = space.corrections
        stored = {name[len("corrections_"):]: np.asarray(space.container[name])
                  for name in space.container.names if name.startswith("corrections_")}
        assert corrections.nbytes() == space.metadata["hybrid"]["correction_bytes"]
        assert corrections.nbytes() == sum(a.nbytes for a in stored.values())
        # Re-encoding what was decoded gives the file's arrays back, byte for byte.
        again = corrections.to_arrays()
        assert again.keys() == stored.keys()
        for name, array in stored.items():
            assert again[name].dtype == array.dtype and again[name].tobytes() == array.tobytes(), name
        # And the other way: in-memory corrections -> file -> the same corrections.
        path = write_container(tmp_path / "c.mspace", corrections.to_arrays(), {})
        with Container.open(path) as container:
            loaded = Corrections.from_arrays(space.n_phases, space.n_vertices, dict(container))
            for name in ("pointer", "vertex", "value", "scale"):
                np.testing.assert_array_equal(getattr(loaded, name), getattr(corrections, name))
                assert getattr(loaded, name).dtype == getattr(corrections, name).dtype


@pytest.mark.parametrize("version", [2, 3])  # 3: its bisection tree may hang a reference on a leaf's edge
def test_space_from_an_older_version_is_refused(space_path, tmp_path, version):
    with Container.open(space_path) as container:
        metadata = {**container.metadata, "version": version}
        old = write_container(tmp_path / "old.mspace", {name: container[name] for name in container}, metadata)
    with pytest.raises(MotionSpaceError,
                       match=rf"version {version} is from an older morphspace; rebuild the space") as error:
        MotionSpace.open(old)
    assert str(old) in str(error.value)


def test_truncated_space_file_is_a_clear_error(space_path, tmp_path):
    data = space_path.read_bytes()
    broken = tmp_path / "broken.mspace"
    broken.write_bytes(data[: len(data) // 2])
    with pytest.raises(MotionSpaceError, match="truncated") as error:
        MotionSpace.open(broken)
    assert str(broken) in str(error.value)


def test_sources_must_agree(body, tmp_path):
    motion = jump(body.skeleton, 0.3, 0.5, fps=15)
    V = animate(body, motion)
    walk = gait(body.skeleton, 1.0, cycles=2.0, fps=15)
    cyclic = SourceClip("walk", animate(body, walk), 15.0, True)
    one_shot = SourceClip("jump", V, 15.0, False)
    with pytest.raises(ValueError, match="all cyclic or all non-cyclic"):
        build_motion_space(tmp_path / "x.mspace", [cyclic, one_shot], body.F, name="x")
    with pytest.raises(ValueError, match="at least 2 sources"):
        build_motion_space(tmp_path / "x.mspace", [one_shot], body.F, name="x")
    other = SourceClip("other", V[:, :500], 15.0, False)
    with pytest.raises(ValueError, match="other: vertices have shape"):
        build_motion_space(tmp_path / "x.mspace", [one_shot, other], body.F, name="x")
    assert not (tmp_path / "x.mspace").exists()


def test_extra_metadata_may_not_replace_the_builders_own(tmp_path):
    from engine.motion_space import SourceClip, build_motion_space

    clips = [SourceClip(name, np.zeros((3, 4, 3)), 30.0, False) for name in ("a", "b")]
    with pytest.raises(ValueError, match="units: the builder writes these itself"):
        build_motion_space(tmp_path / "x.mspace", clips, np.array([[0, 1, 2]]), name="x", metadata={"units": "mm"})
    assert not (tmp_path / "x.mspace").exists()
