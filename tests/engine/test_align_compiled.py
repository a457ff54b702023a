"""The alignment's compiled inner loops (engine/align/compiled.py) and the k-d tree behind them
(engine/nearest.py) against plain references: the numpy region tests over every candidate, the
colour cues' and the rotation fit's array formulations, and scipy's cKDTree."""

import pickle

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from engine.align.compiled import closest_among_faces
from engine.align.matching import TargetSurface
from engine.nearest import PointTree
from engine.surface import closest_on_triangles


@pytest.fixture(scope="module")
def mesh():
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    V = np.asarray(m.vertices) * [1.0, 1.6, 0.7]  # uneven triangles: edge, corner and face regions all occur
    return V, np.asarray(m.faces)


def test_the_nearest_candidate_matches_the_numpy_region_tests(mesh):
    V, F = mesh
    rng = np.random.default_rng(3)
    P = V[rng.integers(0, len(V), 500)] * rng.uniform(0.8, 1.2, (500, 1)) + rng.normal(0, 0.02, (500, 3))
    candidates = rng.integers(0, len(F), (500, 7))
    candidates[::5, 3:] = -1  # padding: no candidate there
    points, distance, face, bary = closest_among_faces(P, V, F, candidates)
    safe = np.where(candidates >= 0, candidates, 0)
    tri = V[F[safe]]
    ref_points, ref_bary = closest_on_triangles(P[:, None, :], tri[:, :, 0], tri[:, :, 1], tri[:, :, 2])
    ref_distance = np.where(candidates >= 0, np.linalg.norm(ref_points - P[:, None, :], axis=2), np.inf)
    best = np.argmin(ref_distance, axis=1)
    rows = np.arange(len(P))
    np.testing.assert_allclose(distance, ref_distance[rows, best], rtol=0, atol=1e-12)
    np.testing.assert_allclose(points, ref_points[rows, best], rtol=0, atol=1e-12)
    # the face may differ only where two candidates share the closest point (an edge or a corner)
    np.testing.assert_allclose(np.einsum("qk,qkc->qc", bary, V[F[face]]), points, rtol=0, atol=1e-12)
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(axis=1), 1.0)
    assert (face == candidates[rows, best]).mean() > 0.9


def _closest_on_segment(P, A, B):
    ab = B - A
    length2 = float(ab @ ab)
    t = np.clip((P - A) @ ab / length2, 0.0, 1.0) if length2 > 0 else np.zeros(len(P))
    return A + t[:, None] * ab


@pytest.mark.parametrize("corners", [(0, 0, 1), (0, 1, 0), (1, 0, 0), (0, 0, 0)])
def test_a_face_that_repeats_a_corner_is_the_segment_between_the_others(corners):
    """Scans carry faces like (a, a, b): the closest point on one is on the segment a-b, in the
    compiled loop (it divided 0 by 0 there), the numpy region tests and the tet embedding's."""
    from engine.tetmesh.embed_barycentric import _point_triangle_distance

    rng = np.random.default_rng(7)
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.2, -0.1]])
    F = np.array([corners])
    P = rng.uniform(-0.6, 1.6, (400, 3))
    expected = _closest_on_segment(P, V[corners[0]], V[corners[2] if corners[2] != corners[0] else corners[1]])
    points, distance, face, bary = closest_among_faces(P, V, F, np.zeros((len(P), 1), dtype=np.int64))
    np.testing.assert_allclose(points, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(distance, np.linalg.norm(P - expected, axis=1), rtol=0, atol=1e-12)
    assert np.all(face == 0) and np.allclose(bary.sum(axis=1), 1.0)
    A, B, C = (np.broadcast_to(V[c], P.shape) for c in corners)
    ref_points, ref_bary = closest_on_triangles(P, A, B, C)
    np.testing.assert_allclose(ref_points, expected, rtol=0, atol=1e-12)
    assert np.allclose(ref_bary.sum(axis=1), 1.0)
    np.testing.assert_allclose(_point_triangle_distance(P, A, B, C), np.linalg.norm(P - expected, axis=1),
                               rtol=0, atol=1e-12)


def test_a_point_without_candidates_is_infinitely_far(mesh):
    V, F = mesh
    P = np.array([[0.0, 0.0, 1.0], [0.0, 0.9, 0.0]])
    points, distance, face, _ = closest_among_faces(P, V, F, np.array([[-1, -1], [0, -1]]))
    assert face[0] == -1 and np.isinf(distance[0]) and np.array_equal(points[0], P[0])
    assert face[1] == 0 and np.isfinite(distance[1])


def test_closest_points_on_a_target_are_the_exact_ones_nearly_everywhere(mesh):
    """TargetSurface.closest looks among the 6 faces with the nearest centres: never nearer than
    the exact closest point (every face a candidate), and that one for nearly every point."""
    V, F = mesh
    rng = np.random.default_rng(4)
    P = V[rng.integers(0, len(V), 300)] + rng.normal(0, 0.003, (300, 3))
    _, distance, _ = TargetSurface(V, F).closest(P)
    _, exact, _, _ = closest_among_faces(P, V, F, np.broadcast_to(np.arange(len(F)), (len(P), len(F))))
    assert np.all(distance >= exact - 1e-12)
    assert np.mean(distance <= exact + 1e-12) > 0.95
    assert np.max(distance - exact) < 1e-4


def test_the_point_tree_finds_cKDTrees_neighbours_and_survives_pickling(mesh):
    V, _ = mesh
    rng = np.random.default_rng(5)
    P = rng.normal(0, 0.5, (400, 3))
    tree = PointTree(V)
    for k in (1, 6):
        d, i = tree.query(P, k=k)
        d_ref, i_ref = cKDTree(V).query(P, k=k)
        assert i.dtype == np.int64 and i.shape == i_ref.shape
        np.testing.assert_array_equal(i, i_ref)
        np.testing.assert_allclose(d, d_ref, rtol=1e-12)
    again = pickle.loads(pickle.dumps(tree))
    np.testing.assert_array_equal(again.query(P, k=3)[1], tree.query(P, k=3)[1])
    with pytest.raises(ValueError, match="k must be between"):
        tree.query(P, k=len(V) + 1)


def reference_colour_flow(y, m, face, bary, idx, target, colors, sigma, reach):
    """The colour cues' choice as (points, 2k + 1) numpy arrays (the formulation before the compiled one)."""
    k = idx.shape[1]
    here = np.einsum("pk,pkc->pc", bary, target.colors[target.F[face]])
    there, vertices = target.colors[idx], target.V[idx]
    middles = 0.5 * (y[:, None, :] + vertices)
    wanted = colors[:, None, :]
    score = np.concatenate([
        np.sum((here[:, None, :] - wanted) ** 2, axis=2) / sigma**2,
        np.sum((there - wanted) ** 2, axis=2) / sigma**2 + np.sum((vertices - y[:, None, :]) ** 2, axis=2) / reach,
        np.sum((0.5 * (here[:, None, :] + there) - wanted) ** 2, axis=2) / sigma**2
        + np.sum((middles - y[:, None, :]) ** 2, axis=2) / reach], axis=1)
    facing = np.einsum("pkc,pc->pk", target.normals[idx], m) > 0.5
    score = np.where(np.concatenate([np.ones((len(y), 1), dtype=bool), facing, facing], axis=1), score, np.inf)
    best = np.argmin(score, axis=1)
    rows = np.arange(len(y))
    gain = score[:, 0] - score[rows, best]
    pick = np.clip((best - 1) % k, 0, k - 1)
    chosen = np.where((best <= k)[:, None], vertices[rows, pick], middles[rows, pick])
    shift = np.where((best == 0)[:, None], 0.0, chosen - y)
    shift -= np.einsum("pc,pc->p", shift, m)[:, None] * m
    return shift, gain / (gain + 1.0)


def test_the_colour_choice_matches_the_array_formulation(mesh):
    from engine.align.compiled import colour_choice

    V, F = mesh
    rng = np.random.default_rng(6)
    colours = rng.uniform(0, 1, (len(V), 3))
    target = TargetSurface(V, F, colours)
    P = V[rng.integers(0, len(V), 400)] + rng.normal(0, 0.01, (400, 3))
    y, _, face = target.closest(P)
    _, _, _, bary = closest_among_faces(P, target.V, target.F, target.face_tree.query(P, k=6)[1])
    m = target.normals[target.F[face, 0]]
    wanted = np.clip(colours[target.F[face, 0]] + rng.normal(0, 0.2, (400, 3)), 0, 1)
    idx = target.tree.query(y, k=8)[1]
    reach = 2.0 * target.edge_length**2
    shift, strength = colour_choice(y, m, face, bary, idx, target, wanted, 0.12, reach)
    ref_shift, ref_strength = reference_colour_flow(y, m, face, bary, idx, target, wanted, 0.12, reach)
    np.testing.assert_allclose(shift, ref_shift, rtol=0, atol=1e-12)
    np.testing.assert_allclose(strength, ref_strength, rtol=0, atol=1e-12)
    assert 0.2 < np.mean(strength > 0) < 1.0  # some matches move, some stay


def test_the_rotation_fit_matches_the_batched_array_formulation():
    from scipy.spatial.transform import Rotation

    from engine.align.rigid import rodrigues, rotation_fit

    rng = np.random.default_rng(7)
    t = 2000
    truth = Rotation.random(t, random_state=1).as_matrix()
    F = truth * rng.uniform(0.9, 1.1, (t, 1, 1)) + rng.normal(0, 0.02, (t, 3, 3))
    R0 = Rotation.from_rotvec(rng.normal(0, 0.1, (t, 3))).as_matrix() @ truth  # a warm start
    R = R0.copy()
    for _ in range(3):  # the iteration as batched arrays (Mueller et al. 2016)
        omega = np.cross(R, F, axisa=1, axisb=1).sum(axis=1) / (np.abs(np.einsum("tij,tij->t", R, F)) + 1e-9)[:, None]
        R = rodrigues(omega) @ R
    fitted = rotation_fit(F, R0, iterations=3)
    np.testing.assert_allclose(fitted, R, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fitted @ np.swapaxes(fitted, 1, 2), np.broadcast_to(np.eye(3), (t, 3, 3)), atol=1e-12)
    U, _, Vt = np.linalg.svd(F)
    polar = U @ Vt  # the closest rotations (all proper here)
    assert np.abs(rotation_fit(F, R0, iterations=12) - polar).max() < 1e-6  # it converges to them


def test_the_patch_normal_equations_match_the_per_point_einsums():
    from engine.align.compiled import patch_normal_equations

    rng = np.random.default_rng(8)
    q, count = 3000, 17
    p, r = rng.normal(0, 0.1, (q, 3)), rng.normal(0, 0.01, (q, 3))
    M = rng.normal(size=(q, 3))
    M /= np.linalg.norm(M, axis=1, keepdims=True)
    W, tau = rng.uniform(0, 1, q), rng.uniform(0, 0.3, q)
    labels = rng.integers(0, count - 1, q)  # the last patch gets no point
    metric = W[:, None, None] * (M[:, :, None] * M[:, None, :]
                                 + tau[:, None, None] * (np.eye(3) - M[:, :, None] * M[:, None, :]))
    cross = np.zeros((q, 3, 3))  # -[p]x: cross @ omega = omega x p
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 0] = p[:, 2], -p[:, 1], -p[:, 2]
    cross[:, 1, 2], cross[:, 2, 0], cross[:, 2, 1] = p[:, 0], p[:, 1], -p[:, 0]
    J = np.concatenate([cross, np.broadcast_to(np.eye(3), (q, 3, 3))], axis=2)  # (q, 3, 6)
    H_points = np.einsum("pri,prl,plj->pij", J, metric, J)
    g_points = np.einsum("pri,prl,pl->pi", J, metric, r)
    H, g = patch_normal_equations(p, r, M, W, tau, labels, count)
    for k in range(count):
        np.testing.assert_allclose(H[k], H_points[labels == k].sum(axis=0), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(g[k], g_points[labels == k].sum(axis=0), rtol=1e-12, atol=1e-15)
    assert not H[count - 1].any() and not g[count - 1].any()


def test_a_read_only_install_without_a_writable_home_still_aligns(tmp_path):
    """numba refuses ``cache=True`` with a RuntimeError at import where neither the package nor a
    user cache is writable (a container's read-only install run as a user without a home): the
    loops then compile in the process. Checked with the package and HOME mounted read-only in a
    mount namespace of their own (skipped where the host does not allow one)."""
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    package = tmp_path / "install"
    shutil.copytree(root / "engine", package / "engine", ignore=shutil.ignore_patterns("__pycache__"))
    home = tmp_path / "home"
    home.mkdir()
    probe = ("import numpy as np; from engine.align.compiled import closest_among_faces; "
             "V = np.eye(3); F = np.array([[0, 1, 2]]); "
             "print(closest_among_faces(np.zeros((1, 3)), V, F, np.zeros((1, 1), dtype=int))[1][0])")
    script = (f"mount --bind {package} {package} && mount -o remount,bind,ro {package} && "
              f"mount --bind {home} {home} && mount -o remount,bind,ro {home} && "
              f"! touch {package}/probe 2>/dev/null && "
              f"HOME={home} NUMBA_CACHE_DIR= PYTHONPATH={package} {sys.executable} -c '{probe}'")
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "true"], capture_output=True).returncode:
        pytest.skip("no mount namespaces here")
    done = subprocess.run(["unshare", "-m", "bash", "-c", script], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path, env={k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert abs(float(done.stdout.split()[-1]) - 1 / np.sqrt(3)) < 1e-12  # the origin to the plane x+y+z=1
    assert not list((package / "engine" / "align").glob("__pycache__/*.nbi"))  # nothing cached there
