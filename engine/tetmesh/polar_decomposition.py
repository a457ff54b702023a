"""Batched polar decomposition into proper rotations and symmetric stretches."""

from __future__ import annotations

import numpy as np


def polar_decomposition(F):
    """Split matrices into a proper rotation times a symmetric matrix, ``F = R S``.

    Parameters
    ----------
    F : (..., 3, 3) float array   e.g. per-tet deformation gradients

    Returns
    -------
    R : (..., 3, 3) float64 array   proper rotations (orthogonal, ``det R = +1``)
    S : (..., 3, 3) float64 array   symmetric; positive semi-definite when ``det F >= 0``

    Notes
    -----
    Batched SVD ``F = U diag(s) W^T``; ``R = U W^T`` and ``S = W diag(s) W^T``. Where
    ``det(U W^T) < 0`` (an inverted element, or an indefinite sign in a near-degenerate
    one) the singular vector of the smallest singular value is flipped, so ``R`` stays a
    rotation and ``S`` takes one negative eigenvalue: the rotation closest to ``F`` with
    ``F = R S`` exact. This is the rotation / stretch split of the non-linear blend,
    Casas et al. 2012, section 4.1.
    """
    F = np.asarray(F, dtype=np.float64)
    if F.shape[-2:] != (3, 3):
        raise ValueError(f"F must have shape (..., 3, 3), got {F.shape}")
    U, s, Wt = np.linalg.svd(F)
    flip = np.linalg.det(U) * np.linalg.det(Wt) < 0
    if np.any(flip):
        U[flip, :, 2] *= -1.0  # numpy sorts singular values descending: column 2 is smallest
        s[flip, 2] *= -1.0
    R = U @ Wt
    S = np.swapaxes(Wt, -1, -2) @ (s[..., :, None] * Wt)
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    return R, S
