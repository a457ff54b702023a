"""Pairwise non-rigid alignment and its propagation along a tree, on a small synthetic body."""

import numpy as np
import pytest

from engine.align_evaluation import score_alignment, surface_coordinates, true_positions
from engine.alignment import (
    AlignmentOptions,
    PairwiseAligner,
    TargetSurface,
    align_captures,
    align_tree,
    farthest_point_patches,
    partition_tree,
    rotation_fit,
)
from engine.mesh_io import Mesh
from engine.rotations import rot_y
from engine.similarity_tree import chain_tree
from engine.synthetic import SequenceSpec, build_body, generate_sequence_data
from engine.synthetic.remesh import remesh_frame
from engine.tetmesh import polar_decomposition, tetrahedralize


@pytest.fixture(scope="module")
def capture():
    body = build_body(1000)
    data = generate_sequence_data(body, SequenceSpec("walk", "gait", {"speed": 1.0, "cycles": 0.2,
                                                                      "start_phase": 0.1}),
                                  fps=15, seed=1)
    return body, data["vertices"], data["unstructured"]


@pytest.fixture(scope="module")
def aligner(capture):
    _, _, frames = capture
    V, F, C = frames[0]
    return PairwiseAligner(V, F, C, tets=tetrahedralize(V, F, epsilon=2e-3))


def _errors(result_V, capture, aligner, k, transform=None):
    body, V, _ = capture
    faces, bary, _ = surface_coordinates(aligner.V, V[0], body.F)
    truth = true_positions(V[k:k + 1], body.F, faces, bary)[0]
    if transform is not None:
        truth = transform(truth)
    return np.linalg.norm(result_V - truth, axis=1)


def test_aligning_the_root_onto_itself_changes_nothing(aligner):
    result = aligner.align(aligner.V_tet, TargetSurface(aligner.V, aligner.F))
    np.testing.assert_allclose(result.V, aligner.V, atol=1e-9)
    assert result.residual < 1e-9 and result.distortion < 1e-9


def test_a_rigidly_moved_remeshed_copy_recovers_the_correspondences(capture, aligner):
    body, V, _ = capture
    R, t = rot_y(np.radians(25.0)), np.array([0.3, 0.02, -0.4])
    Vb, Fb, _ = remesh_frame(V[0], body.F, None, seed=77)
    result = aligner.align(aligner.V_tet, TargetSurface(Vb @ R.T + t, Fb))
    errors = _errors(result.V, capture, aligner, 0, transform=lambda P: P @ R.T + t)
    assert errors.mean() < 0.15 * aligner.edge_length  # ~5 mm for 5 cm edges
    assert np.percentile(errors, 95) < 0.5 * aligner.edge_length
    assert result.residual < 0.003


def test_a_bent_copy_is_aligned_within_a_bound(capture, aligner):
    _, V, frames = capture
    size = np.ptp(V[0], axis=0).max()
    for k in (1, 2):
        Vk, Fk, Ck = frames[k]
        result = aligner.align(aligner.V_tet, TargetSurface(Vk, Fk, Ck))
        errors = _errors(result.V, capture, aligner, k)
        assert errors.mean() < 0.01 * size  # 1% of the model size
        assert np.percentile(errors, 95) < 0.03 * size
        assert result.residual < 0.003


def test_tree_pieces_align_the_same_in_parallel(capture, aligner):
    _, _, frames = capture
    tree = chain_tree([3], root=1)  # two branches from frame 1: 1-0 and 1-2
    task_of, heads, task_parent = partition_tree(tree.parent, tree.order, chunk=1)
    assert heads[0] == 1 and sorted(heads) == [0, 1, 2] and task_parent.tolist() == [-1, 0, 0]
    assert task_of[1] == 0
    serial = align_tree(aligner, frames[:3], tree, chunk=1)
    parallel = align_tree(aligner, frames[:3], tree, chunk=1, workers=2)
    np.testing.assert_allclose(parallel.vertices, serial.vertices, atol=1e-9)
    np.testing.assert_array_equal(parallel.parent, serial.parent)


def test_rotation_fit_finds_the_polar_rotation():
    rng = np.random.default_rng(0)
    R, _ = polar_decomposition(rng.normal(size=(50, 3, 3)) * 0.1 + np.eye(3))
    S = np.eye(3) + 0.05 * rng.normal(size=(50, 3, 3))
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    F = R @ S
    expected, _ = polar_decomposition(F)
    np.testing.assert_allclose(rotation_fit(F, np.broadcast_to(np.eye(3), F.shape), iterations=20), expected,
                               atol=1e-8)


def test_patches_are_nested_and_cover_the_surface(aligner):
    counts = [10, 20, 40]
    labels = farthest_point_patches(aligner.V, aligner.F, counts, seed=0)
    for count, label in zip(counts, labels):
        assert label.min() == 0 and label.max() == count - 1
        assert len(np.unique(label)) == count
    again = farthest_point_patches(aligner.V, aligner.F, counts, seed=0)
    assert all(np.array_equal(a, b) for a, b in zip(labels, again))  # reproducible from the seed


def test_align_tree_and_captures_give_every_frame_the_root_topology(capture, aligner):
    body, V, frames = capture
    tree = chain_tree([3], root=0)
    result = align_tree(aligner, frames[:3], tree)
    assert result.vertices.shape == (3, len(aligner.V), 3)
    np.testing.assert_allclose(result.vertices[0], aligner.V)
    assert result.parent.tolist() == [-1, 0, 1] and np.all(result.residual < 0.003)
    meshes = [Mesh(vertices=f[0], faces=f[1], colors=f[2]) for f in frames[:3]]
    run = align_captures(meshes, [3], root=0, tets=(aligner.V_tet, aligner.T),
                         options=AlignmentOptions(levels=3, rounds=(3, 2, 1)))
    errors, summary = score_alignment(run.aligned.vertices, 0, frames[0][0], V[:3], body.F, np.ptp(V[0], axis=0).max())
    assert errors.shape == (3, len(frames[0][0]))
    assert summary["mean_pct"] < 1.0


def test_pattern_frames_take_frames_from_every_sequence():
    from engine.align_evaluation import pattern_frames

    picks = pattern_frames([10, 40, 5, 3], 6)
    assert len(picks) == 6 and len(set(picks)) == 6
    starts = np.array([0, 10, 50, 55])
    sequences = {int(np.searchsorted(starts, k, side="right") - 1) for k in picks}
    assert sequences == {0, 1, 2, 3}
    assert pattern_frames([2], 6) == [0, 1]  # fewer frames than asked for


def test_pattern_colours_follow_the_rest_positions_and_tell_left_from_right():
    from engine.align_evaluation import pattern_colors, pattern_sheet

    body = build_body(1000)
    colors = pattern_colors(body.V)
    assert colors.shape == (len(body.V), 3) and colors.min() >= 0 and colors.max() <= 1
    left, right = body.V[:, 0] < -0.05, body.V[:, 0] > 0.05
    left_colours = {tuple(c) for c in colors[left]}
    right_colours = {tuple(c) for c in colors[right]}
    assert len(left_colours) == 2 and len(right_colours) == 2 and not left_colours & right_colours
    # moving the frames does not move the pattern: it is fixed on the root (frame 0 here)
    frames = np.stack([body.V, body.V + [0.3, 0.0, 0.0], body.V @ rot_y(0.5).T])
    image = pattern_sheet(frames, body.F, 0, [3], ["still"], size=300)
    assert image.shape == (300, 300, 3) and image.std() > 10


def test_pattern_frames_spread_over_many_sequences():
    from engine.align_evaluation import pattern_frames

    lengths = [10] * 14
    picks = pattern_frames(lengths, 6)
    sequences = sorted(k // 10 for k in picks)
    assert len(set(sequences)) == 6 and sequences[0] == 0 and sequences[-1] == 13
