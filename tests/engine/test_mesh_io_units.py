"""Units and up axis of captures: conversion to metres +Y up, its inverse, and detection."""

import numpy as np
import pytest

from engine.mesh_io.units import (
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
