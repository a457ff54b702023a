"""The pairwise non-rigid aligner and its pieces (rigid fitting, patches) on a small synthetic body."""

import numpy as np

from engine.align import TargetSurface, farthest_point_patches, rotation_fit, surface_coordinates, true_positions
from engine.rotations import rot_y
from engine.synthetic.remesh import remesh_frame
from engine.tetmesh import polar_decomposition


def _errors(result_V, capture, aligner, k, transform=None):
    body, V, _ = capture
    faces, bary, _ = surface_coordinates(aligner.V, V[0], body.F)
    truth = true_positions(V[k:k + 1], body.F, faces, bary)[0]
    if transform is not None:
        truth = transform(truth)
    return np.linalg.norm(result_V - truth, axis=1)


def test_aligning_the_root_onto_itself_changes_nothing(walk_aligner):
    aligner = walk_aligner
    result = aligner.align(aligner.V_tet, TargetSurface(aligner.V, aligner.F))
    np.testing.assert_allclose(result.V, aligner.V, atol=1e-9)
    assert result.residual < 1e-9 and result.distortion < 1e-9


def test_a_rigidly_moved_remeshed_copy_recovers_the_correspondences(walk_capture, walk_aligner):
    body, V, _ = walk_capture
    aligner = walk_aligner
    R, t = rot_y(np.radians(25.0)), np.array([0.3, 0.02, -0.4])
    Vb, Fb, _ = remesh_frame(V[0], body.F, None, seed=77)
    result = aligner.align(aligner.V_tet, TargetSurface(Vb @ R.T + t, Fb))
    errors = _errors(result.V, walk_capture, aligner, 0, transform=lambda P: P @ R.T + t)
    assert errors.mean() < 0.15 * aligner.edge_length  # ~5 mm for 5 cm edges
    assert np.percentile(errors, 95) < 0.5 * aligner.edge_length
    assert result.residual < 0.003


def test_a_bent_copy_is_aligned_within_a_bound(walk_capture, walk_aligner):
    _, V, frames = walk_capture
    size = np.ptp(V[0], axis=0).max()
    for k in (1, 2):
        Vk, Fk, Ck = frames[k]
        result = walk_aligner.align(walk_aligner.V_tet, TargetSurface(Vk, Fk, Ck))
        errors = _errors(result.V, walk_capture, walk_aligner, k)
        assert errors.mean() < 0.01 * size  # 1% of the model size
        assert np.percentile(errors, 95) < 0.03 * size
        assert result.residual < 0.003


def test_rotation_fit_finds_the_polar_rotation():
    rng = np.random.default_rng(0)
    R, _ = polar_decomposition(rng.normal(size=(50, 3, 3)) * 0.1 + np.eye(3))
    S = np.eye(3) + 0.05 * rng.normal(size=(50, 3, 3))
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    F = R @ S
    expected, _ = polar_decomposition(F)
    np.testing.assert_allclose(rotation_fit(F, np.broadcast_to(np.eye(3), F.shape), iterations=20), expected,
                               atol=1e-8)


def test_patches_are_nested_and_cover_the_surface(walk_aligner):
    counts = [10, 20, 40]
    labels = farthest_point_patches(walk_aligner.V, walk_aligner.F, counts, seed=0)
    for count, label in zip(counts, labels):
        assert label.min() == 0 and label.max() == count - 1
        assert len(np.unique(label)) == count
    again = farthest_point_patches(walk_aligner.V, walk_aligner.F, counts, seed=0)
    assert all(np.array_equal(a, b) for a, b in zip(labels, again))  # reproducible from the seed


def test_subdivision_keeps_the_surface_and_carries_colours():
    from engine.synthetic.remesh import subdivide

    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    C = np.eye(4)[:, :3].astype(np.float32)
    V2, F2, C2 = subdivide(V, F, C)
    assert len(V2) == 4 + 6 and len(F2) == 16 and C2.dtype == np.float32
    area = lambda V, F: 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    assert np.isclose(area(V2, F2), area(V, F))
    midpoint = int(np.flatnonzero(np.all(np.isclose(V2, [0.5, 0.0, 0.0]), axis=1))[0])
    np.testing.assert_allclose(C2[midpoint], 0.5 * (C[0] + C[1]))
    assert np.array_equal(subdivide(V, F)[1], F2)


def test_a_dense_capture_is_matched_on_a_subset_at_the_fine_levels(walk_capture):
    """A 4x denser root and target (every triangle split in four), matched at every patch level on
    a fixed subset (``fine_match_samples``): aligned as well as the 1,000-vertex capture is."""
    from engine.align import AlignmentOptions, PairwiseAligner
    from engine.synthetic.remesh import subdivide
    from engine.tetmesh import tetrahedralize

    body, V, frames = walk_capture
    (V0, F0, C0), (V1, F1, C1) = frames[0], frames[1]
    V0, F0, C0 = subdivide(V0, F0, C0)
    V1, F1, C1 = subdivide(V1, F1, C1)
    options = AlignmentOptions(fine_match_samples=1500)
    aligner = PairwiseAligner(V0, F0, C0, tets=tetrahedralize(V0, F0, resolution=48), options=options)
    assert len(aligner._fine_subset) == 1500 and len(V0) > 3000
    result = aligner.align(aligner.V_tet, TargetSurface(V1, F1, C1))
    faces, bary, _ = surface_coordinates(aligner.V, V[0], body.F)
    errors = np.linalg.norm(result.V - true_positions(V[1:2], body.F, faces, bary)[0], axis=1)
    size = np.ptp(V[0], axis=0).max()
    assert errors.mean() < 0.01 * size and np.percentile(errors, 95) < 0.03 * size
    assert result.residual < 0.003


def test_a_limb_thrown_forward_is_swung_onto_the_surface_nothing_covers():
    """The right hand reaches forward at shoulder height from a hanging arm: matched patch by
    patch, the arm's patches stay by the hip they fit, and the target's arm is left uncovered;
    a swing about the shoulder (``AlignmentOptions.swing_limbs``, engine.align.coverage) puts it there
    (the pull of engine.align.reach, on by default, off here: it would cover the arm first)."""
    from engine.align import AlignmentOptions, PairwiseAligner
    from engine.synthetic import animate, build_body
    from engine.synthetic.reaches import reach
    from engine.tetmesh import tetrahedralize

    body = build_body(1000)
    motion = reach(body.skeleton, 1.4, fps=15)
    frames = animate(body, motion)
    V0, V1 = frames[0], frames[motion.events["peak_frame"]]
    tets, target = tetrahedralize(V0, body.F, resolution=48), TargetSurface(V1, body.F)
    error = {}
    for swing in (False, True):
        # patches stepping on their own: the swing is measured against the plain patch matching
        options = AlignmentOptions(patches=16, swing_limbs=swing, patch_coupling=0.0, reach_limbs=False)
        aligner = PairwiseAligner(V0, body.F, tets=tets, options=options)
        error[swing] = np.linalg.norm(aligner.align(aligner.V_tet, target).V - V1, axis=1) / body.size
    assert error[False].mean() > 0.015 and error[False].max() > 0.3  # the arm left by the hip
    assert error[True].mean() < 0.5 * error[False].mean() and error[True].max() < 0.5 * error[False].max()


def test_a_patch_half_covered_by_the_target_is_matched_with_partial_confidence(walk_aligner):
    """A patch's confidence is 1.25 times the share of its vertices that find a match (clipped to
    0..1): on a target that keeps only one side of the body, patches wholly kept are about sure
    and patches the cut runs through (and that slid onto what is left) come out in between, at a
    fine level (every vertex matched) as at a coarse one. (A model size once took the place of
    the patches' vertex counts at the fine levels, and every patch with a few matches came out
    fully sure.)"""
    a = walk_aligner
    V, F = a.V, a.F
    cut = np.median(V[:, 0])
    keep = F[(V[F][:, :, 0] < cut).all(axis=1)]
    used = np.unique(keep)
    target = TargetSurface(V[used], np.searchsorted(used, keep))
    for level in (0, len(a.patch_counts) - 1):
        labels, count = a.patch_labels[level], a.patch_counts[level]
        _, confidence = a._match_patches(V, target, labels, count, False, coarse=level == 0)
        per_patch = np.array([confidence[labels == p].max() for p in range(count)])
        side = np.array([np.mean(V[labels == p, 0] < cut) for p in range(count)])
        assert np.all(per_patch[side == 1] > 0.9), level
        partial = (per_patch > 0.05) & (per_patch < 0.95)
        assert partial.sum() >= 0.05 * count, (level, np.round(per_patch, 2))   # 9 of 30, 23 of 240


def test_the_search_gate_fits_again_with_the_search_only_where_the_colours_disagree(walk_capture, walk_aligner):
    from dataclasses import replace

    from engine.align.pairwise import PairwiseAligner
    from engine.align.options import better_alignment

    _, _, frames = walk_capture
    base = walk_aligner
    Vk, Fk, Ck = frames[2]
    target = TargetSurface(Vk, Fk, Ck)

    def aligner(**changes):   # the articulated search on the coarsest level (off by default since session 49)
        options = replace(base.options, **{"colour_weight": 1.0, "search_levels": 1, **changes})
        return PairwiseAligner(base.V, base.F, base.colors, tets=(base.V_tet, base.T), options=options)

    plain = aligner(search_levels=0).align(base.V_tet, target)
    searching = aligner()
    searched = searching.align(base.V_tet, target)
    assert searched.searched and not plain.searched
    never = aligner(search_gate=1e9).align(base.V_tet, target)  # the colours always agree well enough
    assert not never.searched
    np.testing.assert_array_equal(never.V, plain.V)
    always = aligner(search_gate=1e-9).align(base.V_tet, target)  # they never agree that well
    keep = better_alignment(searched, plain, searching.colour_floor)
    np.testing.assert_array_equal(always.V, (searched if keep else plain).V)
    assert always.searched is keep
