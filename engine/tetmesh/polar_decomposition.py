"""Batched polar decomposition into proper rotations and symmetric stretches."""

from __future__ import annotations

import numpy as np

from engine.jit import compiled

# A gradient whose determinant is below this share of its scale cubed (an inverted element, or a
# nearly flat one) is split by the SVD, which says which way the smallest stretch points.
NEWTON_LEAST_DET = 1e-6
NEWTON_STEPS = 40  # at most; a well-conditioned gradient takes 5-8, the last one a polish


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
    ``R`` is the orthogonal factor of ``F``, the rotation closest to it. Where ``det F`` is
    positive and not small against ``F``'s scale (``NEWTON_LEAST_DET``: almost every tet of a
    body), it is found by Newton's iteration with determinant scaling, ``X <- (g X + X^-T / g) / 2``
    with ``g = |det X|^(-1/3)`` (Higham, "Computing the polar decomposition", 1986), compiled, one
    matrix at a time: about 8 times faster than a batched LAPACK SVD of 3 x 3 matrices (17 ms
    against 145 ms for 20,000 gradients near the identity, 0.5% of them inverted), and orthogonal
    to rounding. Elsewhere, batched SVD ``F = U diag(s) W^T``; ``R = U W^T`` and
    ``S = W diag(s) W^T``, and where ``det(U W^T) < 0`` (an inverted element, or an indefinite
    sign in a near-degenerate one) the singular vector of the smallest singular value is
    flipped, so ``R`` stays a rotation and ``S`` takes one negative eigenvalue: the rotation
    closest to ``F`` with ``F = R S`` exact. ``S = R^T F``, symmetrised, either way. This is the
    rotation / stretch split of the non-linear blend, Casas et al. 2012, section 4.1.
    """
    F = np.asarray(F, dtype=np.float64)
    if F.shape[-2:] != (3, 3):
        raise ValueError(f"F must have shape (..., 3, 3), got {F.shape}")
    shape = F.shape
    flat = np.ascontiguousarray(F.reshape(-1, 3, 3))
    R = np.empty_like(flat)
    S = np.empty_like(flat)
    by_svd = np.zeros(len(flat), dtype=np.bool_)
    if len(flat):
        _newton_polar(flat, R, S, by_svd, NEWTON_LEAST_DET, NEWTON_STEPS)
    if by_svd.any():
        R[by_svd], S[by_svd] = _svd_polar(flat[by_svd])
    return R.reshape(shape), S.reshape(shape)


def _svd_polar(F):
    """The polar factors of (m, 3, 3) ``F`` by batched SVD, the smallest stretch flipped where
    ``det F < 0`` (see :func:`polar_decomposition`)."""
    U, s, Wt = np.linalg.svd(F)
    flip = np.linalg.det(U) * np.linalg.det(Wt) < 0
    if np.any(flip):
        U[flip, :, 2] *= -1.0  # numpy sorts singular values descending: column 2 is smallest
        s[flip, 2] *= -1.0
    R = U @ Wt
    S = np.swapaxes(Wt, -1, -2) @ (s[..., :, None] * Wt)
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    return R, S


@compiled
def _newton_polar(F, R, S, by_svd, least_det, steps):  # pragma: no cover (compiled; tested through polar_decomposition)
    X = np.empty((3, 3))
    C = np.empty((3, 3))
    for i in range(F.shape[0]):
        scale = 0.0
        for a in range(3):
            for b in range(3):
                X[a, b] = F[i, a, b]
                scale += F[i, a, b] * F[i, a, b]
        scale = (scale / 3.0) ** 1.5  # the cube of the mean column length
        det = (X[0, 0] * (X[1, 1] * X[2, 2] - X[1, 2] * X[2, 1]) - X[0, 1] * (X[1, 0] * X[2, 2] - X[1, 2] * X[2, 0])
               + X[0, 2] * (X[1, 0] * X[2, 1] - X[1, 1] * X[2, 0]))
        if not det > least_det * scale:
            by_svd[i] = True
            continue
        polish = False
        done = False
        for _ in range(steps):
            # C = the cofactors of X, so X^-T = C / det X
            C[0, 0] = X[1, 1] * X[2, 2] - X[1, 2] * X[2, 1]
            C[0, 1] = X[1, 2] * X[2, 0] - X[1, 0] * X[2, 2]
            C[0, 2] = X[1, 0] * X[2, 1] - X[1, 1] * X[2, 0]
            C[1, 0] = X[0, 2] * X[2, 1] - X[0, 1] * X[2, 2]
            C[1, 1] = X[0, 0] * X[2, 2] - X[0, 2] * X[2, 0]
            C[1, 2] = X[0, 1] * X[2, 0] - X[0, 0] * X[2, 1]
            C[2, 0] = X[0, 1] * X[1, 2] - X[0, 2] * X[1, 1]
            C[2, 1] = X[0, 2] * X[1, 0] - X[0, 0] * X[1, 2]
            C[2, 2] = X[0, 0] * X[1, 1] - X[0, 1] * X[1, 0]
            det = X[0, 0] * C[0, 0] + X[0, 1] * C[0, 1] + X[0, 2] * C[0, 2]
            if not det > 0.0:
                break
            g = 1.0 if polish else det ** (-1.0 / 3.0)
            change = 0.0
            for a in range(3):
                for b in range(3):
                    y = 0.5 * (g * X[a, b] + C[a, b] / (g * det))
                    change += abs(y - X[a, b])
                    X[a, b] = y
            if polish:
                done = True
                break
            if change <= 1e-12:
                polish = True  # one more, unscaled step: quadratic convergence takes it to rounding
        if not done:
            by_svd[i] = True
            continue
        for a in range(3):
            for b in range(3):
                R[i, a, b] = X[a, b]
        for a in range(3):
            for b in range(a, 3):
                sab = 0.0
                sba = 0.0
                for k in range(3):
                    sab += X[k, a] * F[i, k, b]
                    sba += X[k, b] * F[i, k, a]
                S[i, a, b] = S[i, b, a] = 0.5 * (sab + sba)
