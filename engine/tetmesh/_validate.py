"""Input checks shared by the tet-mesh functions (clear ``ValueError`` on bad input)."""

from __future__ import annotations

import numpy as np


def as_vertices(V, name="V"):
    """``V`` as a C-contiguous (n, 3) float64 array of finite values, else ``ValueError``."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {V.shape}")
    if not np.all(np.isfinite(V)):
        raise ValueError(f"{name} has {int(np.sum(~np.isfinite(V)))} non-finite coordinates")
    return V


def as_tets(T, n_vertices, name="T"):
    """``T`` as a C-contiguous (t, 4) int64 array of indices below ``n_vertices``."""
    T = np.asarray(T)
    if T.ndim != 2 or T.shape[1] != 4:
        raise ValueError(f"{name} must have shape (t, 4), got {T.shape}")
    if T.size and not np.issubdtype(T.dtype, np.integer):
        raise ValueError(f"{name} must hold integer vertex indices, got dtype {T.dtype}")
    T = np.ascontiguousarray(T, dtype=np.int64)
    if T.size and (T.min() < 0 or T.max() >= n_vertices):
        raise ValueError(f"{name} indexes vertices outside 0..{n_vertices - 1} "
                         f"(min {T.min()}, max {T.max()})")
    return T


def edge_matrices(V, T):
    """(t, 3, 3) matrices whose columns are the edges x1 - x0, x2 - x0, x3 - x0 of each tet."""
    x0 = V[T[:, 0]]
    return np.stack([V[T[:, 1]] - x0, V[T[:, 2]] - x0, V[T[:, 3]] - x0], axis=-1)


def inverse_edge_matrices(V, T, name="V"):
    """Inverses of :func:`edge_matrices`, or a ``ValueError`` naming the degenerate tets."""
    E = edge_matrices(V, T)
    det = np.linalg.det(E)
    scale = np.einsum("tij,tij->t", E, E) ** 1.5  # ~ edge length cubed
    bad = np.flatnonzero(np.abs(det) <= 1e-14 * np.maximum(scale, np.finfo(float).tiny))
    if bad.size:
        raise ValueError(f"{name}: {bad.size} degenerate (zero-volume) tetrahedra, e.g. tet {bad[0]}")
    return np.linalg.inv(E)
