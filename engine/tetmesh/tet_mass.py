"""Per-gradient-row volume weights of a tetrahedral mesh."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .tet_volumes import tet_volumes


def tet_mass(V, T):
    """Diagonal matrix ``D`` of tet volumes, each repeated three times (one per gradient row).

    Parameters
    ----------
    V : (k, 3) float array
    T : (t, 4) int array

    Returns
    -------
    D : (3t, 3t) scipy.sparse.dia_matrix, float64   ``|vol_i|`` at rows ``3*i .. 3*i + 2``

    Notes
    -----
    The ``D`` of Casas et al. 2012, eq. (2). Absolute volumes, so either orientation works.
    """
    return sp.diags(np.repeat(np.abs(tet_volumes(V, T)), 3))
