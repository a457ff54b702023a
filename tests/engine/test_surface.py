"""Surface measurements, operators and closest-point queries."""

import numpy as np
import pytest
import trimesh

from engine.surface import (
    SurfaceQuery,
    cotangent_laplacian,
    enclosed_volume,
    lumped_mass,
    model_size,
    orient_outward,
    volume_centroid,
)


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    return np.asarray(m.vertices), np.asarray(m.faces)


def test_unit_cube_volume_centroid_and_size():
    cube = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    V, F = np.asarray(cube.vertices) + [1.0, 2.0, 3.0], np.asarray(cube.faces)
    assert enclosed_volume(V, F) == pytest.approx(6.0)
    np.testing.assert_allclose(volume_centroid(V, F), [1.0, 2.0, 3.0], atol=1e-12)
    assert model_size(V) == pytest.approx(3.0)


def test_volume_centroid_is_vectorised_over_frames(sphere):
    V, F = sphere
    frames = np.stack([V, V + [0.0, 1.0, 0.0], 2.0 * V])
    c = volume_centroid(frames, F)
    np.testing.assert_allclose(c, [[0, 0, 0], [0, 1, 0], [0, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(enclosed_volume(frames, F)[2], 8 * enclosed_volume(V, F))


def test_cotangent_laplacian_rows_sum_to_zero_and_is_symmetric_psd(sphere):
    V, F = sphere
    L = cotangent_laplacian(V, F)
    np.testing.assert_allclose(np.asarray(L.sum(axis=1)).ravel(), 0.0, atol=1e-10)
    assert abs(L - L.T).max() < 1e-12
    x = np.random.default_rng(0).normal(size=len(V))
    assert x @ (L @ x) > 0
    assert lumped_mass(V, F).diagonal().sum() == pytest.approx(trimesh.Trimesh(V, F).area)


def test_closest_points_match_brute_force(sphere):
    V, F = sphere
    rng = np.random.default_rng(1)
    P = V[rng.integers(0, len(V), 200)] * rng.uniform(0.97, 1.03, (200, 1)) + rng.normal(0, 0.004, (200, 3))
    points, faces, bary, distance = SurfaceQuery(V, F).closest(P)
    reference, ref_distance, _ = trimesh.proximity.closest_point(trimesh.Trimesh(V, F, process=False), P)
    np.testing.assert_allclose(distance, ref_distance, atol=1e-9)
    np.testing.assert_allclose(points, np.einsum("qk,qkc->qc", bary, V[F[faces]]), atol=1e-12)
    assert np.all(bary >= -1e-12) and np.allclose(bary.sum(axis=1), 1.0)


def test_points_on_the_surface_are_their_own_closest_points(sphere):
    V, F = sphere
    rng = np.random.default_rng(2)
    faces = rng.integers(0, len(F), 100)
    w = rng.dirichlet(np.ones(3), 100)
    P = np.einsum("qk,qkc->qc", w, V[F[faces]])
    points, _, _, distance = SurfaceQuery(V, F).closest(P)
    assert distance.max() < 1e-12
    np.testing.assert_allclose(points, P, atol=1e-12)


def test_main_components_drops_small_floating_pieces_and_keeps_the_order():
    import trimesh

    from engine.surface import main_components

    body = trimesh.creation.icosphere(subdivisions=2)
    blob = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    V = np.concatenate([blob.vertices + [3.0, 0, 0], body.vertices])
    F = np.concatenate([blob.faces, body.faces + len(blob.vertices)])
    V_kept, F_kept, kept = main_components(V, F)
    np.testing.assert_array_equal(kept, np.arange(len(blob.vertices), len(V)))
    np.testing.assert_array_equal(V_kept, body.vertices)
    np.testing.assert_array_equal(F_kept, body.faces)
    same = main_components(body.vertices, body.faces)  # one piece: given back as it is
    assert same[0] is not None and len(same[2]) == len(body.vertices)


def test_main_components_welds_an_unwelded_surface():
    """A triangle soup (every face with its own three corners, as some exporters write a mesh)
    is one piece once twins are welded: the first of each set of twins stands for it."""
    from engine.surface import main_components

    body = trimesh.creation.icosphere(subdivisions=2)
    soup_V = body.vertices[body.faces].reshape(-1, 3)
    soup_F = np.arange(len(soup_V)).reshape(-1, 3)
    V_kept, F_kept, kept = main_components(soup_V, soup_F)
    assert len(V_kept) == len(body.vertices) and len(F_kept) == len(body.faces)
    np.testing.assert_array_equal(V_kept, soup_V[kept])
    # the same surface: every face's corners where the welded mesh's are
    np.testing.assert_array_equal(np.sort(V_kept[F_kept].reshape(len(F_kept), -1), axis=0),
                                  np.sort(body.vertices[body.faces].reshape(len(body.faces), -1), axis=0))
    for first in kept:  # the first of its twins
        assert not np.any(np.all(soup_V[:first] == soup_V[first], axis=1))


def test_faces_wound_inward_or_mixed_are_turned_outward(sphere):
    V, F = sphere
    G, turned = orient_outward(V, F)
    assert turned == 0 and np.array_equal(G, F)  # already outward: as it was
    G, turned = orient_outward(V, F[:, ::-1])
    assert turned == len(F) and np.array_equal(G, F)
    mixed = np.where((np.random.default_rng(0).random(len(F)) < 0.3)[:, None], F[:, ::-1], F)
    G, turned = orient_outward(V, mixed)
    assert turned == int(np.sum(np.any(mixed != F, axis=1))) and np.array_equal(G, F)


def test_each_piece_and_open_surfaces_face_outward(sphere):
    V, F = sphere
    # two pieces, the second reversed and with a hole (an open piece still faces out)
    V2 = np.concatenate([V, V + [2.0, 0.0, 0.0]])
    top = np.flatnonzero(V[F].mean(axis=1)[:, 1] > 0.4)
    second = np.delete(F, top, axis=0) + len(V)
    G, turned = orient_outward(V2, np.concatenate([F, second[:, ::-1]]))
    assert turned == len(second)
    np.testing.assert_array_equal(G, np.concatenate([F, second]))
    assert enclosed_volume(V2, G[:len(F)]) > 0


def test_a_sheet_and_a_few_faces_keep_their_winding():
    sheet = trimesh.creation.box(extents=(1.0, 1.0, 1e-4))  # encloses next to nothing for its area
    V, F = np.asarray(sheet.vertices), np.asarray(sheet.faces)[:, ::-1]
    G, turned = orient_outward(V, F)
    assert turned == 0 and np.array_equal(G, F)
    ball = trimesh.creation.icosphere(subdivisions=5)  # 20,480 faces: one reversed face is under 0.1%
    V, F = np.asarray(ball.vertices), np.asarray(ball.faces).copy()
    F[7] = F[7, ::-1]
    G, turned = orient_outward(V, F)
    assert turned == 0 and np.array_equal(G, F)
    assert orient_outward(V, F[:0])[1] == 0
