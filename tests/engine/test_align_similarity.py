"""Dissimilarity matrix over frames: self-similarity, rotation invariance, filtering, parallel chunks."""

import numpy as np
import pytest
import trimesh

from engine.align.similarity import (
    _balanced_row_blocks,
    dissimilarity_matrix,
    frame_histograms,
    shape_dissimilarity,
    temporal_filter,
)
from engine.align.pictures import similarity_image
from engine.rotations import rot_y


def _bent(angle):
    """A box "body" whose "arm" box swings by ``angle`` radians about a shoulder."""
    torso = trimesh.creation.box((0.4, 0.7, 0.25))
    arm = trimesh.creation.box((0.1, 0.5, 0.1))
    arm.apply_translation((0.0, -0.25, 0.0))
    arm.apply_transform(trimesh.transformations.rotation_matrix(angle, (0, 0, 1)))
    arm.apply_translation((0.27, 0.3, 0.0))
    mesh = trimesh.util.concatenate([torso, arm]).subdivide()
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.fixture(scope="module")
def frames():
    return [_bent(a) for a in np.linspace(0.0, 1.2, 6)]


def test_a_frame_is_most_similar_to_itself(frames):
    H, radius = frame_histograms(frames)
    D, yaw = dissimilarity_matrix(H)
    assert np.all(np.diag(D) == 0.0)
    off = D + np.diag(np.full(len(D), np.inf))
    assert np.all(off.min(axis=1) > 0.0)
    np.testing.assert_allclose(D, D.T)
    np.testing.assert_allclose(yaw, -yaw.T)
    # the dissimilarity grows with the difference in the arm's angle
    assert np.all(np.diff(D[0]) > 0)


def test_rotated_copies_have_zero_dissimilarity_and_the_right_yaw(frames):
    V, F = frames[3]
    turned = (V @ rot_y(np.radians(70.0)).T + [1.0, 0.0, -2.0], F)
    H, _ = frame_histograms([frames[3], turned, frames[0]])
    D, yaw = dissimilarity_matrix(H)
    assert D[0, 1] < 1e-6 < D[0, 2]
    assert yaw[1, 0] == pytest.approx(70.0, abs=1e-3)  # turns frame 0 onto frame 1


def test_chunked_parallel_matrix_equals_the_serial_one(frames):
    H, _ = frame_histograms(frames * 3)
    serial = dissimilarity_matrix(H, chunk=1)
    parallel = dissimilarity_matrix(H, chunk=2, workers=2, parallel_from=0)
    np.testing.assert_allclose(parallel[0], serial[0], atol=1e-7)
    np.testing.assert_allclose(parallel[1], serial[1], atol=1e-4)
    bounds = _balanced_row_blocks(50, 7)
    assert bounds[0] == 0 and bounds[-1] == 50 and np.all(np.diff(bounds) > 0)


def test_temporal_filter_averages_along_diagonals_within_sequences():
    D = np.arange(25, dtype=float).reshape(5, 5)
    D = D + D.T
    np.fill_diagonal(D, 0.0)
    F = temporal_filter(D, [5], window=1)
    # (1, 3) averages pairs (0, 2), (1, 3), (2, 4)
    assert F[1, 3] == pytest.approx((D[0, 2] + D[1, 3] + D[2, 4]) / 3)
    assert F[0, 4] == pytest.approx(D[0, 4])  # no neighbours inside the sequence
    assert np.all(np.diag(F) == 0.0)
    # two sequences: blocks are filtered separately
    G = temporal_filter(D, [2, 3], window=1)
    assert G[0, 2] == pytest.approx((D[0, 2] + D[1, 3]) / 2)
    np.testing.assert_allclose(temporal_filter(D, [5], window=0), D)
    with pytest.raises(ValueError, match="add up"):
        temporal_filter(D, [2, 2])


def test_shape_dissimilarity_bundles_everything_and_draws_the_matrix(frames):
    stages = []
    result = shape_dissimilarity(frames, [3, 3], window=1, progress=lambda s, d, t: stages.append(s))
    assert result.dissimilarity.shape == (6, 6) and result.radius > 0
    assert {"histograms", "dissimilarity"} <= set(stages)
    image = similarity_image(result.dissimilarity, [3, 3], ["a", "b"], size=300)
    assert image.shape == (300, 300, 3) and image.dtype == np.uint8
