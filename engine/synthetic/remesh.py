"""Independent re-meshing of a frame, as multi-view reconstruction gives.

Each frame's true surface is subdivided, its vertices slid along random edges (staying on the
surface), decimated with quadric error metrics to a random vertex count, projected back onto the
true surface and perturbed along the normal by reconstruction noise. The result has its own
vertex count and connectivity, lies within the noise of the true surface, and carries colours
interpolated from the true surface.
"""

from __future__ import annotations

import fast_simplification
import numpy as np
import scipy.sparse as sp

from engine.surface import SurfaceQuery, vertex_normals


def subdivide(V, F, colors=None):
    """Midpoint subdivision: every triangle into four, the shape unchanged (a denser capture of
    the same surface). Returns (V, F, colors): with per-vertex ``colors`` a midpoint takes the
    mean colour of its edge's ends; without, colors is None."""
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    mid = len(V) + inverse.reshape(3, -1).T  # (m, 3): midpoints of edges 01, 12, 20
    V2 = np.concatenate([V, 0.5 * (V[unique[:, 0]] + V[unique[:, 1]])])
    a, b, c = F[:, 0], F[:, 1], F[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    F2 = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                         np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
    if colors is None:
        return V2, F2, None
    colors = np.asarray(colors)
    mixed = 0.5 * (colors[unique[:, 0]].astype(np.float64) + colors[unique[:, 1]])
    return V2, F2, np.concatenate([colors, mixed.astype(colors.dtype)])


def _is_closed_manifold(F):
    """Every undirected edge is used by exactly two faces, once in each direction."""
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    if len(np.unique(directed, axis=0)) != len(directed):
        return False
    undirected, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    return bool(np.all(counts == 2))


def remesh_frame(V, F, colors=None, *, seed=0, vertex_ratio=(0.85, 1.15), noise=0.001, attempts=4):
    """Re-mesh one frame independently of its template connectivity.

    Parameters
    ----------
    V : (n, 3) float array   true surface of the frame
    F : (m, 3) int array     its triangles (closed, outward oriented)
    colors : (n, 3) float array or None   per-vertex colours to carry over
    seed : int
    vertex_ratio : (low, high)   the new vertex count is n times a uniform draw in this range
    noise : float            standard deviation (m) of the normal displacement

    Returns
    -------
    V_new : (k, 3) float array
    F_new : (l, 3) int array     closed, outward oriented
    colors_new : (k, 3) float array or None

    Notes
    -----
    Quadric decimation occasionally leaves a non-manifold edge; such an attempt is redrawn with
    less sliding (the last attempt slides nothing).
    """
    rng = np.random.default_rng(seed)
    V = np.asarray(V, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    query = SurfaceQuery(V, F)
    for attempt in range(attempts):
        slide = 0.12 * 0.5**attempt if attempt < attempts - 1 else 0.0  # last try: no sliding
        Vs, Fs, _ = subdivide(V, F)
        # Slide every vertex a random fraction along one of its edges: stays on the surface.
        edges = np.concatenate([Fs[:, [0, 1]], Fs[:, [1, 2]], Fs[:, [2, 0]]])
        adjacency = sp.csr_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(Vs),) * 2)
        adjacency.sum_duplicates()
        degree = np.diff(adjacency.indptr)
        pick = adjacency.indices[adjacency.indptr[:-1] + rng.integers(0, degree)]
        Vs = Vs + rng.uniform(0.0, slide, (len(Vs), 1)) * (Vs[pick] - Vs)  # more can fold triangles
        target_vertices = int(round(len(V) * rng.uniform(*vertex_ratio)))
        Vd, Fd = fast_simplification.simplify(Vs, Fs, target_count=2 * target_vertices - 4, agg=7.0)
        Vd, Fd = np.asarray(Vd, dtype=float), np.asarray(Fd, dtype=np.int64)
        used = np.unique(Fd)
        if len(used) != len(Vd):
            remap = np.full(len(Vd), -1)
            remap[used] = np.arange(len(used))
            Vd, Fd = Vd[used], remap[Fd]
        if _is_closed_manifold(Fd):
            break
    points, faces, bary, _ = query.closest(Vd)
    normals = vertex_normals(points, Fd)
    points = points + rng.normal(0.0, noise, (len(points), 1)) * normals
    new_colors = None
    if colors is not None:
        new_colors = np.einsum("qk,qkc->qc", bary, np.asarray(colors)[F[faces]])
    return points, Fd, new_colors
