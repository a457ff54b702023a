"""Gradient operator of piecewise-linear functions on a tetrahedral mesh."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ._validate import as_tets, as_vertices, inverse_edge_matrices


def tet_gradient(V, T):
    """Sparse matrix taking per-vertex values to the constant gradient in each tetrahedron.

    Parameters
    ----------
    V : (k, 3) float array   tet-mesh vertex positions (no degenerate tets)
    T : (t, 4) int array     tetrahedra

    Returns
    -------
    G : (3t, k) scipy.sparse.csr_matrix, float64
        Rows ``3*i``, ``3*i + 1``, ``3*i + 2`` are d/dx, d/dy, d/dz in tet ``i`` (12 non-zeros
        per tet, each row sums to zero). For vertex positions ``X`` (k, 3), the block
        ``(G @ X)[3*i:3*i+3]`` is the transpose of tet ``i``'s deformation gradient.

    Raises
    ------
    ValueError
        Bad shapes, out-of-range indices or a zero-volume tet.

    Notes
    -----
    The discrete tetrahedron gradient operator of Casas et al. 2012, section 3.2 (their
    ref. [35]), used for the volumetric Laplacian ``L = G^T D G`` of eq. (2). With the edge
    matrix ``E = [x1 - x0, x2 - x0, x3 - x0]`` the gradient of a linear function is
    ``E^{-T} [f1 - f0, f2 - f0, f3 - f0]``; orientation does not matter.
    """
    V = as_vertices(V, "V")
    T = as_tets(T, len(V))
    Einv_T = np.swapaxes(inverse_edge_matrices(V, T), 1, 2)  # (t, 3, 3): E^{-T}
    t = len(T)
    values = np.empty((t, 3, 4))
    values[:, :, 1:] = Einv_T
    values[:, :, 0] = -Einv_T.sum(axis=2)
    rows = np.broadcast_to(np.arange(3 * t).reshape(t, 3, 1), (t, 3, 4))
    cols = np.broadcast_to(T[:, None, :], (t, 3, 4))
    G = sp.csr_matrix((values.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * t, len(V)))
    G.sum_duplicates()
    return G
