"""Signed volumes of tetrahedra."""

from __future__ import annotations

import numpy as np

from ._validate import as_tets, as_vertices


def tet_volumes(V, T):
    """Signed volume of every tetrahedron.

    Parameters
    ----------
    V : (k, 3) float array   tet-mesh vertex positions
    T : (t, 4) int array     tetrahedra (indices into ``V``)

    Returns
    -------
    volume : (t,) float64 array   ``det[x1 - x0, x2 - x0, x3 - x0] / 6``; positive when
                                  ``x3`` lies on the side of triangle (x0, x1, x2) that its
                                  counter-clockwise normal points to

    Examples
    --------
    >>> V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> tet_volumes(V, [[0, 1, 2, 3]])
    array([0.16666667])
    """
    V = as_vertices(V, "V")
    T = as_tets(T, len(V))
    x0 = V[T[:, 0]]
    e1, e2, e3 = V[T[:, 1]] - x0, V[T[:, 2]] - x0, V[T[:, 3]] - x0
    return np.einsum("ij,ij->i", e1, np.cross(e2, e3)) / 6.0
