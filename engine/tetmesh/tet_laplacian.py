"""Volumetric (tetrahedral) Laplacian."""

from __future__ import annotations

from .tet_gradient import tet_gradient
from .tet_mass import tet_mass


def tet_laplacian(V, T):
    """Volume-weighted Laplacian ``L = G^T D G`` of a tetrahedral mesh.

    Parameters
    ----------
    V : (k, 3) float array   tet-mesh vertex positions (no degenerate tets)
    T : (t, 4) int array     tetrahedra

    Returns
    -------
    L : (k, k) scipy.sparse.csr_matrix, float64
        Symmetric positive semi-definite, rows sum to zero; ``x^T L x`` is the Dirichlet
        energy ``sum_i |tet_i| |grad x|^2`` of the piecewise-linear function ``x``.

    Notes
    -----
    Casas et al. 2012, eq. (2): ``L = G^T D G`` with ``G`` the tetrahedron gradient operator
    (:func:`tet_gradient`) and ``D`` the diagonal of tet volumes, each repeated three times
    (:func:`tet_mass`). Same sign convention as a stiffness matrix (positive diagonal).
    """
    G = tet_gradient(V, T)
    D = tet_mass(V, T)
    L = (G.T @ D @ G).tocsr()
    L = 0.5 * (L + L.T)  # exact symmetry despite rounding in the products
    L.sum_duplicates()
    return L.tocsr()
