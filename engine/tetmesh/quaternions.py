"""Per-element rotations as unit quaternions and back (for blending rotations).

Quaternions are (w, x, y, z), as in :mod:`engine.rotations`.
"""

from __future__ import annotations

import numpy as np

from ..rotations import matrix_to_quaternion


def rotations_to_quaternions(R):
    """Unit quaternions of rotation matrices, in the hemisphere ``w >= 0``.

    Parameters
    ----------
    R : (..., 3, 3) float array   proper rotations (e.g. ``polar_decomposition(F)[0]``)

    Returns
    -------
    q : (..., 4) float64 array   (w, x, y, z), unit length, ``w >= 0``

    Notes
    -----
    Shepperd's method (:func:`engine.rotations.matrix_to_quaternion`): the largest of
    ``trace, R_xx, R_yy, R_zz`` picks the stable formula, so rotations near 180 degrees are
    accurate. ``q`` and ``-q`` are the same rotation: align signs before averaging
    (Casas et al. 2012, section 4.1, interpolates rotations per element).
    """
    R = np.asarray(R, dtype=np.float64)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"R must have shape (..., 3, 3), got {R.shape}")
    return matrix_to_quaternion(R)


def quaternions_to_rotations(q):
    """Rotation matrices of quaternions (normalised here, so blended quaternions are fine).

    Parameters
    ----------
    q : (..., 4) float array   (w, x, y, z), any non-zero length

    Returns
    -------
    R : (..., 3, 3) float64 array   proper rotations; ``R(q) == R(-q)``

    Raises
    ------
    ValueError
        Wrong shape, or a zero (or non-finite) quaternion.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,):
        raise ValueError(f"q must have shape (..., 4), got {q.shape}")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(norm) & (norm > 0)):
        raise ValueError("q has zero-length or non-finite quaternions")
    w, x, y, z = np.moveaxis(q / norm, -1, 0)
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R
