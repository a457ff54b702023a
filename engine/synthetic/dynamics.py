"""Secondary surface dynamics: soft tissue and a loose garment lagging the skinned body.

Each vertex carries damped springs (one per material) driven by the acceleration of its skinned
position: u'' + 2 zeta omega u' + omega^2 u = -a(t), integrated exactly for piecewise-constant
input (zero-order hold). Accelerations are taken in the root's heading frame so a turning gait
stays periodic in that frame. Cyclic clips use the periodic steady state (solved in closed form),
so they loop exactly; non-cyclic clips start at rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from engine.rotations import rot_y


@dataclass(frozen=True)
class Material:
    """A damped spring: natural frequency (Hz), damping ratio, displacement cap (m)."""

    frequency: float
    damping: float
    cap: float


SOFT_TISSUE = Material(frequency=5.0, damping=0.25, cap=0.02)
GARMENT = Material(frequency=2.2, damping=0.3, cap=0.035)


def _discretise(material, dt):
    """Exact zero-order-hold discretisation of the spring: s_{k+1} = A s_k + b f_k."""
    w = 2 * np.pi * material.frequency
    Ac = np.array([[0.0, 1.0, 0.0], [-w * w, -2 * material.damping * w, 1.0], [0.0, 0.0, 0.0]])
    E = expm(Ac * dt)
    return E[:2, :2], E[:2, 2]


def _respond(material, accel, dt, periodic):
    """Spring displacement (frames, n, 3) for forcing -accel; periodic steady state if asked."""
    A, b = _discretise(material, dt)
    frames = accel.shape[0]
    force = -accel
    state = np.zeros((2,) + accel.shape[1:])
    if periodic:
        # One pass from rest gives s_N = A^N s_0 + c with s_0 = 0; the periodic solution has
        # s_0 = s_N, so s_0 = (I - A^N)^-1 c (the same 2x2 system for every vertex and axis).
        for k in range(frames):
            state = np.einsum("ij,j...->i...", A, state) + b[:, None, None] * force[k]
        AN = np.linalg.matrix_power(A, frames)
        state = np.einsum("ij,j...->i...", np.linalg.inv(np.eye(2) - AN), state)
    out = np.empty_like(accel)
    for k in range(frames):
        out[k] = state[0]
        state = np.einsum("ij,j...->i...", A, state) + b[:, None, None] * force[k]
    return out


def _cap(u, cap):
    """Smoothly limit displacement magnitudes below ``cap`` (identity for small u)."""
    length = np.linalg.norm(u, axis=-1, keepdims=True)
    return u / np.sqrt(1.0 + (length / cap) ** 2)


def secondary_motion(V, heading, fps, amplitudes, *, periodic, before=None, after=None, world=True):
    """Displacements of soft tissue and garment for a skinned vertex sequence.

    Parameters
    ----------
    V : (frames, n, 3) float array     skinned world positions
    heading : (frames,) float array    root heading (radians about +Y)
    fps : float
    amplitudes : dict Material -> (n,) float array   per-vertex weight of each material
    periodic : bool                    V is exactly one cycle (frame ``frames`` repeats frame 0 in
                                       the root frame): solve for the periodic steady state
    before, after : (n, 3) float arrays or None
        world positions one frame before the first and after the last, for the accelerations at
        the ends; default: at rest there. A cycle must pass its true neighbours (the frame after
        the last is the first moved by one cycle's root motion, not the first itself).

    world : bool                       return world displacements (else in the heading frame)

    Returns
    -------
    D : (frames, n, 3) float array   displacements to add to V
    """
    dt = 1.0 / fps
    prev = np.concatenate([(V[:1] if before is None else before[None]), V[:-1]])
    nxt = np.concatenate([V[1:], (V[-1:] if after is None else after[None])])
    accel = (nxt - 2 * V + prev) / (dt * dt)
    R = rot_y(heading)  # heading frame -> world
    accel_local = np.einsum("fba,fnb->fna", R, accel)
    total = np.zeros_like(V)
    for material, amplitude in amplitudes.items():
        weight = np.asarray(amplitude, dtype=float)
        active = weight > 1e-3
        if not np.any(active):
            continue
        u = _respond(material, accel_local[:, active], dt, periodic)
        u = _cap(u, material.cap)
        total[:, active] += weight[active, None] * u
    return np.einsum("fab,fnb->fna", R, total) if world else total
