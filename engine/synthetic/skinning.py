"""Dual-quaternion skinning (Kavan et al. 2007) of the synthetic body.

Dual quaternions blend rigid joint transforms without the volume collapse of linear blend
skinning at the knees and elbows, which matters for jumps (deep knee flexion).
"""

from __future__ import annotations

import numpy as np

from engine.rotations import matrix_to_quaternion, quaternion_multiply


def skin_dual_quaternion(V_rest, rest_joints, joint_rotations, joint_positions, weight_index, weight):
    """Pose the rest surface with dual-quaternion skinning.

    Parameters
    ----------
    V_rest : (n, 3) float array                rest vertices
    rest_joints : (J, 3) float array           rest joint positions
    joint_rotations : (frames, J, 3, 3) float  world rotation of each joint's segment
    joint_positions : (frames, J, 3) float     world position of each joint
    weight_index : (n, k) int array            influencing joints per vertex
    weight : (n, k) float array                skin weights, rows sum to 1

    Returns
    -------
    V : (frames, n, 3) float array   posed vertices

    Notes
    -----
    Joint j maps a rest point x to R_j (x - rest_j) + p_j. Quaternions of a vertex's influences
    are sign-aligned with its first influence before blending (antipodality).
    """
    R = np.asarray(joint_rotations, dtype=float)
    P = np.asarray(joint_positions, dtype=float)
    frames = R.shape[0]
    q = matrix_to_quaternion(R)  # (frames, J, 4)
    t = P - np.einsum("fjab,jb->fja", R, rest_joints)
    t_quat = np.concatenate([np.zeros(t.shape[:-1] + (1,)), t], axis=-1)
    d = 0.5 * quaternion_multiply(t_quat, q)
    out = np.empty((frames,) + V_rest.shape)
    for f in range(frames):
        qv = q[f][weight_index]  # (n, k, 4)
        dv = d[f][weight_index]
        sign = np.sign(np.einsum("nki,ni->nk", qv, qv[:, 0]))
        sign[sign == 0] = 1.0
        w = weight * sign
        b0 = np.einsum("nk,nki->ni", w, qv)
        be = np.einsum("nk,nki->ni", w, dv)
        norm = np.linalg.norm(b0, axis=1, keepdims=True)
        b0 /= norm
        be /= norm
        w0, v0 = b0[:, :1], b0[:, 1:]
        we, ve = be[:, :1], be[:, 1:]
        x = V_rest
        # Rotate x by the unit quaternion b0, then add the translation of the dual part.
        rotated = x + 2.0 * np.cross(v0, np.cross(v0, x) + w0 * x)
        translation = 2.0 * (w0 * ve - we * v0 + np.cross(v0, ve))
        out[f] = rotated + translation
    return out
