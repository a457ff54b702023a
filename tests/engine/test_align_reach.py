"""Limbs pulled out as-rigid-as-possible to what nothing covers (engine.align.reach)."""

import numpy as np

from engine.align import AlignmentOptions, PairwiseAligner
from engine.align.matching import TargetSurface
from engine.align.reach import HANDLE, HOLD, Extremities, extremities_of, reach_uncovered
from engine.surface import model_size
from engine.synthetic.body import JOINT_INDEX


def test_the_extremities_of_a_body_are_its_hands_feet_and_head(reach_pair):
    body, V0, _, _ = reach_pair
    size = model_size(V0)
    extremities = Extremities(V0, body.F, size)
    names = {index: name for name, index in JOINT_INDEX.items()}
    owners = [{names[s] for s in np.unique(body.segment[h])} for h in extremities.handles]
    # the five ends of the body's geodesic reach come first, each alone in its handle
    assert sorted(map(sorted, owners[:5])) == [["ankle_l"], ["ankle_r"], ["head"], ["wrist_l"], ["wrist_r"]]
    right = owners.index({"wrist_r"})
    hand = extremities.handles[right]
    assert np.all(np.linalg.norm(V0[hand] - V0[extremities.vertices[right]], axis=1) < HANDLE * size)
    # what holds is the body beyond the arm: not the forearm, and not the hand
    hold = extremities.holds[right]
    assert not np.isin(hand, hold).any()
    assert not np.isin(np.flatnonzero(body.segment == JOINT_INDEX["elbow_r"]), hold).any()
    assert np.isin(np.flatnonzero(body.segment == JOINT_INDEX["ankle_l"]), hold).all()
    assert len(hold) > 0.5 * len(V0) and HOLD > HANDLE


def test_a_limb_thrown_forward_is_pulled_onto_the_surface_nothing_covers(reach_pair):
    """Matched patch by patch, the arm stays by the hip it fits and the target's arm is left
    uncovered; pulled by its hand with the body beyond the shoulder holding, the arm bends as
    the solid lets it and lands on the target's arm. The same input gives the same result."""
    body, V0, V1, tets = reach_pair
    target = TargetSurface(V1, body.F)
    error, results = {}, {}
    for pull in (False, True):
        aligner = PairwiseAligner(V0, body.F, tets=tets, options=AlignmentOptions(patches=16, reach_limbs=pull))
        results[pull] = aligner.align(aligner.V_tet, target)
        error[pull] = np.linalg.norm(results[pull].V - V1, axis=1) / body.size
    assert error[False].mean() > 0.015 and error[False].max() > 0.3  # the arm left by the hip
    assert error[True].mean() < 0.3 * error[False].mean() and error[True].max() < 0.2 * error[False].max()
    again = PairwiseAligner(V0, body.F, tets=tets, options=AlignmentOptions(patches=16, reach_limbs=True))
    assert np.array_equal(again.align(again.V_tet, target).V, results[True].V)


def test_nothing_is_pulled_where_the_target_is_covered(reach_pair):
    """A target the source already covers (itself, moved 2 cm) leaves the pose as it was."""
    body, V0, _, tets = reach_pair
    aligner = PairwiseAligner(V0, body.F, tets=tets, options=AlignmentOptions(patches=16, reach_limbs=True))
    X = aligner.V_tet + [0.0, 0.0, 0.02]
    R = np.broadcast_to(np.eye(3), (len(aligner.T), 3, 3)).copy()
    X2, R2, pulled = reach_uncovered(aligner, X, R, TargetSurface(V0, body.F))
    assert pulled == 0 and X2 is X and R2 is R
    assert extremities_of(aligner) is extremities_of(aligner)  # made once per aligner


def test_the_frames_with_a_limb_pulled_are_counted(reach_pair):
    """``AlignedFrames.pulled`` counts the pulls kept in each frame's alignment: the reach frame,
    aligned from the hanging arm, has its hand pulled out; without the option nothing is."""
    from engine.align import align_captures
    from engine.mesh_io import Mesh

    body, V0, V1, _ = reach_pair
    meshes = [Mesh(V0, body.F), Mesh(V1, body.F)]
    counts = {}
    for pull in (True, False):
        run = align_captures(meshes, np.array([2]), root=0, workers=1, repair=False,
                             options=AlignmentOptions(patches=16, reach_limbs=pull))
        counts[pull] = run.aligned.pulled.tolist()
    assert counts[True][0] == 0 and counts[True][1] >= 1
    assert counts[False] == [0, 0]


def test_a_part_of_the_solid_between_the_hand_and_the_hold_is_held(reach_pair):
    """A tet island joined to the rest only through the surface (here the forearm's middle,
    cut out of the solid; in a studio frame the tets under a fingertip or a thin hem) that
    falls between a pull's handle and its hold is held where it is: without it the pull's
    solve would be singular and the whole alignment would stop with a ValueError."""
    from scipy.sparse.csgraph import dijkstra

    from engine.align.reach import _edge_graph
    from engine.tetmesh import tet_components

    body, V0, V1, (V_tet, T) = reach_pair
    size = model_size(V0)
    extremities = Extremities(V0, body.F, size)
    names = {index: name for name, index in JOINT_INDEX.items()}
    right = [k for k, h in enumerate(extremities.handles) if {names[s] for s in np.unique(body.segment[h])} == {"wrist_r"}][0]
    along = dijkstra(_edge_graph(V0, body.F), indices=int(extremities.vertices[right]))
    # cut the solid across the arm twice, between the handle and the hold
    at = along[np.argmin(np.linalg.norm(V_tet[:, None] - V0[None], axis=2), axis=1)][T]
    cut = (((at > 0.14) & (at < 0.2)) | ((at > 0.3) & (at < 0.36))).any(axis=1)
    used = np.unique(T[~cut])
    kept = np.searchsorted(used, T[~cut])
    tets = (V_tet[used], kept)
    aligner = PairwiseAligner(V0, body.F, tets=tets, options=AlignmentOptions(patches=16, reach_limbs=True))
    parts, part = tet_components(kept, len(used))
    owner = part[np.asarray(aligner.B.argmax(axis=1)).ravel()]
    base = np.concatenate([extremities.handles[right], extremities.holds[right]])
    loose = np.flatnonzero(~np.isin(owner, owner[base]))
    assert parts >= 3 and len(loose) > 0   # an island that neither the hand nor the hold reaches
    rows, _ = extremities_of(aligner).solver(right, aligner)   # factors without a singular system
    assert np.isin(loose, rows).all() and np.isin(base, rows).all()
    result = aligner.align(aligner.V_tet, TargetSurface(V1, body.F))
    assert np.isfinite(result.V).all()   # the alignment went through the pulls it tried
