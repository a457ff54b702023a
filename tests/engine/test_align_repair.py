"""Per-frame confidence and the repair pass (engine.align.repair)."""

import numpy as np
import pytest

from engine.align import alignment_confidence, align_tree, repair_alignment
from engine.align.similarity_tree import rooted_tree


def test_confidence_is_one_for_a_perfect_frame_and_falls_with_tail_and_residual():
    c = alignment_confidence([0.0, 0.0, 0.017, 0.0], [0.0, 4.0, 0.0, 40.0], 1.7)
    assert c[0] == 1.0
    assert c[1] == pytest.approx(np.exp(-1)) and c[2] == pytest.approx(np.exp(-1))
    assert c[3] < 1e-4


def test_a_slipped_frame_is_flagged_and_realigned_from_the_root(walk_aligner, walk_capture):
    """Frame 2 aligned from a deliberately wrong pose (a mirrored tet mesh): the repair pass
    sees the torn solid, aligns it again from the root, and its confidence recovers."""
    aligner = walk_aligner
    meshes = walk_capture[2][:3]
    tree = rooted_tree([[0, 1], [1, 2]], [1.0, 1.0], 0, 3)
    aligned = align_tree(aligner, meshes, tree)
    good = aligned.vertices[2].copy()
    centre = aligner.V_tet.mean(axis=0)
    mirrored = (aligned.poses[1] - centre) * [-1.0, 1.0, 1.0] + centre  # left and right swapped
    slipped = aligner.align(mirrored, _target(meshes[2]))
    aligned.vertices[2], aligned.poses[2] = slipped.V, slipped.X
    aligned.residual[2], aligned.distortion_tail[2] = slipped.residual, slipped.distortion_tail
    before = alignment_confidence(aligned.residual, aligned.distortion_tail, 1.75)
    repair_alignment(aligner, meshes, aligned)
    assert before[2] < 0.5 <= aligned.confidence[2]
    assert aligned.repaired[2] and aligned.parent[2] == 0
    assert not aligned.repaired[:2].any()
    assert np.abs(aligned.vertices[2] - good).mean() < 0.5 * np.abs(slipped.V - good).mean()


def _target(mesh):
    from engine.align import TargetSurface

    return TargetSurface(*mesh[:3])
