"""Rigid motions for the pairwise aligner: rotation fitting, point-to-plane and per-patch steps.

Small batched solvers shared by the rigid start, the patch matching and the as-rigid-as-possible
local steps of :class:`engine.align.pairwise.PairwiseAligner`.
"""

from __future__ import annotations

import numpy as np

from engine.align.compiled import patch_normal_equations, rotation_fit_compiled
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
    columns, ``R <- exp(omega) R``. Each step is a few products, far cheaper than a
    batched SVD, and a warm start needs only a few steps.
    The iteration runs one matrix at a time in compiled code
    (:func:`engine.align.compiled.rotation_fit_compiled`), about three times faster than as
    batched array operations.
    """
    return rotation_fit_compiled(F, R0, iterations)


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


def patch_rigid_steps(P, Y, M, W, tangential, labels, count, coupling=None):
    """Batched rigid steps per patch (linearised), point-to-plane plus a tangential part.

    Minimises, per patch, sum w [((x - y) . m)^2 + tau |(I - m m^T)(x - y)|^2] with
    x = p + omega x (p - c) + shift, c the patch's weighted centre.

    With ``coupling = (pairs, points, spread, weight)`` the patches' steps are solved together,
    adjacent patches' steps pulled towards each other (:func:`coupled_patch_steps`): a patch
    whose data leave a motion free (a plain sleeve's twist about its arm) takes its
    neighbours' step there instead of none.

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
    # per point: metric w (m m^T + tau (I - m m^T)), J = [-[p]x  I] (x - y = p + c - y + J delta),
    # J^T metric J and J^T metric (x - y), summed per patch (compiled)
    Hs, gs = patch_normal_equations(p, P - Y, M, W, tangential, labels, count)
    Hs = Hs.reshape(count, 6, 6)
    scale = np.trace(Hs, axis1=1, axis2=2) / 6.0
    Hs = Hs + (1e-3 * scale + 1e-12)[:, None, None] * np.eye(6)
    if coupling is not None and coupling[3] > 0 and len(coupling[0]):
        delta = coupled_patch_steps(Hs, gs, centres, *coupling)
    else:
        delta = -np.linalg.solve(Hs, gs[..., None])[..., 0]
    return delta[:, :3], delta[:, 3:], centres


def coupled_patch_steps(H, g, centres, pairs, points, spread, weight):
    """Rigid steps of all patches at once, adjacent patches' steps kept alike.

    Minimises ``sum_p (d_p^T H_p d_p / 2 + g_p^T d_p)`` plus, for every adjacent pair (a, b),
    ``k_ab / 2 (|u_a(q) - u_b(q)|^2 + r^2 |omega_a - omega_b|^2)``: ``u_p(q) = omega_p x (q - c_p) +
    shift_p`` is the step's displacement at the pair's border point ``q``, ``r`` the border's
    spread, and ``k_ab = weight * (tr_a + tr_b) / 6`` with ``tr`` the trace of a patch's
    translational data block (so the pull scales with the data and ``weight`` is unitless).

    The pull is on the *steps*, not the poses: where a patch's data determine its motion the
    iteration still converges to that motion (a zero step costs nothing); where they leave a
    direction free (a plain cone's twist, a cylinder's slide) the patch moves with its
    neighbours there instead of staying behind.

    Parameters
    ----------
    H : (count, 6, 6) float array   per-patch data Hessians (omega, shift)
    g : (count, 6) float array      per-patch gradients
    centres : (count, 3) float array
    pairs : (e, 2) int array        adjacent patches
    points : (e, 3) float array     a border point of each pair
    spread : (e,) float array       r of each pair (m)
    weight : float

    Returns
    -------
    delta : (count, 6) float array   (omega, shift) per patch
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    count = len(H)
    pairs = np.asarray(pairs, dtype=np.int64)
    trans = np.trace(H[:, 3:, 3:], axis1=1, axis2=2)
    k = float(weight) * (trans[pairs[:, 0]] + trans[pairs[:, 1]]) / 6.0
    e = len(pairs)

    def jacobian(q, c):  # (e, 3, 6): u = -[q - c]x omega + shift
        d = q - c
        J = np.zeros((len(d), 3, 6))
        J[:, 0, 1], J[:, 0, 2] = d[:, 2], -d[:, 1]
        J[:, 1, 0], J[:, 1, 2] = -d[:, 2], d[:, 0]
        J[:, 2, 0], J[:, 2, 1] = d[:, 1], -d[:, 0]
        J[:, :, 3:] = np.eye(3)
        return J

    Ja, Jb = jacobian(points, centres[pairs[:, 0]]), jacobian(points, centres[pairs[:, 1]])
    E = np.zeros((e, 6, 6))
    E[:, [0, 1, 2], [0, 1, 2]] = (np.asarray(spread, dtype=np.float64) ** 2)[:, None]
    kk = k[:, None, None]
    Aaa = kk * (np.einsum("eki,ekj->eij", Ja, Ja) + E)
    Abb = kk * (np.einsum("eki,ekj->eij", Jb, Jb) + E)
    Aab = -kk * (np.einsum("eki,ekj->eij", Ja, Jb) + E)
    six = np.arange(6)
    rows, cols, vals = [], [], []

    def add(block_rows, block_cols, blocks):
        r = (6 * block_rows[:, None, None] + six[None, :, None]) + 0 * six[None, None, :]
        c = (6 * block_cols[:, None, None] + six[None, None, :]) + 0 * six[None, :, None]
        rows.append(r.ravel())
        cols.append(c.ravel())
        vals.append(blocks.ravel())

    add(np.arange(count), np.arange(count), H)
    add(pairs[:, 0], pairs[:, 0], Aaa)
    add(pairs[:, 1], pairs[:, 1], Abb)
    add(pairs[:, 0], pairs[:, 1], Aab)
    add(pairs[:, 1], pairs[:, 0], np.swapaxes(Aab, 1, 2))
    A = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(6 * count, 6 * count))
    return -spla.spsolve(A, np.asarray(g, dtype=np.float64).ravel()).reshape(count, 6)


__all__ = ["coupled_patch_steps", "kabsch", "patch_rigid_steps", "point_to_plane_step", "rodrigues", "rotation_fit", "rotation_set",
           "stack_rotations"]
