"""Triangle-surface measurements and operators shared across the engine.

Model size, enclosed volume and volume centroid, cotangent Laplacian and lumped mass, and
closest points on a surface (with barycentric coordinates).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from engine.nearest import PointTree

FLAT_PIECE = 0.01   # orient_outward: a piece enclosing less than this times area^1.5 is a sheet
FEW_FACES = 0.001   # orient_outward: this share of faces or fewer to turn leaves the mesh as it is


def model_size(V):
    """Largest extent of the axis-aligned bounding box (DESIGN.md: "model size").

    Parameters
    ----------
    V : (n, 3) float array

    Returns
    -------
    size : float
    """
    V = np.asarray(V, dtype=float)
    return float(np.max(V.max(axis=0) - V.min(axis=0)))


def enclosed_volume(V, F):
    """Signed volume enclosed by a closed, outward-oriented triangle surface.

    Parameters
    ----------
    V : (n, 3) or (frames, n, 3) float array
    F : (m, 3) int array

    Returns
    -------
    volume : float or (frames,) float array
    """
    V = np.asarray(V, dtype=float)
    a, b, c = V[..., F[:, 0], :], V[..., F[:, 1], :], V[..., F[:, 2], :]
    return np.einsum("...i,...i->...", a, np.cross(b, c)).sum(axis=-1) / 6.0


def volume_centroid(V, F):
    """Centre of mass of the solid bounded by a closed surface, at uniform density.

    Parameters
    ----------
    V : (n, 3) or (frames, n, 3) float array
    F : (m, 3) int array   outward oriented, closed

    Returns
    -------
    c : (3,) or (frames, 3) float array

    Notes
    -----
    Sum over the signed tetrahedra (origin, a, b, c): each contributes volume det/6 at centroid
    (a + b + c) / 4. Used as the body's centre of mass for jump height and distance.
    """
    V = np.asarray(V, dtype=float)
    a, b, c = V[..., F[:, 0], :], V[..., F[:, 1], :], V[..., F[:, 2], :]
    vol = np.einsum("...i,...i->...", a, np.cross(b, c)) / 6.0
    centre = (a + b + c) / 4.0
    return np.einsum("...f,...fi->...i", vol, centre) / vol.sum(axis=-1)[..., None]


def surface_area(V, F):
    """Total area of the triangles F (m, 3) over vertices V (n, 3), as a float."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    return 0.5 * float(np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum())


def face_normals(V, F):
    """Unit face normals (m, 3) of an (n, 3) vertex array."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


def vertex_normals(V, F):
    """Area-weighted unit vertex normals (n, 3)."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    out = np.zeros_like(V, dtype=float)
    for k in range(3):
        np.add.at(out, F[:, k], n)
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.where(length > 0, length, 1.0)


def cotangent_laplacian(V, F):
    """Cotangent Laplacian of a triangle mesh (positive semi-definite convention).

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array

    Returns
    -------
    L : (n, n) scipy.sparse.csr_matrix   L[i, j] = -(cot a + cot b) / 2, rows sum to zero
    """
    n = len(V)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = F[:, (k + 1) % 3], F[:, (k + 2) % 3], F[:, k]
        u, v = V[i] - V[o], V[j] - V[o]
        cross = np.linalg.norm(np.cross(u, v), axis=1)
        cot = np.einsum("ij,ij->i", u, v) / np.maximum(cross, 1e-12)
        rows += [i, j]
        cols += [j, i]
        vals += [-0.5 * cot, -0.5 * cot]
    W = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n, n)).tocsr()
    return (sp.diags(-np.asarray(W.sum(axis=1)).ravel()) + W).tocsr()


def lumped_mass(V, F):
    """Lumped (barycentric) mass matrix: a third of the incident triangle areas per vertex."""
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    m = np.zeros(len(V))
    for k in range(3):
        np.add.at(m, F[:, k], area / 3.0)
    return sp.diags(m).tocsr()


def closest_on_triangles(P, A, B, C):
    """Closest points on triangles (A, B, C) to points P, all (..., 3); and their barycentrics (..., 3).

    Region tests after Ericson, "Real-Time Collision Detection", section 5.1.5, over any leading
    shape (for (points, candidate faces) the points are broadcast, not repeated), the regions
    chosen by ``np.where`` rather than masked writes.
    """
    ab, ac, ap = B - A, C - A, P - A
    d1, d2 = np.einsum("...j,...j->...", ab, ap), np.einsum("...j,...j->...", ac, ap)
    bp = P - B
    d3, d4 = np.einsum("...j,...j->...", ab, bp), np.einsum("...j,...j->...", ac, bp)
    cp = P - C
    d5, d6 = np.einsum("...j,...j->...", ab, cp), np.einsum("...j,...j->...", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        u = 1.0 - v - w
        # edge and vertex regions override the interior solution, most specific last
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        # an edge region needs the edge (its squared length, the denominator, > 0): a face that repeats a
        # corner is the segment between its other two, which the other regions find
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0) & ((d4 - d3) + (d5 - d6) > 0)
        u, v, w = np.where(m, 0.0, u), np.where(m, 1 - t, v), np.where(m, t, w)
        t = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0) & (d2 - d6 > 0)
        u, v, w = np.where(m, 1 - t, u), np.where(m, 0.0, v), np.where(m, t, w)
        t = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0) & (d1 - d3 > 0)
        u, v, w = np.where(m, 1 - t, u), np.where(m, t, v), np.where(m, 0.0, w)
    for m, corner in (((d6 >= 0) & (d5 <= d6), 2), ((d3 >= 0) & (d4 <= d3), 1), ((d1 <= 0) & (d2 <= 0), 0)):
        u, v, w = (np.where(m, float(corner == 0), u), np.where(m, float(corner == 1), v),
                   np.where(m, float(corner == 2), w))
    bary = np.nan_to_num(np.stack([u, v, w], axis=-1), nan=1.0 / 3.0)
    closest = bary[..., :1] * A + bary[..., 1:2] * B + bary[..., 2:] * C
    return closest, bary


class SurfaceQuery:
    """Closest-point queries against a fixed triangle surface.

    ``query = SurfaceQuery(V, F)`` builds the acceleration structure once;
    ``query.closest(P)`` is the hot path.

    Notes
    -----
    Candidate faces are those incident to the ``k`` nearest surface vertices of each query point,
    which is exact whenever the closest face has a vertex among them; for queries close to the
    surface compared with the edge length (projection, noise, alignment residuals) this holds.
    """

    def __init__(self, V, F, k=8):
        self.V = np.asarray(V, dtype=float)
        self.F = np.asarray(F, dtype=np.int64)
        self.k = int(min(k, len(self.V)))
        self.tree = PointTree(self.V)
        n = len(self.V)
        incidence = sp.csr_matrix(
            (np.ones(3 * len(self.F)), (self.F.ravel(), np.repeat(np.arange(len(self.F)), 3))),
            shape=(n, len(self.F)))
        self._vertex_faces = np.split(incidence.indices, incidence.indptr[1:-1])
        valence = np.diff(incidence.indptr)
        width = int(valence.max())
        self._ring = np.full((n, width), -1, dtype=np.int64)
        for i, faces in enumerate(self._vertex_faces):
            self._ring[i, :len(faces)] = faces

    def closest(self, P):
        """Closest surface points to P.

        Parameters
        ----------
        P : (q, 3) float array

        Returns
        -------
        points : (q, 3) float array      closest points on the surface
        faces : (q,) int array           the face each lies on
        bary : (q, 3) float array        barycentric coordinates in that face
        distance : (q,) float array      Euclidean distance from P
        """
        P = np.asarray(P, dtype=float)
        _, nearest = self.tree.query(P, k=self.k)
        nearest = nearest.reshape(len(P), -1)
        candidates = self._ring[nearest].reshape(len(P), -1)
        q, c = candidates.shape
        valid = candidates >= 0
        flat_faces = np.where(valid, candidates, 0).ravel()
        tri = self.V[self.F[flat_faces]]
        Pq = np.repeat(P, c, axis=0)
        points, bary = closest_on_triangles(Pq, tri[:, 0], tri[:, 1], tri[:, 2])
        dist = np.linalg.norm(points - Pq, axis=1).reshape(q, c)
        dist[~valid] = np.inf
        best = np.argmin(dist, axis=1)
        pick = np.arange(q) * c + best
        return points[pick], flat_faces[pick], bary[pick], dist[np.arange(q), best]


def welded_faces(V, F):
    """The faces with vertices at exactly the same place taken as one (an unwelded export gives
    every face its own corners; a UV seam duplicates its vertices): each stands for the first of
    its twins, and the faces that then repeat a corner are left out. ``F`` itself when no two
    vertices share a place."""
    _, first, inverse = np.unique(V, axis=0, return_index=True, return_inverse=True)
    if len(first) == len(V):
        return F
    F = first[inverse.ravel()][F]
    return F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]


def main_components(V, F, *, min_fraction=0.05):
    """Drop the small disconnected pieces of a surface (floating reconstruction fragments).

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array
    min_fraction : float   a connected piece is kept when its area is at least this fraction of
                           the largest piece's area

    Returns
    -------
    V_kept : (k, 3) float array   the vertices of the kept pieces, in their original order
    F_kept : (l, 3) int64 array   their faces, re-indexed
    kept : (k,) int64 array       original index of each kept vertex (``V_kept == V[kept]``)

    Notes
    -----
    Multi-view reconstructions leave small blobs around the performer (noise, props' shadows,
    a studio's edges); as part of a root mesh they would become part of every aligned frame,
    and as part of a target they attract matches. Pieces connected through a shared vertex
    count as one; vertices at exactly the same position are welded into one first (the first
    of them is kept), so an unwelded triangle soup is one piece again.
    """
    from scipy.sparse.csgraph import connected_components

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = len(V)
    F = welded_faces(V, F)
    rows = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    cols = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    count, label = connected_components(sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)),
                                        directed=False)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    piece_area = np.bincount(label[F[:, 0]], weights=area, minlength=count)
    keep_piece = piece_area >= min_fraction * piece_area.max()
    keep_face = keep_piece[label[F[:, 0]]]
    if keep_face.all() and len(np.unique(F)) == n:
        return V, F, np.arange(n)
    kept = np.unique(F[keep_face])
    index = np.full(n, -1, dtype=np.int64)
    index[kept] = np.arange(len(kept))
    return V[kept], index[F[keep_face]], kept



def orient_outward(V, F):
    """Faces wound consistently, every connected piece facing outward.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array

    Returns
    -------
    F : (m, 3) int64 array   the faces, some with their winding reversed (the same array's
                             values when nothing needed turning)
    turned : int             how many faces were reversed

    Notes
    -----
    Reconstructions do not always wind their faces the way this engine reads them (outward,
    counter-clockwise seen from outside): an exporter with the other handedness reverses every
    face, and a mesh stitched from pieces can mix both. The alignment's matching compares
    normals, so a frame facing inward has no compatible pairs at all (a studio strikes pair:
    0.65% of the model size as wound, 5.4% with the target's faces reversed). Two faces that
    share an edge are consistent when they run along it in opposite directions; the faces of
    each piece (faces joined through edges that exactly two faces share) are made consistent
    with its first face by a breadth-first walk, then the piece is reversed as a whole when
    the volume it encloses is negative (for an open piece, its volume with the holes closed
    by the fan from its centroid, which the holes' rims leave the same sign on a body). A
    piece that encloses next to nothing for its area (a sheet: a fin of doubled faces where a
    reconstruction pinched two surfaces together, volume under 1% of ``area^1.5``; a sphere's
    is 9.4%) has no inside to face away from and keeps its winding. A non-orientable piece
    keeps what the walk gives it; faces joined only through a non-manifold edge count as
    separate pieces. When no more than 0.1% of the faces would turn (the doubled faces of such
    a fin, whose two windings no walk can reconcile), the faces are returned as they are.
    """
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    m = len(F)
    if m == 0:
        return F, 0
    half = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])  # directed edges, face f at f, m + f, 2m + f
    face = np.tile(np.arange(m), 3)
    key = np.minimum(half[:, 0], half[:, 1]) * (len(V) + 1) + np.maximum(half[:, 0], half[:, 1])
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    starts = np.flatnonzero(np.r_[True, key_sorted[1:] != key_sorted[:-1]])
    counts = np.diff(np.r_[starts, len(key_sorted)])
    pair = starts[counts == 2]  # manifold edges: exactly two half-edges
    a, b = order[pair], order[pair + 1]
    same = half[a, 0] == half[b, 0]  # both faces run the edge the same way: one must turn
    fa, fb = face[a], face[b]
    graph = sp.coo_matrix((np.ones(len(fa)), (fa, fb)), shape=(m, m)).tocsr()
    graph = graph + graph.T
    parity = sp.coo_matrix((same.astype(np.int8) + 1, (fa, fb)), shape=(m, m)).tocsr()
    parity = parity + parity.T  # 1: consistent, 2: one must turn
    pieces, piece = connected_components(graph, directed=False)
    state = [False] * m
    for first in np.unique(piece, return_index=True)[1]:  # each piece's first face
        visit, pred = breadth_first_order(graph, int(first), directed=False, return_predecessors=True)
        if len(visit) < 2:
            continue
        child, parent = visit[1:], pred[visit[1:]]
        turn = (np.asarray(parity[child, parent]).ravel() == 2).tolist()
        for f, up, t in zip(child.tolist(), parent.tolist(), turn):
            state[f] = state[up] ^ t
    flip = np.array(state, dtype=bool)
    G = np.where(flip[:, None], F[:, ::-1], F)
    tri = V[G]
    centre = np.zeros((pieces, 3))
    np.add.at(centre, piece, tri.mean(axis=1))
    centre /= np.bincount(piece, minlength=pieces)[:, None]
    rel = tri - centre[piece][:, None, :]
    volume = np.bincount(piece, weights=np.einsum("fi,fi->f", rel[:, 0], np.cross(rel[:, 1], rel[:, 2])),
                         minlength=pieces)
    face_area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    area = np.bincount(piece, weights=face_area, minlength=pieces)
    inward = (volume < 0) & (np.abs(volume) / 6.0 >= FLAT_PIECE * area ** 1.5)
    flip ^= inward[piece]
    turned = int(flip.sum())
    if turned <= FEW_FACES * m:
        return F, 0
    return np.where(flip[:, None], F[:, ::-1], F), turned
