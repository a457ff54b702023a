"""Volumetric shape histograms: exact invariances first, then discrimination."""

import numpy as np
import pytest
import trimesh

from engine.align.shape_histogram import (
    best_rotation,
    histogram_distance,
    histogram_norm2,
    histogram_sectors,
    is_closed,
    rotation_correlation,
    shape_histogram,
)
from engine.rotations import rot_y


@pytest.fixture(scope="module")
def figure():
    """A non-symmetric closed "figure": a box torso, an arm and a leg (three closed boxes)."""
    parts = [trimesh.creation.box((0.4, 0.6, 0.25)),
             trimesh.creation.box((0.12, 0.5, 0.12), transform=trimesh.transformations.translation_matrix((0.3, 0.05, 0.1))),
             trimesh.creation.box((0.15, 0.6, 0.15), transform=trimesh.transformations.translation_matrix((-0.1, -0.55, 0.0)))]
    mesh = trimesh.util.concatenate(parts).subdivide().subdivide()
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def test_a_rotation_about_the_vertical_axis_leaves_the_histogram_unchanged(figure):
    V, F = figure
    H = shape_histogram(V, F, radius=1.0)
    for degrees in (7.0, 33.0, 90.0, -140.0, 180.0):
        moved = V @ rot_y(np.radians(degrees)).T + np.array([0.4, -0.2, 1.3])
        G = shape_histogram(moved, F, radius=1.0)
        np.testing.assert_allclose(np.abs(G), np.abs(H), atol=1e-12)  # magnitudes: exactly invariant
        distance, found = histogram_distance(G, H)
        assert distance < 1e-6
        assert abs((found - degrees + 180.0) % 360.0 - 180.0) < 1e-6  # and the angle is recovered


def test_a_rotation_by_whole_sectors_rolls_the_sector_histogram(figure):
    V, F = figure
    H = shape_histogram(V, F, radius=1.0, harmonics=8)
    S = histogram_sectors(H, 24)
    G = shape_histogram(V @ rot_y(np.radians(45.0)).T, F, radius=1.0, harmonics=8)
    np.testing.assert_allclose(histogram_sectors(G, 24), np.roll(S, 3, axis=-1), atol=1e-12)
    assert S.sum() == pytest.approx(1.0)


def test_the_histogram_measures_volume_by_shells():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    H = shape_histogram(sphere.vertices, sphere.faces, radius=0.5, shells=5, elevations=4, harmonics=0)
    shell_mass = H[..., 0].real.sum(axis=1)
    edges = np.linspace(0.0, 1.0, 6)
    np.testing.assert_allclose(shell_mass, np.diff(edges**3), atol=2e-3)  # uniform ball: r^3 law
    np.testing.assert_allclose(H[..., 0].real.sum(axis=0), 0.25, atol=2e-3)  # equal-area bands


def test_open_surfaces_are_binned_by_area(figure):
    V, F = figure
    assert is_closed(F) and not is_closed(F[:-4])
    H = shape_histogram(V, F[:-4], radius=1.0)
    assert H[..., 0].real.sum() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="closed"):
        shape_histogram(V, F[:-4], radius=1.0, mode="volume")


def test_different_shapes_are_far_apart_and_self_correlation_peaks_at_zero(figure):
    V, F = figure
    H = shape_histogram(V, F, radius=1.0)
    bent = V.copy()
    arm = bent[:, 0] > 0.22
    bent[arm] = (bent[arm] - [0.3, 0.3, 0.1]) @ trimesh.transformations.rotation_matrix(1.2, [0, 0, 1])[:3, :3].T \
        + [0.3, 0.3, 0.1]
    G = shape_histogram(bent, F, radius=1.0)
    assert histogram_distance(G, H)[0] > 0.05 * np.sqrt(histogram_norm2(H))
    c = rotation_correlation(H, H, 72)
    degrees, peak = best_rotation(c)
    assert abs(degrees) < 1e-9 and peak == pytest.approx(histogram_norm2(H))
