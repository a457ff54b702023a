"""Barycentric embedding of points (a surface) in a tetrahedral mesh."""

from __future__ import annotations

from itertools import chain

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ._validate import as_tets, as_vertices, inverse_edge_matrices
from .boundary_faces import boundary_faces

_INSIDE_TOL = 1e-10  # barycentric coordinates down to -1e-10 count as inside
_CHUNK = 16384       # points per vectorised block (bounds temporary memory)


def embed_barycentric(P, V_tet, T):
    """Sparse matrix giving points as barycentric combinations of tet-mesh vertices.

    Parameters
    ----------
    P : (n, 3) float array       points to embed, e.g. the rest surface vertices
    V_tet : (k, 3) float array   tet-mesh vertices (no degenerate tets)
    T : (t, 4) int array         tetrahedra

    Returns
    -------
    B : (n, k) scipy.sparse.csr_matrix, float64
        Exactly 4 stored entries per row (the vertices of one tet, sorted), rows sum to 1,
        and ``B @ V_tet == P`` up to rounding, for every point, inside or not. After the tet
        mesh deforms to ``X``, ``B @ X`` moves each point with the affine map of its tet.

    Notes
    -----
    DESIGN.md step 7: the tet vertices are lattice points, not the surface vertices, so the
    surface rides on the tet mesh (Casas et al. 2012, section 4.1, blends per tetrahedron). Points outside the
    tet mesh (the tet boundary only approximates the surface, to within about a lattice cell)
    use the *extrapolated* coordinates of the closest tet, some slightly negative, rather
    than clamped ones: extrapolation reproduces the rest points exactly and still follows
    that tet's affine motion, whereas clamping would snap them onto the boundary. See
    :func:`tet_barycentric` for the tets and the distances outside.
    """
    P = as_vertices(P, "P")
    V_tet = as_vertices(V_tet, "V_tet")
    T = as_tets(T, len(V_tet))
    tet_index, W, _ = tet_barycentric(P, V_tet, T)
    cols = T[tet_index]
    order = np.argsort(cols, axis=1)
    cols = np.take_along_axis(cols, order, axis=1)
    W = np.take_along_axis(W, order, axis=1)
    indptr = np.arange(0, 4 * len(P) + 1, 4)
    return sp.csr_matrix((W.ravel(), cols.ravel(), indptr), shape=(len(P), len(V_tet)))


def tet_barycentric(P, V_tet, T, *, k_nearest=8):
    """The tet containing (or closest to) each point and the point's barycentric coordinates.

    Parameters
    ----------
    P : (n, 3) float array       query points
    V_tet : (k, 3) float array   tet-mesh vertices (no degenerate tets)
    T : (t, 4) int array         tetrahedra
    k_nearest : int              tets (by nearest centroid) tested per point before the
                                 slower searches; a tuning knob, not a correctness one

    Returns
    -------
    tet_index : (n,) int64 array   the tet used for each point
    W : (n, 4) float64 array       coordinates w.r.t. ``T[tet_index]``: rows sum to 1 and
                                   ``sum_j W[:, j, None] * V_tet[T[tet_index, j]] == P``;
                                   all >= -1e-10 for points inside the tet mesh
    distance : (n,) float64 array  0 for points found inside a tet, otherwise the distance
                                   from the point to the tet mesh (to its boundary)

    Notes
    -----
    Candidates are the ``k_nearest`` tets by centroid (a k-d tree), tested vectorised. For
    the points in none of them the exactly closest boundary triangle is found; points on
    its outer side are outside the tet mesh, the others get ``4 * k_nearest`` candidates.
    Points still in no tet take the tet that owns their closest boundary triangle, with
    extrapolated coordinates (see :func:`embed_barycentric`).
    """
    P = as_vertices(P, "P")
    V_tet = as_vertices(V_tet, "V_tet")
    T = as_tets(T, len(V_tet))
    if len(T) == 0:
        raise ValueError("T has no tetrahedra")
    n = len(P)
    x0 = V_tet[T[:, 0]]
    Einv = inverse_edge_matrices(V_tet, T, "V_tet")
    tree = cKDTree(V_tet[T].mean(axis=1))

    tet_index = np.full(n, -1, dtype=np.int64)
    W = np.zeros((n, 4))
    distance = np.zeros(n)

    def search(points, k):
        for start in range(0, len(points), _CHUNK):
            chunk = points[start:start + _CHUNK]
            found, tets, coords = _search_candidates(P[chunk], tree, min(k, len(T)), x0, Einv)
            tet_index[chunk[found]] = tets[found]
            W[chunk[found]] = coords[found]
        return points[tet_index[points] < 0]

    missed = search(np.arange(n), k_nearest)
    if len(missed):
        owner, gap, side = _closest_boundary_tets(P[missed], V_tet, T)
        search(missed[side <= 0], 4 * k_nearest)  # not certainly outside: look wider
        still = tet_index[missed] < 0
        missed, owner, gap, side = missed[still], owner[still], gap[still], side[still]
        tet_index[missed] = owner
        W[missed] = _coordinates(P[missed], x0[owner], Einv[owner])
        distance[missed] = np.where(side < 0, 0.0, gap)
    return tet_index, W, distance


def _coordinates(points, x0, Einv):
    """(m, 4) barycentric coordinates of points w.r.t. tets given by x0 (m, 3), Einv (m, 3, 3)."""
    lam = np.einsum("...ij,...j->...i", Einv, points - x0)
    return np.concatenate([1.0 - lam.sum(axis=-1, keepdims=True), lam], axis=-1)


def _search_candidates(points, tree, k, x0, Einv):
    """Test the ``k`` tets with the nearest centroids; the most-inside one wins if inside."""
    _, candidates = tree.query(points, k=k, workers=-1)
    candidates = candidates.reshape(len(points), k)
    coords = _coordinates(points[:, None, :], x0[candidates], Einv[candidates])  # (m, k, 4)
    score = coords.min(axis=-1)
    best = np.argmax(score, axis=1)
    rows = np.arange(len(points))
    found = score[rows, best] >= -_INSIDE_TOL
    return found, candidates[rows, best], coords[rows, best]


def _closest_boundary_tets(points, V_tet, T):
    """Closest boundary triangles of ``points``: owner tets, exact distances and sides.

    Returns ``owner`` (m,) tets, ``distance`` (m,) and ``side`` (m,): +1 where the point is
    certainly outside the tet mesh, -1 certainly inside, 0 when undecided (the closest point
    is on a triangle's edge or corner, where one face normal cannot tell).

    The nearest triangle centroid gives an upper bound ``d`` on the distance; any closer
    triangle has its centroid within ``d + r`` (``r``: its centroid-to-corner radius). The
    triangles are grouped by radius in powers of two, one k-d tree per group, so that a few
    large triangles do not widen the search around the many small ones.
    """
    Fb, owner = boundary_faces(T)
    A, B, C = V_tet[Fb[:, 0]], V_tet[Fb[:, 1]], V_tet[Fb[:, 2]]
    centroid = (A + B + C) / 3.0
    radius = np.sqrt(np.max([np.sum((X - centroid) ** 2, axis=1) for X in (A, B, C)], axis=0))
    _, nearest = cKDTree(centroid).query(points, workers=-1)
    bound = _point_triangle_distance(points, A[nearest], B[nearest], C[nearest]) * (1 + 1e-9)

    group = np.floor(np.log2(radius / radius.min())).astype(np.int64)
    which, faces = [], []
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        lists = cKDTree(centroid[members]).query_ball_point(
            points, bound + radius[members].max(), workers=-1, return_sorted=False)
        counts = np.fromiter(map(len, lists), dtype=np.int64, count=len(points))
        which.append(np.repeat(np.arange(len(points)), counts))
        faces.append(members[np.fromiter(chain.from_iterable(lists), dtype=np.int64, count=counts.sum())])
    which, faces = np.concatenate(which), np.concatenate(faces)
    near = np.linalg.norm(points[which] - centroid[faces], axis=1) <= bound[which] + radius[faces]
    which, faces = which[near], faces[near]

    d = _point_triangle_distance(points[which], A[faces], B[faces], C[faces])
    order = np.lexsort((d, which))  # by point, then by distance: first of each point wins
    best = faces[order[np.searchsorted(which[order], np.arange(len(points)))]]
    a, b, c = A[best], B[best], C[best]
    distance, closest, interior = _point_triangle_distance(points, a, b, c, full=True)
    offset = np.einsum("ij,ij->i", points - closest, np.cross(b - a, c - a))
    side = np.where(interior & (distance > 0), np.sign(offset), 0.0).astype(np.int64)
    return owner[best], distance, side


def _point_triangle_distance(P, A, B, C, full=False):
    """(m,) distances from points P to triangles (A, B, C), all (m, 3) (Ericson's regions).

    With ``full``, also the (m, 3) closest points and an (m,) mask of those that lie in the
    interior of their triangle (not on an edge or a corner).
    """
    def dot(x, y):
        return np.einsum("ij,ij->i", x, y)

    ab, ac, ap, bp, cp = B - A, C - A, P - A, P - B, P - C
    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        closest = A + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]  # interior
        # Overwrite with the vertex / edge regions, lowest priority first (an edge region needs the
        # edge: a face that repeats a corner is the segment between its other two).
        regions = [
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0) & ((d4 - d3) + (d5 - d6) > 0),
             lambda: B + (C - B) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0) & (d2 - d6 > 0), lambda: A + ac * (d2 / (d2 - d6))[:, None]),
            ((d6 >= 0) & (d5 <= d6), lambda: C),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0) & (d1 - d3 > 0), lambda: A + ab * (d1 / (d1 - d3))[:, None]),
            ((d3 >= 0) & (d4 <= d3), lambda: B),
            ((d1 <= 0) & (d2 <= 0), lambda: A),
        ]
        interior = np.ones(len(P), dtype=bool)
        for mask, point in regions:
            if np.any(mask):
                closest[mask] = point()[mask]
                interior &= ~mask
    distance = np.linalg.norm(P - closest, axis=1)
    return (distance, closest, interior) if full else distance
