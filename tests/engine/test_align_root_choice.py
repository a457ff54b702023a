"""The root frame: central in the tree, and with its limbs apart (engine.align.root_choice)."""

import numpy as np
import pytest
from skimage.measure import marching_cubes

from engine.align.options import AlignmentOptions
from engine.align.root_choice import choose_root, geodesic_spread, surface_handles
from engine.align.root_trial import trial_candidates, trial_probes, try_roots
from engine.align.similarity_tree import similarity_tree, tree_centrality, tree_root
from engine.mesh_io import Mesh

CELL = 0.01


def _body(arm_gap, *, bend=0.0):
    """A torso with an arm hanging beside it from a shoulder, as a reconstruction would mesh it.

    ``arm_gap`` (m) between the arm and the torso's side: 0 merges the hand with the hip, as a
    studio reconstruction does where they touch. ``bend`` (m) swings the lower arm outwards
    (posing: the surface bends, nearly isometrically).
    """
    field = np.zeros((70, 80, 30))
    field[5:25, 10:70, 8:22] = 1.0                                   # torso, 20 x 60 x 14 cm
    x0 = 25 + int(round(arm_gap / CELL))
    field[25:x0 + 7, 62:70, 10:20] = 1.0                             # shoulder
    for y in range(20, 70):                                          # arm, 7 cm thick, hanging down
        shift = int(round(bend / CELL * max(0.0, (45 - y) / 25.0)))
        field[x0 + shift:x0 + shift + 7, y, 11:19] = 1.0
    V, F, _, _ = marching_cubes(np.pad(field, 2), level=0.5, spacing=(CELL, CELL, CELL))
    return Mesh(vertices=V.astype(np.float64), faces=F.astype(np.int64))


def test_merged_contacts_shrink_the_geodesic_spread_and_posing_does_not():
    apart, merged, posed = _body(0.05), _body(0.0), _body(0.05, bend=0.08)
    s_apart = geodesic_spread(apart.vertices, apart.faces)
    s_merged = geodesic_spread(merged.vertices, merged.faces)
    s_posed = geodesic_spread(posed.vertices, posed.faces)
    assert s_merged < 0.9 * s_apart, (s_merged, s_apart)
    assert abs(s_posed - s_apart) < 0.07 * s_apart, (s_posed, s_apart)  # 4.6% here; merged: 16%


def test_holes_do_not_pass_for_limbs_apart():
    whole = _body(0.0)
    centre = whole.vertices[whole.faces].mean(axis=1)
    lo, hi = whole.vertices.min(axis=0), whole.vertices.max(axis=0)
    # a wide hole through the front of the torso and one across the arm: walks would go round them
    torso = (centre[:, 2] < lo[2] + 0.03) & (centre[:, 1] > lo[1] + 0.25) & (centre[:, 1] < lo[1] + 0.45)
    arm = (centre[:, 0] > hi[0] - 0.08) & (centre[:, 1] > lo[1] + 0.3) & (centre[:, 1] < lo[1] + 0.34)
    holed = Mesh(vertices=whole.vertices, faces=whole.faces[~(torso | arm)])
    assert len(holed.faces) < len(whole.faces) - 50
    s_whole = geodesic_spread(whole.vertices, whole.faces)
    assert abs(geodesic_spread(holed.vertices, holed.faces) - s_whole) < 0.03 * s_whole


def test_the_root_is_nearly_central_with_its_limbs_apart():
    frames = [_body(0.0), _body(0.05), _body(0.0)]
    # nearly as central as the most central frame: the one with the arm apart wins
    root, report = choose_root(frames, np.array([10.0, 10.04, 10.0]))
    assert root == 1 and report["central"] == 0
    assert report["spread"][list(report["candidates"]).index(1)] == report["spread"].max()
    # much less central: depth costs more than the merge, the central frame stays the root
    root, _ = choose_root(frames, np.array([10.0, 14.0, 10.0]))
    assert root == 0
    # a few per cent wider from posing alone is no reason to leave the central frame
    posed = [_body(0.05, bend=0.08), _body(0.05), _body(0.05, bend=0.08)]
    root, report = choose_root(posed, np.array([10.0, 10.01, 10.0]))
    assert root == 0 and report["spread"][list(report["candidates"]).index(1)] > report["spread"][0]


def _touching(bridges):
    """The torso and an arm 5 cm apart, touching where ``bridges`` say ((y0, y1) cell rows): a hand
    on the hip with the elbow out, as a reconstruction merges it, closes a loop through the
    contact (a handle) where an arm merged all along its length closes none."""
    field = np.zeros((70, 80, 30))
    field[5:25, 10:70, 8:22] = 1.0
    field[25:37, 62:70, 10:20] = 1.0
    field[30:37, 20:70, 11:19] = 1.0
    for y0, y1 in bridges:
        field[25:30, y0:y1, 11:19] = 1.0
    V, F, _, _ = marching_cubes(np.pad(field, 2), level=0.5, spacing=(CELL, CELL, CELL))
    return Mesh(vertices=V.astype(np.float64), faces=F.astype(np.int64))


def test_handles_count_the_loops_merged_contacts_close():
    import trimesh

    for mesh, handles in ((trimesh.creation.icosphere(3), 0), (trimesh.creation.torus(1.0, 0.3), 1),
                          (_touching([]), 0), (_body(0.0), 0), (_touching([(20, 26)]), 1),
                          (_touching([(20, 26), (40, 46)]), 2)):
        assert surface_handles(mesh.vertices, mesh.faces) == handles
    # a hole is no handle: one face out of the sphere, and a disc cut out of the arm
    sphere = trimesh.creation.icosphere(3)
    assert surface_handles(sphere.vertices, sphere.faces[1:]) == 0
    arm = _touching([(20, 26)])
    centre = arm.vertices[arm.faces].mean(axis=1)
    cut = (centre[:, 0] > 0.36) & (centre[:, 1] > 0.5) & (centre[:, 1] < 0.53)
    assert cut.any() and surface_handles(arm.vertices, arm.faces[~cut]) == 1


def test_a_root_with_fewer_handles_is_taken_over_a_more_central_one():
    frames = [_touching([(20, 26), (40, 46)]), _touching([]), _touching([(20, 26), (40, 46)])]
    # a third less central and 19% wider: the spread alone pays more in centrality than it gains, so
    # it keeps the central frame, whose arm touches the torso twice
    centrality = np.array([10.0, 13.4, 10.0])
    assert choose_root(frames, centrality, handle_slack=None)[0] == 0
    root, report = choose_root(frames, centrality)
    assert root == 1 and list(report["handles"][np.argsort(report["candidates"])]) == [2.0, 0.0, 2.0]
    assert report["allowed"] == [1]  # the frames the trial may try too
    # one handle more than the fewest is allowed: the spread and the centrality decide as before
    frames = [_touching([(20, 26)]), _touching([]), _touching([(20, 26)])]
    assert choose_root(frames, np.array([10.0, 10.3, 10.0]))[0] == choose_root(
        frames, np.array([10.0, 10.3, 10.0]), handle_slack=None)[0]
    # beyond the slack no frame is a candidate, however few its handles
    assert choose_root([frames[0], _touching([]), frames[0]], np.array([10.0, 14.0, 10.0]))[0] == 0


def test_tree_centrality_is_what_the_median_root_minimises_and_choose_root_overrides_it():
    rng = np.random.default_rng(3)
    P = np.cumsum(rng.normal(size=(12, 2)), axis=0)
    D = np.linalg.norm(P[:, None] - P[None], axis=2)
    tree = similarity_tree(D)
    mst = similarity_tree(D, root=0)
    total = tree_centrality(mst.edges, mst.weights, len(D))
    assert tree.root == int(np.argmin(total)) == tree_root(mst.edges, mst.weights, len(D))
    # brute force: the sum of tree path lengths from every node
    assert np.allclose(total, [similarity_tree(D, root=r).cost.sum() for r in range(len(D))])
    seen = []
    chosen = similarity_tree(D, choose_root=lambda c: seen.append(c) or 5)
    assert chosen.root == 5 and np.allclose(seen[0], total)
    with pytest.raises(ValueError, match="choose_root gave 99"):
        similarity_tree(D, choose_root=lambda c: 99)


def test_trial_candidates_start_from_the_spread_choice_and_skip_near_poses():
    # frames 0-2 are one rest pose (as a take's first and last frames), 3-5 others
    P = np.array([[0.0], [0.01], [0.02], [1.0], [2.0], [3.0]])
    D = np.abs(P - P.T)
    centrality = np.array([1.0, 1.01, 1.02, 1.1, 1.2, 2.0])  # frame 5 is beyond the slack
    assert trial_candidates(D, centrality, 1, slack=0.35, count=4) == [1, 3, 4]
    assert trial_candidates(D, centrality, 1, slack=0.35, count=2) == [1, 3]
    # with nothing kept apart, the most central frames in order
    assert trial_candidates(D, centrality, 1, slack=0.35, count=3, apart=0.0) == [1, 0, 2]
    # frames the handles allow come first (5 is beyond the slack); the others fill the places left
    assert trial_candidates(D, centrality, 1, slack=0.35, count=2, allowed=[1, 4, 5]) == [1, 4]
    assert trial_candidates(D, centrality, 1, slack=0.35, count=4, allowed=[1, 4, 5]) == [1, 4, 3]
    assert trial_candidates(D, centrality, 1, slack=0.35, count=2, allowed=[1]) == [1, 3]


def test_trial_probes_are_spread_evenly_and_never_a_candidate():
    assert trial_probes(60, [0, 30], count=6) == [5, 15, 25, 35, 45, 55]
    probes = trial_probes(12, [1, 3, 5], count=6)
    assert len(set(probes)) == 6 and not set(probes) & {1, 3, 5}
    assert probes == [0, 2, 4, 7, 9, 11]  # the middles 1, 3 and 5 are candidates: their left neighbours
    assert len(trial_probes(5, [0, 1], count=6)) == 3  # no more probes than frames left


def test_the_trial_takes_the_candidate_whose_probes_align_best():
    """A root whose hand is merged with its hip tears where the probes' arms swing out; the
    root with the arm apart only bends, and the trial takes it over the merged one."""
    frames = [_body(0.0), _body(0.05), _body(0.05, bend=0.08), _body(0.05, bend=0.12), _body(0.05, bend=0.04)]
    options = AlignmentOptions(levels=3)
    root, report, tets = try_roots(frames, [0, 1], [2, 3, 4], None, options=options, use_colors=False,
                                   colours=False)
    assert root == 1 and report["candidates"] == [0, 1] and report["probes"] == [2, 3, 4]
    badness = np.array(report["badness"])
    assert badness.shape == (2, 3) and np.all(np.isfinite(badness))
    assert report["mean"][1] < 0.7 * report["mean"][0], report
    # every candidate's tet mesh comes back for the alignment (and the race), and a second trial,
    # in two worker processes, is the same
    assert sorted(tets) == [0, 1] and tets[1][0].shape[1] == 3 and tets[1][1].shape[1] == 4
    # (its progress starts at 0 before the first candidate's set-up, so a bar opens when the stage does)
    seen = []
    again = try_roots(frames, [0, 1], [2, 3, 4], None, options=options, use_colors=False, colours=False, workers=2,
                      progress=lambda done, total: seen.append((done, total)))
    assert again[1] == report and all(np.array_equal(again[2][c][1], tets[c][1]) for c in (0, 1))
    assert seen[0] == (0, 2) and seen[-1] == (2, 2)


def test_a_candidate_that_cannot_be_filled_is_null_in_the_report_and_never_taken():
    import json

    from engine.align.root_race import finalists

    flat = Mesh(vertices=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]]), faces=np.array([[0, 1, 2], [1, 3, 2]]))
    frames = [flat, _body(0.05), _body(0.05, bend=0.08), _body(0.05, bend=0.12)]
    root, report, tets = try_roots(frames, [0, 1], [2, 3], None, options=AlignmentOptions(levels=2),
                                   use_colors=False, colours=False)
    assert root == 1 and tets[0] is None and tets[1] is not None
    assert report["badness"][0] == [None, None] and report["mean"][0] is None and report["mean"][1] > 0
    json.dumps(report, allow_nan=False)  # strict JSON, as the job record and the manifest need
    assert finalists(report) == [1]
