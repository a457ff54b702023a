"""Tests for engine.tetmesh: exact facts first, then properties, then lattice tet meshes."""

from itertools import permutations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from engine.rotations import axis_angle_matrix
from engine.surface import enclosed_volume
from engine.tetmesh.occupancy import grid_occupancy
from engine.tetmesh import (
    boundary_faces,
    deformation_gradients,
    embed_barycentric,
    polar_decomposition,
    quaternions_to_rotations,
    rotations_to_quaternions,
    tet_barycentric,
    tet_gradient,
    tet_laplacian,
    tet_mass,
    tet_volumes,
    tetrahedralize,
)

UNIT_TET_V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
UNIT_TET_T = np.array([[0, 1, 2, 3]])


def grid_tets(n, size=1.0):
    """A cube of n^3 cells, each split into 6 positively oriented tets (Kuhn subdivision)."""
    ticks = np.linspace(0.0, size, n + 1)
    V = np.stack(np.meshgrid(ticks, ticks, ticks, indexing="ij"), axis=-1).reshape(-1, 3)
    index = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    tets = []
    for i, j, k in np.ndindex(n, n, n):
        for order in permutations(range(3)):
            corner, path = np.array([i, j, k]), [index[i, j, k]]
            for axis in order:
                corner[axis] += 1
                path.append(index[tuple(corner)])
            tets.append(path)
    T = np.array(tets)
    negative = tet_volumes(V, T) < 0
    T[negative] = T[negative][:, [0, 1, 3, 2]]
    return V, T


@pytest.fixture(scope="module")
def sphere_tets():
    """An icosphere (radius 1) and its lattice tet mesh, computed once for the module."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    V_tet, T = tetrahedralize(sphere.vertices, sphere.faces, resolution=24)
    return sphere.vertices, sphere.faces, V_tet, T


# -- exact facts ------------------------------------------------------------------------------

def test_unit_tet_volume_is_one_sixth_and_orientation_gives_the_sign():
    assert tet_volumes(UNIT_TET_V, UNIT_TET_T)[0] == pytest.approx(1.0 / 6.0, abs=1e-15)
    assert tet_volumes(UNIT_TET_V, [[0, 1, 3, 2]])[0] == pytest.approx(-1.0 / 6.0, abs=1e-15)


def test_unit_tet_gradient_matrix():
    G = tet_gradient(UNIT_TET_V, UNIT_TET_T).toarray()
    expected = np.array([[-1.0, 1, 0, 0], [-1, 0, 1, 0], [-1, 0, 0, 1]])
    np.testing.assert_allclose(G, expected, atol=1e-15)


def test_unit_tet_laplacian_is_volume_times_gradient_gram():
    L = tet_laplacian(UNIT_TET_V, UNIT_TET_T).toarray()
    expected = np.array([[3.0, -1, -1, -1], [-1, 1, 0, 0], [-1, 0, 1, 0], [-1, 0, 0, 1]]) / 6.0
    np.testing.assert_allclose(L, expected, atol=1e-15)


def test_barycentric_coordinates_of_the_unit_tet_centroid_and_corners():
    P = np.vstack([UNIT_TET_V.mean(axis=0), UNIT_TET_V])
    tet_index, W, distance = tet_barycentric(P, UNIT_TET_V, UNIT_TET_T)
    np.testing.assert_array_equal(tet_index, 0)
    np.testing.assert_allclose(W, np.vstack([np.full(4, 0.25), np.eye(4)]), atol=1e-15)
    np.testing.assert_array_equal(distance, 0.0)


def test_point_outside_a_single_tet_is_extrapolated_with_its_distance():
    P = np.array([[1.0, 1.0, 1.0], [-0.5, 0.2, 0.2]])
    _, W, distance = tet_barycentric(P, UNIT_TET_V, UNIT_TET_T)
    np.testing.assert_allclose(W[0], [-2.0, 1.0, 1.0, 1.0], atol=1e-14)
    np.testing.assert_allclose(distance, [2.0 / np.sqrt(3.0), 0.5], atol=1e-14)
    B = embed_barycentric(P, UNIT_TET_V, UNIT_TET_T)
    np.testing.assert_allclose(B @ UNIT_TET_V, P, atol=1e-14)


def test_boundary_faces_of_a_single_tet_point_outward():
    F, owner = boundary_faces(UNIT_TET_T)
    assert F.shape == (4, 3)
    np.testing.assert_array_equal(owner, 0)
    assert enclosed_volume(UNIT_TET_V, F) == pytest.approx(1.0 / 6.0)


# -- operators on a structured grid -----------------------------------------------------------

def test_gradient_of_a_linear_field_is_its_slope_in_every_tet():
    V, T = grid_tets(3, size=2.0)
    a, b = np.array([0.3, -1.2, 2.5]), 0.7
    g = (tet_gradient(V, T) @ (V @ a + b)).reshape(-1, 3)
    np.testing.assert_allclose(g, np.broadcast_to(a, g.shape), atol=1e-12)


def test_laplacian_is_symmetric_psd_with_zero_row_sums():
    V, T = grid_tets(3)
    V = V + 0.05 * np.random.default_rng(0).normal(size=V.shape)  # irregular, still valid
    assert np.all(tet_volumes(V, T) > 0)
    L = tet_laplacian(V, T)
    assert isinstance(L, sp.csr_matrix)
    assert abs(L - L.T).max() == 0.0
    np.testing.assert_allclose(np.asarray(L.sum(axis=1)).ravel(), 0.0, atol=1e-12)
    eigenvalues = np.linalg.eigvalsh(L.toarray())
    assert eigenvalues[0] > -1e-12
    assert eigenvalues[1] > 1e-6  # connected mesh: only the constants are in the null space


def test_laplacian_energy_is_volume_weighted_dirichlet_energy():
    V, T = grid_tets(2)
    x = np.random.default_rng(1).normal(size=len(V))
    gradients = (tet_gradient(V, T) @ x).reshape(-1, 3)
    energy = np.sum(tet_volumes(V, T) * np.sum(gradients**2, axis=1))
    assert x @ tet_laplacian(V, T) @ x == pytest.approx(energy, rel=1e-12)
    np.testing.assert_allclose(tet_mass(V, T).diagonal(), np.repeat(tet_volumes(V, T), 3))


def test_gradient_rejects_a_flat_tet():
    V = UNIT_TET_V.copy()
    V[3] = [0.3, 0.3, 0.0]
    with pytest.raises(ValueError, match="degenerate"):
        tet_gradient(V, UNIT_TET_T)


def test_bad_shapes_and_indices_raise_value_errors():
    with pytest.raises(ValueError, match=r"\(t, 4\)"):
        tet_volumes(UNIT_TET_V, [[0, 1, 2]])
    with pytest.raises(ValueError, match="outside"):
        tet_volumes(UNIT_TET_V, [[0, 1, 2, 4]])
    with pytest.raises(ValueError, match="non-finite"):
        tet_gradient(np.full((4, 3), np.nan), UNIT_TET_T)


def test_deformation_gradients_of_an_affine_map_are_the_matrix():
    V, T = grid_tets(2)
    rng = np.random.default_rng(2)
    A = np.eye(3) + 0.4 * rng.normal(size=(3, 3))
    F = deformation_gradients(V, V @ A.T + rng.normal(size=3), T)
    np.testing.assert_allclose(F, np.broadcast_to(A, F.shape), atol=1e-12)


def test_deformation_gradients_match_the_gradient_operator():
    V, T = grid_tets(2)
    X = V + 0.1 * np.random.default_rng(3).normal(size=V.shape)
    F = deformation_gradients(V, X, T)
    GX = (tet_gradient(V, T) @ X).reshape(-1, 3, 3)
    np.testing.assert_allclose(GX, np.swapaxes(F, 1, 2), atol=1e-12)


# -- polar decomposition and quaternions ------------------------------------------------------

def assert_polar(F, R, S):
    np.testing.assert_allclose(R @ S, F, atol=1e-10 * max(1.0, np.abs(F).max()))
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(S, np.swapaxes(S, -1, -2), atol=1e-14)


def test_polar_decomposition_of_rotation_times_stretch_recovers_both():
    rng = np.random.default_rng(4)
    R0 = axis_angle_matrix(rng.normal(size=(50, 3)), rng.uniform(0, np.pi, 50))
    Q = axis_angle_matrix(rng.normal(size=(50, 3)), rng.uniform(0, np.pi, 50))
    S0 = Q @ (rng.uniform(0.2, 3.0, (50, 3))[:, :, None] * np.swapaxes(Q, 1, 2))
    R, S = polar_decomposition(R0 @ S0)
    np.testing.assert_allclose(R, R0, atol=1e-10)
    np.testing.assert_allclose(S, S0, atol=1e-10)


def test_polar_decomposition_of_random_and_near_degenerate_matrices():
    rng = np.random.default_rng(5)
    F = rng.normal(size=(500, 3, 3))  # about half of them have det < 0
    U, s, Wt = np.linalg.svd(rng.normal(size=(100, 3, 3)))
    s[:, 2] = 10.0 ** rng.uniform(-14, -6, 100)  # nearly flat elements, det > 0
    near_flat = (U * s[:, None, :]) @ Wt
    near_flat *= np.sign(np.linalg.det(near_flat))[:, None, None]
    for batch in (F, near_flat):
        R, S = polar_decomposition(batch)
        assert_polar(batch, R, S)
    _, S = polar_decomposition(near_flat)
    assert np.linalg.eigvalsh(S).min() > -1e-12  # det F > 0: S is positive semi-definite


def test_the_compiled_newton_split_is_the_svd_split_and_inverted_elements_still_take_the_svd():
    """Tets that are not inverted or nearly flat are split by Newton's iteration (compiled); the
    others by the SVD, as before. Both give the same factors to rounding."""
    from engine.tetmesh.polar_decomposition import _svd_polar

    rng = np.random.default_rng(7)
    F = np.eye(3) + 0.3 * rng.normal(size=(4000, 3, 3))   # a body's gradients, a few inverted
    F[:1000] *= 1e-3                                       # in millimetres' scale
    inverted = np.linalg.det(F) < 0
    assert 0 < inverted.sum() < 100
    R, S = polar_decomposition(F)
    R_svd, S_svd = _svd_polar(F)
    np.testing.assert_allclose(R, R_svd, atol=1e-13)
    np.testing.assert_allclose(S, S_svd, atol=1e-13)
    assert np.array_equal(R[inverted], R_svd[inverted]) and np.array_equal(S[inverted], S_svd[inverted])
    assert_polar(F, R, S)
    again, _ = polar_decomposition(F)
    assert np.array_equal(again, R)  # the same bytes run after run
    assert polar_decomposition(F[0])[0].shape == (3, 3) and polar_decomposition(F[:0])[0].shape == (0, 3, 3)
    assert polar_decomposition(F.reshape(40, 100, 3, 3))[0].shape == (40, 100, 3, 3)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, (3, 3), elements=st.floats(-10, 10)))
def test_polar_decomposition_property(F):
    R, S = polar_decomposition(F)
    assert_polar(F, R, S)


def test_quaternion_round_trip_including_half_turns():
    rng = np.random.default_rng(6)
    angles = np.concatenate([rng.uniform(0, np.pi, 200), [0.0, np.pi, np.pi, np.pi - 1e-9]])
    axes = np.concatenate([rng.normal(size=(200, 3)), np.eye(3)[[0, 0, 1, 2]]])
    R = axis_angle_matrix(axes, angles)
    q = rotations_to_quaternions(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-14)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(quaternions_to_rotations(q), R, atol=1e-12)
    np.testing.assert_allclose(quaternions_to_rotations(-3.0 * q), R, atol=1e-12)
    np.testing.assert_allclose(rotations_to_quaternions(np.eye(3)), [1.0, 0, 0, 0])
    half_turn_about_x = quaternions_to_rotations([0.0, 1.0, 0.0, 0.0])
    np.testing.assert_allclose(half_turn_about_x, np.diag([1.0, -1.0, -1.0]), atol=1e-15)


def test_quaternions_to_rotations_rejects_zero():
    with pytest.raises(ValueError, match="zero-length"):
        quaternions_to_rotations(np.zeros(4))


# -- tetrahedralize (voxel lattice) -----------------------------------------------------------

def check_tet_mesh(V_surface, F_surface, V_tet, T, rel):
    assert V_tet.dtype == np.float64 and V_tet.shape[1] == 3
    assert T.dtype == np.int64 and T.shape[1] == 4
    np.testing.assert_array_equal(np.unique(T), np.arange(len(V_tet)))  # no unused vertices
    volumes = tet_volumes(V_tet, T)
    assert volumes.min() > 0
    surface_volume = abs(enclosed_volume(V_surface, F_surface))
    assert volumes.sum() == pytest.approx(surface_volume, rel=rel)
    F_boundary, _ = boundary_faces(T)
    assert enclosed_volume(V_tet, F_boundary) == pytest.approx(volumes.sum(), rel=1e-12)


def test_tetrahedralize_icosphere(sphere_tets):
    V, F, V_tet, T = sphere_tets
    check_tet_mesh(V, F, V_tet, T, rel=0.3)  # cells half inside count as solid: a superset
    _, _, distance = tet_barycentric(V, V_tet, T)
    assert np.mean(distance == 0) > 0.5     # most of the surface lies inside the tets


def test_tetrahedralize_volume_converges_with_the_half_inside_rule():
    capsule = trimesh.creation.capsule(height=1.0, radius=0.3, count=[24, 24])
    errors = []
    for resolution in (16, 32, 64):
        V_tet, T = tetrahedralize(capsule.vertices, capsule.faces, resolution=resolution, min_inside=4)
        errors.append(abs(tet_volumes(V_tet, T).sum() / capsule.volume - 1))
    assert errors[2] < errors[0] and errors[2] < 0.03


def test_tetrahedralize_is_deterministic_and_ignores_orientation():
    capsule = trimesh.creation.capsule(height=1.0, radius=0.3, count=[16, 16])
    first = tetrahedralize(capsule.vertices, capsule.faces, resolution=20)
    again = tetrahedralize(capsule.vertices.copy(), capsule.faces.copy(), resolution=20)
    inverted = tetrahedralize(capsule.vertices, capsule.faces[:, ::-1], resolution=20)
    for a, b in ((first, again), (first, inverted)):
        assert a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()
    check_tet_mesh(capsule.vertices, capsule.faces, *first, rel=0.3)


def test_a_triangle_soup_and_a_surface_saved_twice_fill_as_the_surface():
    """Scans come as STL-like soups (three vertices of its own for every face) or with every face
    written twice. They were refused: the soup shares no edge (capped face by face), the doubled
    surface counts every crossing twice (ray parity finds nothing inside). Both now give the
    surface's own tets, byte for byte."""
    capsule = trimesh.creation.capsule(height=1.0, radius=0.3, count=[16, 16])
    V, F = np.asarray(capsule.vertices), np.asarray(capsule.faces)
    whole = tetrahedralize(V, F, resolution=20)
    soup = tetrahedralize(V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3), resolution=20)
    twice = tetrahedralize(V, np.vstack([F, F[::-1, ::-1]]), resolution=20)
    for other in (soup, twice):
        assert other[0].tobytes() == whole[0].tobytes() and other[1].tobytes() == whole[1].tobytes()


def test_tetrahedralize_follows_the_shape_not_the_vertex_count():
    """Midpoint subdivision keeps the surface, and so the cells, while quadrupling the faces."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    V4, F4 = trimesh.remesh.subdivide(sphere.vertices, sphere.faces)
    V_tet, T = tetrahedralize(sphere.vertices, sphere.faces, resolution=20)
    V_tet4, T4 = tetrahedralize(V4, F4, resolution=20)
    assert len(F4) == 4 * len(sphere.faces)
    np.testing.assert_array_equal(T, T4)
    np.testing.assert_allclose(V_tet, V_tet4, atol=1e-12)


def test_tetrahedralize_open_surface_fills_as_if_capped():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    closed = tetrahedralize(sphere.vertices, sphere.faces, resolution=20)
    # a one-triangle hole: its cap lies in the triangle's plane, so the cells are the same
    one = tetrahedralize(sphere.vertices, sphere.faces[1:], resolution=20)
    np.testing.assert_array_equal(one[1], closed[1])
    # a hole round the top: the flat cap cuts off a spherical segment, and no more than that
    top = np.flatnonzero(sphere.vertices[sphere.faces].min(axis=1)[:, 1] > 0.9)
    opened = tetrahedralize(sphere.vertices, np.delete(sphere.faces, top, axis=0), resolution=20)
    segment = np.pi * 0.1 ** 2 * (3 - 0.1) / 3  # the part of the unit ball above y = 0.9
    lost = tet_volumes(*closed).sum() - tet_volumes(*opened).sum()
    assert len(top) > 10 and 0 < lost < 2 * segment
    check_tet_mesh(sphere.vertices, sphere.faces, *opened, rel=0.3)


def test_tetrahedralize_drops_cells_no_surface_point_holds():
    """Two spheres far apart, the second of them with no faces: only the first is filled."""
    a = trimesh.creation.icosphere(subdivisions=2)
    V = np.concatenate([a.vertices, a.vertices + [5.0, 0, 0]])
    V_tet, T = tetrahedralize(V, a.faces, resolution=60)
    assert V_tet[:, 0].max() < 1.5


def test_tetrahedralize_rejects_bad_input():
    sphere = trimesh.creation.icosphere(subdivisions=1)
    with pytest.raises(ValueError, match="non-empty"):
        tetrahedralize(sphere.vertices, np.zeros((0, 3), dtype=int))
    with pytest.raises(ValueError, match="non-finite"):
        tetrahedralize(np.full_like(sphere.vertices, np.inf), sphere.faces)
    with pytest.raises(ValueError, match="outside"):
        tetrahedralize(sphere.vertices, sphere.faces + 1000)
    with pytest.raises(ValueError, match="encloses no lattice cell"):
        flat = sphere.vertices * [1.0, 1e-4, 1.0]
        tetrahedralize(flat, sphere.faces, resolution=8)


def test_grid_occupancy_of_a_sphere():
    sphere = trimesh.creation.icosphere(subdivisions=4)
    h = 0.05
    origin = np.array([-1.2, -1.2, -1.2]) + 0.013
    shape = (49, 49, 49)
    inside = grid_occupancy(sphere.vertices, sphere.faces, origin, h, shape)
    P = origin + np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), axis=-1) * h
    radius = np.linalg.norm(P, axis=-1)
    clear = np.abs(radius - 1.0) > 0.01  # the icosphere lies within 0.5% of the unit sphere
    np.testing.assert_array_equal(inside[clear], radius[clear] < 1.0)


# -- barycentric embedding --------------------------------------------------------------------

def test_embedding_reproduces_points_inside_tets(sphere_tets):
    _, _, V_tet, T = sphere_tets
    rng = np.random.default_rng(7)
    tets = rng.integers(0, len(T), 2000)
    weights = rng.dirichlet(np.ones(4), 2000)
    P = np.einsum("nj,njk->nk", weights, V_tet[T[tets]])
    tet_index, W, distance = tet_barycentric(P, V_tet, T)
    np.testing.assert_array_equal(distance, 0.0)
    assert W.min() >= -1e-10
    np.testing.assert_allclose(np.einsum("nj,njk->nk", W, V_tet[T[tet_index]]), P, atol=1e-12)
    B = embed_barycentric(P, V_tet, T)
    np.testing.assert_allclose(B @ V_tet, P, atol=1e-12)


def test_embedding_of_the_sphere_surface(sphere_tets):
    V, _, V_tet, T = sphere_tets
    B = embed_barycentric(V, V_tet, T)
    assert isinstance(B, sp.csr_matrix) and B.shape == (len(V), len(V_tet))
    np.testing.assert_array_equal(np.diff(B.indptr), 4)
    np.testing.assert_allclose(np.asarray(B.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    np.testing.assert_allclose(B @ V_tet, V, atol=1e-9)
    _, _, distance = tet_barycentric(V, V_tet, T)
    # the solid cells reach to within one cell (model size / resolution 24) of the surface
    assert distance.max() <= np.ptp(V, axis=0).max() / 24


def test_points_outside_take_the_closest_boundary_tet(sphere_tets):
    _, _, V_tet, T = sphere_tets
    rng = np.random.default_rng(8)
    directions = rng.normal(size=(300, 3))
    P = directions / np.linalg.norm(directions, axis=1, keepdims=True) * rng.uniform(1.0, 1.5, (300, 1))
    tet_index, W, distance = tet_barycentric(P, V_tet, T)
    F_boundary, owner = boundary_faces(T)
    mesh = trimesh.Trimesh(V_tet, F_boundary, process=False)
    _, brute_distance, face = trimesh.proximity.closest_point(mesh, P)
    outside = ~mesh.contains(P)
    np.testing.assert_allclose(distance[outside], brute_distance[outside], atol=1e-12)
    assert np.all(distance[~outside] == 0.0)
    np.testing.assert_allclose(np.einsum("nj,njk->nk", W, V_tet[T[tet_index]]), P, atol=1e-12)
    # The chosen tet owns a boundary triangle at exactly that distance.
    points, tets = np.flatnonzero(outside), tet_index[outside]
    pair_point, pair_face = np.nonzero(tets[:, None] == owner[None, :])
    triangles = V_tet[F_boundary[pair_face]]
    closest = trimesh.triangles.closest_point(triangles, P[points[pair_point]])
    pair_distance = np.linalg.norm(closest - P[points[pair_point]], axis=1)
    own_distance = np.full(len(points), np.inf)
    np.minimum.at(own_distance, pair_point, pair_distance)
    np.testing.assert_allclose(own_distance, distance[outside], atol=1e-12)
