"""Tests for engine.deform: the prefactored soft-constrained Laplacian solve (paper eq. 2)."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from engine import deform
from engine.deform import DeformationSolver, stacked_gradients
from engine.rotations import axis_angle_matrix
from engine.tetmesh import deformation_gradients, tet_volumes
from test_tetmesh import grid_tets

BACKENDS = ["scipy"] + (["cholespy"] if deform.cholespy is not None else [])


@pytest.fixture(scope="module")
def mesh():
    V, T = grid_tets(4)
    return V + 0.03 * np.random.default_rng(0).normal(size=V.shape), T


def volume_centroid(V, T):
    volumes = tet_volumes(V, T)
    return volumes @ V[T].mean(axis=1) / volumes.sum()


def affine_copy(V, seed=1):
    rng = np.random.default_rng(seed)
    A = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
    return V @ A.T + rng.normal(size=3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_affine_targets_with_consistent_vertex_constraints_are_reproduced(mesh, backend):
    V, T = mesh
    X_affine = affine_copy(V)
    handles = np.array([0, 17, 60, 124])
    solver = DeformationSolver(V, T, handles, constraint_weight=0.5, backend=backend)
    assert solver.backend == backend
    g = stacked_gradients(deformation_gradients(V, X_affine, T))
    X = solver.solve(g, X_affine[handles])
    np.testing.assert_allclose(X, X_affine, atol=1e-8)


@pytest.mark.parametrize("backend", BACKENDS)
def test_affine_targets_with_barycentric_constraints_and_per_row_weights(mesh, backend):
    V, T = mesh
    X_affine = affine_copy(V, seed=2)
    rng = np.random.default_rng(3)
    rows = rng.integers(0, len(T), 30)
    weights = rng.dirichlet(np.ones(4), 30)
    B = sp.csr_matrix((weights.ravel(), (np.repeat(np.arange(30), 4), T[rows].ravel())), shape=(30, len(V)))
    solver = DeformationSolver(V, T, B, constraint_weight=rng.uniform(0.1, 10.0, 30), backend=backend)
    X = solver.solve(solver.G @ X_affine, B @ X_affine)
    np.testing.assert_allclose(X, X_affine, atol=1e-8)


@pytest.mark.parametrize("backend", BACKENDS)
def test_rotated_gradients_give_the_rotated_mesh(mesh, backend):
    V, T = mesh
    R = axis_angle_matrix(np.array([1.0, 2.0, -0.5]), 2.3)
    X_rotated = V @ R.T + np.array([0.5, -1.0, 2.0])
    g = stacked_gradients(np.broadcast_to(R, (len(T), 3, 3)))
    constrained = DeformationSolver(V, T, [5], constraint_weight=1.0, backend=backend)
    np.testing.assert_allclose(constrained.solve(g, X_rotated[[5]]), X_rotated, atol=1e-8)

    free = DeformationSolver(V, T, backend=backend)
    X = free.solve(g, centroid=volume_centroid(X_rotated, T))
    np.testing.assert_allclose(X, X_rotated, atol=1e-8)


def test_free_solver_keeps_the_rest_centroid_by_default(mesh):
    V, T = mesh
    free = DeformationSolver(V, T)
    X = free.solve(free.G @ (2.0 * V))  # scale by 2 about the volume centroid
    c = volume_centroid(V, T)
    np.testing.assert_allclose(X, c + 2.0 * (V - c), atol=1e-8)


@pytest.mark.parametrize("backend", BACKENDS)
def test_solution_solves_the_normal_equations_of_eq2(mesh, backend):
    V, T = mesh
    rng = np.random.default_rng(4)
    handles = rng.choice(len(V), 10, replace=False)
    weights = rng.uniform(0.5, 3.0, 10)
    solver = DeformationSolver(V, T, handles, constraint_weight=weights, backend=backend)
    g = rng.normal(size=(3 * len(T), 3))
    x_c = rng.normal(size=(10, 3))
    X = solver.solve(g, x_c)
    G, D = solver.G, sp.diags(np.repeat(tet_volumes(V, T), 3))
    B = sp.csr_matrix((np.ones(10), (np.arange(10), handles)), shape=(10, len(V)))
    W2 = sp.diags(weights**2)
    A = (G.T @ D @ G + B.T @ W2 @ B).tocsc()
    expected = spla.spsolve(A, G.T @ D @ g + B.T @ W2 @ x_c)
    np.testing.assert_allclose(X, expected, atol=1e-9)


def test_stronger_weights_pull_constraints_closer(mesh):
    V, T = mesh
    handles = np.array([0, 124])
    targets = V[handles] + np.array([[0.0, 0.0, -0.3], [0.0, 0.0, 0.3]])
    misfit = []
    for weight in (0.1, 1.0, 10.0):
        X = DeformationSolver(V, T, handles, constraint_weight=weight).solve(
            stacked_gradients(np.broadcast_to(np.eye(3), (len(T), 3, 3))), targets)
        misfit.append(np.abs(X[handles] - targets).max())
    assert misfit[0] > misfit[1] > misfit[2]


def test_out_is_written_in_place_and_repeated_solves_agree(mesh):
    V, T = mesh
    solver = DeformationSolver(V, T, [0, 1, 2], constraint_weight=2.0)
    g = solver.G @ affine_copy(V)
    x_c = affine_copy(V)[[0, 1, 2]]
    out = np.empty((len(V), 3))
    assert solver.solve(g, x_c, out=out) is out
    np.testing.assert_array_equal(solver.solve(g, x_c), out)


def test_stacked_gradients_match_the_gradient_operator(mesh):
    V, T = mesh
    X = affine_copy(V) + 0.05 * np.random.default_rng(5).normal(size=V.shape)
    solver = DeformationSolver(V, T)
    np.testing.assert_allclose(stacked_gradients(deformation_gradients(V, X, T)), solver.G @ X, atol=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
def test_component_major_targets_solve_like_stacked_ones(mesh, backend):
    """solve_components(F[i, j] rows) == solve(stacked_gradients(F)), and only without constraints."""
    V, T = mesh
    F = np.random.default_rng(7).normal(size=(len(T), 3, 3))
    solver = DeformationSolver(V, T, backend=backend)
    rows = np.ascontiguousarray(F.transpose(1, 2, 0))  # rows[i, j] = F[:, i, j]
    out = np.empty((len(V), 3))
    assert solver.solve_components(rows, out=out) is out
    np.testing.assert_allclose(out, solver.solve(stacked_gradients(F)), atol=1e-12)
    with pytest.raises(ValueError, match=r"\(3, 3, "):
        solver.solve_components(rows[:, :, :-1])
    with pytest.raises(ValueError, match="unconstrained"):
        DeformationSolver(V, T, [0, 1, 2]).solve_components(rows)


def test_backends_agree(mesh):
    if len(BACKENDS) < 2:
        pytest.skip("cholespy is not installed")
    V, T = mesh
    rng = np.random.default_rng(6)
    g = rng.normal(size=(3 * len(T), 3))
    x_c = rng.normal(size=(3, 3))
    X = [DeformationSolver(V, T, [3, 40, 99], backend=b).solve(g, x_c) for b in BACKENDS]
    np.testing.assert_allclose(X[0], X[1], atol=1e-10)


def test_clear_errors(mesh):
    V, T = mesh
    solver = DeformationSolver(V, T, [0, 1])
    g = np.zeros((3 * len(T), 3))
    with pytest.raises(ValueError, match="target_gradients must have shape"):
        solver.solve(g[:-1], np.zeros((2, 3)))
    with pytest.raises(ValueError, match="constraint_positions are required"):
        solver.solve(g)
    with pytest.raises(ValueError, match=r"shape \(2, 3\)"):
        solver.solve(g, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="only for the unconstrained"):
        solver.solve(g, np.zeros((2, 3)), centroid=np.zeros(3))
    with pytest.raises(ValueError, match="no constraints"):
        DeformationSolver(V, T).solve(g, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="out must be"):
        solver.solve(g, np.zeros((2, 3)), out=np.empty((len(V), 3), dtype=np.float32))
    with pytest.raises(ValueError, match="constraint_weight"):
        DeformationSolver(V, T, [0, 1], constraint_weight=0.0)
    with pytest.raises(ValueError, match="constraint_weight"):
        DeformationSolver(V, T, [0, 1], constraint_weight=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="vertex indices"):
        DeformationSolver(V, T, [0.5])
    with pytest.raises(ValueError, match="backend"):
        DeformationSolver(V, T, [0], backend="magic")


def test_disconnected_parts_need_a_constraint_each():
    V, T = grid_tets(1)
    V2, T2 = np.vstack([V, V + 5.0]), np.vstack([T, T + len(V)])
    with pytest.raises(ValueError, match="no constraint"):
        DeformationSolver(V2, T2, [0])
    X = DeformationSolver(V2, T2, [0, len(V)]).solve(
        stacked_gradients(np.broadcast_to(np.eye(3), (len(T2), 3, 3))), V2[[0, len(V)]])
    np.testing.assert_allclose(X, V2, atol=1e-10)


@pytest.mark.parametrize("backend", BACKENDS)
def test_free_solver_places_each_part_of_a_solid_in_pieces_by_its_own_centroid(backend):
    """A tet mesh in two parts (a body and a floating piece): without constraints each part is
    solved on its own, its centroid kept where it rests; ``centroid`` moves them together."""
    V, T = grid_tets(2)
    V2, T2 = np.vstack([V, 0.5 * V + 5.0]), np.vstack([T, T + len(V)])
    free = DeformationSolver(V2, T2, backend=backend)
    assert free.n_parts == 2 and free.part.tolist() == [0] * len(V) + [1] * len(V)
    np.testing.assert_allclose(free.solve(free.G @ V2), V2, atol=1e-9)
    # each part rotated about its own centroid
    R = axis_angle_matrix(np.array([0.2, 1.0, 0.3]), 1.1)
    g = stacked_gradients(np.broadcast_to(R, (len(T2), 3, 3)))
    X = free.solve(g)
    for part, rows in ((T, slice(0, len(V))), (T, slice(len(V), None))):
        c = volume_centroid(V2[rows], part)
        np.testing.assert_allclose(X[rows], c + (V2[rows] - c) @ R.T, atol=1e-8)
    # ``centroid`` moves both parts as one: the whole's volume centroid lands there
    whole = volume_centroid(V2, T2)
    moved = free.solve(g, centroid=whole + [1.0, -2.0, 0.5])
    np.testing.assert_allclose(moved - X, np.broadcast_to([1.0, -2.0, 0.5], X.shape), atol=1e-8)
