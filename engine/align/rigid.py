"""Rigid motions for the pairwise aligner: rotation fitting, point-to-plane and per-patch steps.

Small batched solvers shared by the rigid start, the patch matching and the as-rigid-as-possible
local steps of :class:`engine.align.pairwise.PairwiseAligner`.
"""

from __future__ import annotations

import numpy as np

from engine.rotations import axis_angle_matrix


def rodrigues(omega):
    """Rotation matrices (q, 3, 3) for rotation vectors (q, 3)."""
    return axis_angle_matrix(omega, np.linalg.norm(omega, axis=-1))


def rotation_fit(F, R0, iterations=4):
    """Rotations closest to matrices F, warm-started from R0 (batched).

    Parameters
    ----------
    F : (t, 3, 3) float array
    R0 : (t, 3, 3) float array   initial rotations (e.g. the previous step's)
    iterations : int

    Returns
    -------
    R : (t, 3, 3) float array

    Notes
    -----
    Müller, Bender, Chentanez, Macklin, "A robust method to extract the rotational part of
    deformations" (MIG 2016): ``omega = sum_i r_i x f_i / (|sum_i r_i . f_i| + eps)`` over the
    columns, ``R <- exp(omega) R``. Each step is a few vectorised products, far cheaper than a
    batched SVD, and a warm start needs only a few steps.
    """
    R = np.array(R0, dtype=np.float64, copy=True)
    for _ in range(iterations):
        cross = np.cross(R, F, axisa=1, axisb=1, axisc=1).sum(axis=2)  # sum over columns
        dot = np.einsum("tij,tij->t", R, F)
        omega = cross / (np.abs(dot) + 1e-9)[:, None]
        R = rodrigues(omega) @ R
    return R


def stack_rotations(R):
    """Rotations (t, 3, 3) stacked transposed into (3t, 3): the right-hand side of the solves."""
    return np.ascontiguousarray(np.swapaxes(R, 1, 2)).reshape(-1, 3)


def kabsch(P, Q, w):
    """Weighted rigid transform (R, t) with R P + t ~ Q."""
    w = w / max(w.sum(), 1e-300)
    cp, cq = w @ P, w @ Q
    H = (P - cp).T @ ((Q - cq) * w[:, None])
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cq - R @ cp


def rotation_set(angles):
    """Rotations by +-angle about the x, y and z axes (degrees): (6 * len(angles), 3, 3)."""
    rotations = []
    for axis in np.eye(3):
        for angle in angles:
            for sign in (1.0, -1.0):
                rotations.append(rodrigues(np.radians(sign * angle) * axis[None])[0])
    return np.array(rotations)


def point_to_plane_step(P, Q, M, w):
    """One linearised point-to-plane rigid step (R, t): minimise sum w ((R p + t - q) . m)^2."""
    J = np.concatenate([np.cross(P, M), M], axis=1)  # (p, 6)
    r = np.einsum("pc,pc->p", P - Q, M)
    H = (J * w[:, None]).T @ J + 1e-9 * np.eye(6)
    g = (J * w[:, None]).T @ r
    delta = -np.linalg.solve(H, g)
    return rodrigues(delta[:3][None])[0], delta[3:]


def patch_rigid_steps(P, Y, M, W, tangential, labels, count):
    """Batched rigid steps per patch (linearised), point-to-plane plus a tangential part.

    Minimises, per patch, sum w [((x - y) . m)^2 + tau |(I - m m^T)(x - y)|^2] with
    x = p + omega x (p - c) + shift, c the patch's weighted centre.

    Returns
    -------
    omega : (count, 3), shift : (count, 3), centres : (count, 3)
    """
    weight_sum = np.bincount(labels, weights=W, minlength=count)
    plain = np.bincount(labels, minlength=count).astype(float)
    centres = np.stack([np.bincount(labels, weights=W * P[:, a], minlength=count) for a in range(3)], axis=1)
    fallback = np.stack([np.bincount(labels, weights=P[:, a], minlength=count) for a in range(3)], axis=1)
    centres = np.where(weight_sum[:, None] > 1e-9, centres / np.maximum(weight_sum, 1e-300)[:, None],
                       fallback / np.maximum(plain, 1.0)[:, None])
    p = P - centres[labels]
    # metric M_i = w (m m^T + tau (I - m m^T))
    mm = np.einsum("pi,pj->pij", M, M)
    metric = W[:, None, None] * (mm + tangential[:, None, None] * (np.eye(3) - mm))
    # x - y = (p + c - y) + [-[p]x  I] [omega; shift]
    cross = np.zeros((len(p), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2] = p[:, 2], -p[:, 1]
    cross[:, 1, 0], cross[:, 1, 2] = -p[:, 2], p[:, 0]
    cross[:, 2, 0], cross[:, 2, 1] = p[:, 1], -p[:, 0]  # -[p]x
    J = np.concatenate([cross, np.broadcast_to(np.eye(3), (len(p), 3, 3))], axis=2)  # (p, 3, 6)
    JtM = np.einsum("pki,pkl->pil", J, metric)  # (p, 6, 3)
    H = np.einsum("pil,plj->pij", JtM, J).reshape(len(p), 36)
    r = P - Y
    g = np.einsum("pil,pl->pi", JtM, r)
    Hs = np.stack([np.bincount(labels, weights=H[:, a], minlength=count) for a in range(36)], axis=1)
    gs = np.stack([np.bincount(labels, weights=g[:, a], minlength=count) for a in range(6)], axis=1)
    Hs = Hs.reshape(count, 6, 6)
    scale = np.trace(Hs, axis1=1, axis2=2) / 6.0
    Hs = Hs + (1e-3 * scale + 1e-12)[:, None, None] * np.eye(6)
    delta = -np.linalg.solve(Hs, gs[..., None])[..., 0]
    return delta[:, :3], delta[:, 3:], centres


__all__ = ["kabsch", "patch_rigid_steps", "point_to_plane_step", "rodrigues", "rotation_fit", "rotation_set",
           "stack_rotations"]
