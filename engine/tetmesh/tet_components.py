"""Connected parts of a tet mesh: vertices joined through shared tetrahedra."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def tet_components(T, n_vertices):
    """The parts of a tet mesh that share no vertex with each other.

    Parameters
    ----------
    T : (t, 4) int array     n_vertices : int   (a vertex no tet uses is a part of its own)

    Returns
    -------
    count : int     label : (n_vertices,) int   the part of every vertex
    """
    T = np.asarray(T, dtype=np.int64)
    rows = np.repeat(T, 4, axis=1).ravel()
    cols = np.tile(T, (1, 4)).ravel()
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(int(n_vertices),) * 2)
    return connected_components(graph, directed=False)
