"""Units and up axis of captures: conversion to metres +Y up, its inverse, and detection."""

import numpy as np
import pytest

from engine.mesh_io.units import (
    detect_floor,
    detect_units,
    detect_up,
    from_metres_y_up,
    resolve_convention,
    to_metres_y_up,
)
from engine.synthetic import SequenceSpec, build_body, generate_sequence_data
from engine.tetmesh import tet_volumes


@pytest.fixture(scope="module")
def walk():
    """(body, (frames, n, 3) vertices of a short walk in metres, +Y up)."""
    body = build_body(1000)
    data = generate_sequence_data(body, SequenceSpec("walk", "gait", {"speed": 1.2, "cycles": 0.5}), fps=10,
                                  seed=0, unstructured=False)
    return body, data["vertices"]


def test_z_up_millimetres_become_y_up_metres_exactly():
    P = np.array([[0.0, 0.0, 1700.0], [0.0, -100.0, 0.0], [250.0, 0.0, 0.0]])  # head, front (-Y), side
    np.testing.assert_array_equal(to_metres_y_up(P, "mm", "z"), [[0, 1.7, 0], [0, 0, 0.1], [0.25, 0, 0]])
    np.testing.assert_array_equal(to_metres_y_up(P, "m", "y"), P)
    np.testing.assert_array_equal(to_metres_y_up(P, "cm", "+Y"), P / 100.0)


@pytest.mark.parametrize("units", ["m", "cm", "mm"])
@pytest.mark.parametrize("up", ["y", "z"])
def test_conversion_round_trips_and_keeps_orientation(walk, units, up):
    body, V = walk
    there = from_metres_y_up(V, units, up)  # a whole sequence (frames, n, 3)
    assert there.shape == V.shape
    np.testing.assert_allclose(to_metres_y_up(there, units, up), V, rtol=0, atol=1e-15)
    # a rotation, not a reflection: tetrahedra keep the sign of their volume
    T = np.array([[0, 1, 2, 3]])
    X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert tet_volumes(to_metres_y_up(X, units, up), T)[0] > 0


def test_units_from_a_human_sized_model():
    assert detect_units(1.75) == ("m", True)
    assert detect_units(175.0) == ("cm", True)
    assert detect_units(1750.0) == ("mm", True)
    assert detect_units(0.3) == ("m", False)  # a cat in metres: a guess, flagged
    assert detect_units(5000.0) == ("mm", False)
    with pytest.raises(ValueError, match="positive"):
        detect_units(0.0)


def test_up_axis_from_the_longer_extent():
    assert detect_up([[0.5, 1.8, 0.3], [0.6, 1.7, 0.4]])[0::2] == ("y", True)
    # the same frames with Y and Z swapped (Z up): exactly the inverse ratio, an even count too
    extents = np.array([[0.5, 1.8, 0.3], [0.6, 1.7, 0.4], [0.4, 1.6, 0.9], [0.5, 1.75, 0.5]])
    ratio_y, ratio_z = detect_up(extents)[1], detect_up(extents[:, [0, 2, 1]])[1]
    assert abs(ratio_y * ratio_z - 1.0) < 1e-12
    assert detect_up([[0.5, 0.3, 1.8]])[0::2] == ("z", True)
    up, ratio, confident = detect_up([[1.7, 1.7, 1.6]])  # arms out, facing along the other axis
    assert not confident and ratio == pytest.approx(1.7 / 1.6)


@pytest.mark.parametrize("units", ["m", "cm", "mm"])
@pytest.mark.parametrize("up", ["y", "z"])
def test_a_walk_in_any_convention_is_detected(walk, units, up):
    _, V = walk
    convention = resolve_convention(from_metres_y_up(V, units, up), "auto", "auto")
    assert (convention.units, convention.up) == (units, up)
    assert (convention.units_from, convention.up_from) == ("detected", "detected")
    assert convention.warnings == ()
    assert f"units {units} (detected" in convention.describe()
    assert convention.to_metadata() == {"units": units, "up": "+" + up.upper(), "units_from": "detected",
                                        "up_from": "detected"}


def test_detection_wins_over_contradicting_metadata_and_says_so(walk):
    _, V = walk
    convention = resolve_convention(from_metres_y_up(V, "mm", "z"), declared_units="m", declared_up="+Y")
    assert (convention.units, convention.up) == ("mm", "z")
    assert any("metadata says m" in w for w in convention.warnings)
    assert any("metadata says +Y up" in w for w in convention.warnings)


def test_metadata_decides_what_the_geometry_cannot():
    cube = [np.array([[0.0, 0.0, 0.0], [30.0, 30.0, 30.0]])]  # 30 across, as tall as deep
    convention = resolve_convention(cube, declared_units="cm", declared_up="+Z")
    assert (convention.units, convention.units_from, convention.up, convention.up_from) == \
        ("cm", "metadata", "z", "metadata")
    guessed = resolve_convention(cube)
    assert guessed.units_from == "detected" and len(guessed.warnings) == 2  # both are guesses, both said


def test_given_units_and_up_are_used_but_doubted_aloud(walk):
    _, V = walk
    convention = resolve_convention(V, "mm", "z")  # really metres, +Y up
    assert (convention.units, convention.up, convention.units_from, convention.up_from) == ("mm", "z", "given",
                                                                                              "given")
    assert any("looks like m" in w for w in convention.warnings)
    assert any("is +Y up?" in w for w in convention.warnings)
    with pytest.raises(ValueError, match="units must be one of"):
        resolve_convention(V, "inch", "y")
    with pytest.raises(ValueError, match="up must be one of"):
        resolve_convention(V, "m", "x")


def walking_animal(frames=20, step=0.09):
    """(frames, n, 3) vertices of a box-built four-legged animal walking along +Z, +Y up: 1.6 m
    long, 1 m tall, so longer than tall as a horse or a dog is; two legs swing while two stand."""
    import trimesh

    def box(extents, centre):
        return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))

    torso, head = box([0.35, 0.35, 1.2], [0, 0.62, 0]), box([0.2, 0.25, 0.4], [0, 0.85, 0.75])
    legs = [box([0.1, 0.45, 0.1], [x, 0.225, z]) for x in (-0.12, 0.12) for z in (-0.5, 0.5)]
    out = []
    for f in range(frames):
        parts = [torso.vertices, head.vertices]
        for k, leg in enumerate(legs):
            swing = 0.5 * np.sin(0.7 * f + np.pi * (k % 2)) if k in (0, 3) else 0.0
            c, s = np.cos(swing), np.sin(swing)
            hip = np.array([0.0, 0.45, leg.vertices[:, 2].mean()])
            R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # about X, at the hip
            parts.append((leg.vertices - hip) @ R.T + hip)
        out.append(np.concatenate(parts) + [0.0, 0.0, step * f])
    return np.asarray(out)


@pytest.mark.parametrize("up", ["y", "z"])
def test_an_animal_longer_than_tall_is_up_by_its_floor(up):
    V = from_metres_y_up(walking_animal(), "m", up)
    extents_up, ratio, confident = detect_up(np.ptp(V, axis=1))
    assert extents_up != up and confident  # the extents alone would turn it on its back
    convention = resolve_convention(V)
    assert (convention.up, convention.up_from) == (up, "detected")
    on, other = convention.floor if up == "y" else convention.floor[::-1]
    assert on == 1.0 and other <= 0.2
    assert any(f"using +{up.upper()}" in w and "floor" in w for w in convention.warnings)
    assert "on a floor in 100% of the frames" in convention.describe()


def test_a_floor_needs_frames_and_a_subject_that_travels(walk):
    _, V = walk
    standing = np.repeat(V[:1], 12, axis=0)  # in place: both axes keep their lowest level
    assert detect_floor(np.stack([standing[:, :, 1].min(axis=1), standing[:, :, 2].min(axis=1)], axis=1),
                        1.7)[0] is None
    assert detect_floor([[0.0, 1.0]] * 7, 1.7)[0] is None  # too few frames to tell
    lows = np.column_stack([np.zeros(20), np.linspace(0.0, 2.0, 20)])  # on one level along Y, travelling along Z
    up, touches = detect_floor(lows, 1.7)
    assert up == "y" and touches[0] == 1.0 and touches[1] <= 0.1
    assert detect_floor(lows[:, ::-1], 1.7)[0] == "z"
    airborne = lows.copy()
    airborne[:12, 0] += 0.4  # off the floor in most frames: no floor either way
    assert detect_floor(airborne, 1.7)[0] is None


def test_the_line_gives_the_extent_along_the_up_axis_over_the_other():
    """A given up axis that is the shorter extent shows a ratio below 1 (it said 2 for a body
    twice as long along Z when told Y is up: a docs-only trial found it)."""
    from engine.mesh_io.units import Convention

    assert "height / depth 0.5" in Convention(up="y", up_from="given", up_ratio=0.5).describe()
    assert "height / depth 2" in Convention(up="z", up_from="given", up_ratio=0.5).describe()
    assert "height / depth 3" in Convention(up="y", up_from="detected", up_ratio=3.0).describe()
