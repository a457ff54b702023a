"""Limbs grafted from other aligned frames' poses (engine.align.limb_graft)."""

import numpy as np

from engine.align import AlignmentOptions, PairwiseAligner
from engine.align.limb_graft import LimbLibrary, batch_kabsch, limbs_of
from engine.align.matching import TargetSurface
from engine.rotations import rot_y
from engine.synthetic.body import JOINT_INDEX


def test_batch_kabsch_recovers_rigid_motions():
    rng = np.random.default_rng(3)
    Q = rng.normal(size=(40, 3))
    R = np.stack([rot_y(np.radians(a)) for a in (10.0, 135.0, -70.0)])
    R[2] = R[2] @ np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # a turn about x as well
    t = rng.normal(size=(3, 3))
    P = np.einsum("haj,hji->hai", Q[None] - t[:, None], R)  # Q = R P + t for each h
    R_found, t_found = batch_kabsch(P, Q)
    assert np.allclose(R_found, R, atol=1e-9) and np.allclose(t_found, t, atol=1e-9)
    assert np.allclose(np.linalg.det(R_found), 1.0)


def test_the_limbs_are_the_ends_of_the_body_with_a_ring_beyond(reach_pair):
    body, V0, _, tets = reach_pair
    aligner = PairwiseAligner(V0, body.F, tets=tets, options=AlignmentOptions(patches=16))
    limbs = limbs_of(aligner)
    assert limbs_of(aligner) is limbs  # made once per aligner
    hand = np.flatnonzero(body.segment == JOINT_INDEX["wrist_r"])
    (arm,) = [k for k, members in enumerate(limbs.members) if np.isin(hand, members).mean() > 0.9]
    # the right arm's limb holds its hand and forearm, not the other hand; its anchor is beyond it
    assert np.isin(np.flatnonzero(body.segment == JOINT_INDEX["elbow_r"]), limbs.members[arm]).mean() > 0.5
    assert not np.isin(np.flatnonzero(body.segment == JOINT_INDEX["wrist_l"]), limbs.members[arm]).any()
    assert not np.isin(limbs.anchors[arm], limbs.members[arm]).any() and len(limbs.anchors[arm]) >= 10
    assert set(limbs.samples[arm]) <= set(limbs.members[arm])


def test_an_arm_left_by_the_hip_is_grafted_from_a_pose_that_reaches(reach_pair):
    """The frame as aligned keeps the arm hanging; the library holds the reach, the whole body
    turned and moved elsewhere: the arm's anchor carries it onto the frame, and the arm's goal
    lands on the target's arm. Aligned again from there, the frame is far better."""
    body, V0, V1, tets = reach_pair
    aligner = PairwiseAligner(V0, body.F, tets=tets, options=AlignmentOptions(patches=16, reach_limbs=False))
    target = TargetSurface(V1, body.F)
    moved = V1 @ rot_y(np.radians(70.0)).T + [0.5, 0.0, -1.0]
    library = LimbLibrary(aligner, np.stack([V0, moved]))
    as_aligned = aligner.align(aligner.V_tet, target)
    goal, grafted = library.graft(as_aligned.V, target)
    hand = np.flatnonzero(body.segment == JOINT_INDEX["wrist_r"])
    before = np.linalg.norm(as_aligned.V[hand] - V1[hand], axis=1).mean()
    assert grafted >= 1 and before > 0.2
    assert np.linalg.norm(goal[hand] - V1[hand], axis=1).mean() < 0.1 * before
    X = library.pose(as_aligned.X, as_aligned.V, target)
    again = aligner.align(X, target)
    error = {key: np.linalg.norm(W - V1, axis=1).mean() / body.size for key, W in
             (("as aligned", as_aligned.V), ("grafted", again.V))}
    assert error["grafted"] < 0.3 * error["as aligned"], error
    # the same input, the same pose
    assert np.array_equal(LimbLibrary(aligner, np.stack([V0, moved])).pose(as_aligned.X, as_aligned.V, target), X)


def test_nothing_is_grafted_from_the_frames_own_pose(reach_pair):
    """A library holding only poses no better than the frame's own leaves it as it is."""
    body, V0, _, tets = reach_pair
    aligner = PairwiseAligner(V0, body.F, tets=tets, options=AlignmentOptions(patches=16))
    library = LimbLibrary(aligner, V0[None])
    goal, grafted = library.graft(V0, TargetSurface(V0, body.F))
    assert grafted == 0 and np.array_equal(goal, V0)
    assert library.pose(aligner.V_tet, V0, TargetSurface(V0, body.F)) is None
    assert LimbLibrary(aligner, np.empty((0, len(V0), 3))).graft(V0, TargetSurface(V0, body.F))[1] == 0


def test_the_repair_grafts_a_flagged_frames_arm_from_a_trusted_frame_that_reaches(reach_pair):
    """Frame 2 (the reach, turned and moved) aligned from the root keeps the arm hanging and is
    flagged; the root cannot mend it; frame 1 (the reach, as aligned well) holds the pose that fits. The
    repair's last phase grafts frame 1's arm onto frame 2 and aligns it again: the arm lands,
    the frame is trusted, and it keeps its parent. With ``graft_limbs`` off it stays flagged."""
    from engine.align import align_tree, repair_alignment
    from engine.align.similarity_tree import rooted_tree

    body, V0, V1, tets = reach_pair
    moved = V1 @ rot_y(np.radians(40.0)).T + [0.3, 0.0, 0.2]
    meshes = [(V0, body.F, None), (V1, body.F, None), (moved, body.F, None)]
    hand = np.flatnonzero(body.segment == JOINT_INDEX["wrist_r"])
    errors = {}
    for graft in (True, False):
        # patches stepping on their own, as the graft was measured (the default couples them)
        options = AlignmentOptions(patches=16, reach_limbs=False, patch_coupling=0.0, graft_limbs=graft)
        aligner = PairwiseAligner(V0, body.F, tets=tets, options=options)
        aligned = align_tree(aligner, meshes, rooted_tree([[0, 1], [0, 2]], [1.0, 1.0], 0, 3))
        # frame 1 as a good alignment would have it: its true surface, fitting exactly
        aligned.vertices[1], aligned.residual[1], aligned.distortion_tail[1] = V1.copy(), 0.0, 0.0
        assert np.linalg.norm(aligned.vertices[2][hand] - moved[hand], axis=1).mean() > 0.2  # the arm hangs
        repair_alignment(aligner, meshes, aligned, budget=1.0)
        errors[graft] = np.linalg.norm(aligned.vertices[2] - moved, axis=1).mean() / body.size
        if graft:
            assert aligned.repaired[2] and aligned.confidence[2] >= 0.5 and aligned.parent[2] == 0
            assert np.linalg.norm(aligned.vertices[2][hand] - moved[hand], axis=1).mean() < 0.05
        else:
            assert aligned.confidence[2] < 0.5
    assert errors[True] < 0.3 * errors[False], errors
    assert AlignmentOptions().graft_limbs is False  # off by default
