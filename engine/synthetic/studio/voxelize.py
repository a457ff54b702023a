"""Occupancy of closed surfaces on a voxel grid, by signed ray crossings (winding numbers).

Rays run along +z through every (x, y) column of grid points. A triangle whose projection
contains a column crosses it once: entering the solid (+1) where the outward normal faces the
ray's origin, leaving (-1) where it faces away. The running sum of crossings along a column is
the winding number of each grid point, so a point inside any of several closed, outward
oriented components, even interpenetrating ones (a hand pushed into a hip, a leg through a
skirt), is occupied: the occupancy of their union.
"""

from __future__ import annotations

import numpy as np

_JITTER = np.array([0.318309886, 0.207879576])  # columns sit this fraction of a cell off the grid


def grid_for(V, spacing, margin):
    """A grid covering points V with ``margin`` cells to spare: origin (3,), shape (3,)."""
    lo = np.floor(V.min(axis=0) / spacing) * spacing - margin * spacing
    hi = V.max(axis=0) + margin * spacing
    shape = np.ceil((hi - lo) / spacing).astype(int) + 1
    return lo, tuple(int(s) for s in shape)


def occupancy(V, F, origin, spacing, shape):
    """Which grid points lie inside the closed, outward-oriented surface (V, F).

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array     closed components, outward oriented (interpenetration allowed)
    origin : (3,) float      position of grid point (0, 0, 0)
    spacing : float          grid step (same on every axis)
    shape : (nx, ny, nz)

    Returns
    -------
    inside : (nx, ny, nz) bool array

    Notes
    -----
    Edge functions are evaluated once per undirected edge orientation (from the lower vertex
    index), so two triangles sharing an edge never both claim, or both miss, a column; columns
    are offset from the grid by an irrational fraction of a cell so none passes exactly through
    a vertex. A column whose crossings do not sum to zero (a surface that is not closed) is left
    empty.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    nx, ny, nz = shape
    xy = (V[:, :2] - origin[:2]) / spacing - _JITTER  # column (i, j) sits at integer coordinates
    z = (V[:, 2] - origin[2]) / spacing
    A, B, C = xy[F[:, 0]], xy[F[:, 1]], xy[F[:, 2]]
    area = (B[:, 0] - A[:, 0]) * (C[:, 1] - A[:, 1]) - (B[:, 1] - A[:, 1]) * (C[:, 0] - A[:, 0])
    keep = area != 0
    F, A, B, C, area = F[keep], A[keep], B[keep], C[keep], area[keep]
    lo = np.ceil(np.minimum(np.minimum(A, B), C)).astype(np.int64)
    hi = np.floor(np.maximum(np.maximum(A, B), C)).astype(np.int64)
    width = hi - lo + 1
    hits_index, hits_sign = [], []
    orientation = np.sign(area)
    for di in range(int(width[:, 0].max(initial=0))):
        rows = np.flatnonzero(width[:, 0] > di)
        for dj in range(int(width[rows, 1].max(initial=0))):
            t = rows[width[rows, 1] > dj]
            i, j = lo[t, 0] + di, lo[t, 1] + dj
            p = np.stack([i, j], axis=1).astype(np.float64)
            e = [_edge(xy, F[t, a], F[t, b], p) for a, b in ((1, 2), (2, 0), (0, 1))]
            o = orientation[t]
            inside = (e[0] * o > 0) & (e[1] * o > 0) & (e[2] * o > 0)
            inside &= (i >= 0) & (i < nx) & (j >= 0) & (j < ny)
            if not np.any(inside):
                continue
            t, i, j = t[inside], i[inside], j[inside]
            weights = np.stack([e[0][inside], e[1][inside], e[2][inside]], axis=1) / area[t, None]
            depth = np.einsum("nk,nk->n", weights, z[F[t]])
            k = np.clip(np.ceil(depth), 0, nz).astype(np.int64)
            hits_index.append((i * ny + j) * (nz + 1) + k)
            hits_sign.append(-orientation[t])
    if not hits_index:
        return np.zeros(shape, dtype=bool)
    crossings = np.bincount(np.concatenate(hits_index), weights=np.concatenate(hits_sign),
                            minlength=nx * ny * (nz + 1)).reshape(nx, ny, nz + 1)
    winding = np.cumsum(crossings, axis=2)
    broken = np.abs(winding[:, :, -1]) > 0.5
    inside = winding[:, :, :nz] > 0.5
    inside[broken] = False
    return inside


def _edge(xy, a, b, p):
    """Edge function of directed edges a -> b at points p, computed from the lower index."""
    swap = a > b
    lo, hi = np.where(swap, b, a), np.where(swap, a, b)
    P, Q = xy[lo], xy[hi]
    value = (Q[:, 0] - P[:, 0]) * (p[:, 1] - P[:, 1]) - (Q[:, 1] - P[:, 1]) * (p[:, 0] - P[:, 0])
    return np.where(swap, -value, value)
