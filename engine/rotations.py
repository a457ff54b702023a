"""Rotation helpers: axis-angle matrices, frames from a direction and a pole, quaternions.

All functions are vectorised over leading dimensions. Quaternions are (w, x, y, z).
"""

from __future__ import annotations

import numpy as np


def axis_angle_matrix(axis, angle):
    """Rotation matrices for rotations by ``angle`` (radians) about ``axis``.

    Parameters
    ----------
    axis : (..., 3) float array   rotation axes (need not be unit length)
    angle : (...) float array     angles in radians

    Returns
    -------
    R : (..., 3, 3) float array   proper rotations (Rodrigues' formula)
    """
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    axis, angle = np.broadcast_arrays(axis, angle[..., None])
    angle = angle[..., 0]
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    k = axis / np.where(norm > 0, norm, 1.0)
    x, y, z = k[..., 0], k[..., 1], k[..., 2]
    c, s = np.cos(angle), np.sin(angle)
    t = 1.0 - c
    R = np.empty(angle.shape + (3, 3))
    R[..., 0, 0] = c + x * x * t
    R[..., 0, 1] = x * y * t - z * s
    R[..., 0, 2] = x * z * t + y * s
    R[..., 1, 0] = y * x * t + z * s
    R[..., 1, 1] = c + y * y * t
    R[..., 1, 2] = y * z * t - x * s
    R[..., 2, 0] = z * x * t - y * s
    R[..., 2, 1] = z * y * t + x * s
    R[..., 2, 2] = c + z * z * t
    return R


def rot_x(angle):
    """Rotation about +X; a positive angle tilts +Y towards +Z."""
    return axis_angle_matrix(np.array([1.0, 0.0, 0.0]), angle)


def rot_y(angle):
    """Rotation about +Y (yaw); a positive angle turns +Z towards +X (a left turn)."""
    return axis_angle_matrix(np.array([0.0, 1.0, 0.0]), angle)


def rot_z(angle):
    """Rotation about +Z; a positive angle turns +X towards +Y."""
    return axis_angle_matrix(np.array([0.0, 0.0, 1.0]), angle)


def frame_from_direction(direction, pole):
    """Orthonormal frames whose second axis is ``direction`` and third leans to ``pole``.

    Parameters
    ----------
    direction : (..., 3) float array   the frame's y axis (normalised here)
    pole : (..., 3) float array        the z axis is ``pole`` made orthogonal to ``direction``

    Returns
    -------
    B : (..., 3, 3) float array   columns (x, y, z), right handed

    Notes
    -----
    Used to pose a limb segment: the world rotation of a segment is
    ``frame_from_direction(d, p) @ frame_from_direction(d_rest, p_rest).T``, which maps the
    rest bone direction onto ``d`` and keeps the bending plane facing ``p`` (no twist).
    """
    b = np.asarray(direction, dtype=float)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    pole = np.asarray(pole, dtype=float)
    c = pole - np.sum(pole * b, axis=-1, keepdims=True) * b
    c = c / np.linalg.norm(c, axis=-1, keepdims=True)
    a = np.cross(b, c)
    return np.stack([a, b, c], axis=-1)


def matrix_to_quaternion(R):
    """Unit quaternions (w, x, y, z) with w >= 0 for rotation matrices (Shepperd's method).

    Parameters
    ----------
    R : (..., 3, 3) float array

    Returns
    -------
    q : (..., 4) float array
    """
    R = np.asarray(R, dtype=float)
    shape = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    trace = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    diag = np.stack([trace, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    which = np.argmax(diag, axis=1)
    q = np.empty((R.shape[0], 4))
    for case in range(4):
        m = which == case
        if not np.any(m):
            continue
        r = R[m]
        if case == 0:
            s = np.sqrt(1.0 + trace[m]) * 2.0
            q[m] = np.stack([0.25 * s, (r[:, 2, 1] - r[:, 1, 2]) / s,
                             (r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 1, 0] - r[:, 0, 1]) / s], axis=1)
        elif case == 1:
            s = np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2]) * 2.0
            q[m] = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, 0.25 * s,
                             (r[:, 0, 1] + r[:, 1, 0]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s], axis=1)
        elif case == 2:
            s = np.sqrt(1.0 + r[:, 1, 1] - r[:, 0, 0] - r[:, 2, 2]) * 2.0
            q[m] = np.stack([(r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 0, 1] + r[:, 1, 0]) / s,
                             0.25 * s, (r[:, 1, 2] + r[:, 2, 1]) / s], axis=1)
        else:
            s = np.sqrt(1.0 + r[:, 2, 2] - r[:, 0, 0] - r[:, 1, 1]) * 2.0
            q[m] = np.stack([(r[:, 1, 0] - r[:, 0, 1]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s,
                             (r[:, 1, 2] + r[:, 2, 1]) / s, 0.25 * s], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(shape + (4,))


def quaternion_multiply(a, b):
    """Hamilton products a * b of (..., 4) quaternions (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)
