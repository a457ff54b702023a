"""Alignment propagated over a tree: pieces, workers, and the end-to-end align_captures."""

import numpy as np
import pytest

from engine.align import AlignmentOptions, align_captures, align_tree, chain_tree, partition_tree, score_alignment
from engine.mesh_io import Mesh


def test_tree_pieces_align_the_same_in_parallel(walk_capture, walk_aligner):
    _, _, frames = walk_capture
    tree = chain_tree([3], root=1)  # two branches from frame 1: 1-0 and 1-2
    task_of, heads, task_parent = partition_tree(tree.parent, tree.order, chunk=1)
    assert heads[0] == 1 and sorted(heads) == [0, 1, 2] and task_parent.tolist() == [-1, 0, 0]
    assert task_of[1] == 0
    serial = align_tree(walk_aligner, frames[:3], tree, chunk=1)
    parallel = align_tree(walk_aligner, frames[:3], tree, chunk=1, workers=2)
    np.testing.assert_allclose(parallel.vertices, serial.vertices, atol=1e-9)
    np.testing.assert_array_equal(parallel.parent, serial.parent)


def test_align_tree_and_captures_give_every_frame_the_root_topology(walk_capture, walk_aligner):
    body, V, frames = walk_capture
    aligner = walk_aligner
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


def test_a_frame_follows_its_parents_momentum_only_in_line_in_one_sequence():
    from engine.align.propagation import in_line_grandparents

    # sequences of 4 and 3 frames; root 1; the second sequence hangs off frame 3; frame 7 turns back
    parent = np.array([1, -1, 1, 2, 3, 4, 5, 8, 2])
    got = in_line_grandparents(parent, [4, 5])
    #                        0   1   2  3   4   5  6   7   8
    assert got.tolist() == [-1, -1, -1, 1, -1, -1, 4, -1, -1]
    with pytest.raises(ValueError, match="lengths add up to 7"):
        in_line_grandparents(parent, [4, 3])
