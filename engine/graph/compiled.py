"""A held frame's foot and leg arithmetic, compiled (numba): the work of ``LegRig`` and
``FootPins`` on a few hundred rows, which numpy did in dozens of calls a frame (each a few
microseconds of overhead on two 3-vectors or a few hundred rows), each done here in one call.

- :func:`ring_means`: a leg's joints, the centroids of its hip, knee and ankle rings (float64).
- :func:`move_legs`: every moved leg's two-bone solution (the knee's new place, the thigh's and
  the shin's rotations and stretch) and the blend of the segments' affine maps over the leg's
  vertices, written back into the float32 mesh. A foot's vertices (weight 1 on the foot) move by
  exactly ``share x offset``: the graph player reads the held feet without moving the legs.
- :func:`feet_world`: the feet's vertices gathered, moved by their held offsets as
  :func:`move_legs` moves them, turned by the heading and moved to the root (``clock.place``'s
  float32 steps).
- :func:`contact_moves`: ``clock.contact_moves`` for float32 feet (each foot's least horizontal
  move of a vertex on the ground in both frames).

(The transition search's played candidates are compiled beside their numpy formulation, in
``engine.graph.terms._play_blends``; :func:`warm_up` covers them too.)

The same IEEE operations as the Python formulations they replace (no fast-math), summed in the
order written; the 3x3 products are summed row by column, where numpy's BLAS may order a sum
differently, so the legs agree with ``tests/engine/test_graph_legs.py``'s numpy reference to
float32 rounding, not bit for bit. Deterministic: the same input gives the same bytes.
"""

from __future__ import annotations

import math

import numpy as np

from engine.jit import compiled


@compiled
def _ring_means(mesh, ring_index, bounds, out):  # pragma: no cover (compiled; tested through ring_means)
    for j in range(3):
        lo, hi = bounds[j], bounds[j + 1]
        w = 1.0 / (hi - lo)
        sx = sy = sz = 0.0
        for r in range(lo, hi):
            v = ring_index[r]
            sx += w * np.float64(mesh[v, 0])
            sy += w * np.float64(mesh[v, 1])
            sz += w * np.float64(mesh[v, 2])
        out[j, 0], out[j, 1], out[j, 2] = sx, sy, sz


def ring_means(mesh, ring_index, bounds):
    """(3, 3) float64: rows (hip, knee, ankle), each the mean of ``mesh``'s rows
    ``ring_index[bounds[j]:bounds[j + 1]]``; ``mesh`` (n, 3) float32 or float64."""
    out = np.empty((3, 3))
    _ring_means(mesh, ring_index, bounds, out)
    return out


@compiled
def _norm3(x, y, z):  # pragma: no cover
    return math.sqrt(x * x + y * y + z * z)


@compiled
def _rotation(p, q, R):  # pragma: no cover (engine.graph.legs._rotation, into R)
    n = _norm3(p[0], p[1], p[2])
    px, py, pz = p[0] / n, p[1] / n, p[2] / n
    n = _norm3(q[0], q[1], q[2])
    qx, qy, qz = q[0] / n, q[1] / n, q[2] / n
    ax, ay, az = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx
    s, c = math.sqrt(ax * ax + ay * ay + az * az), px * qx + py * qy + pz * qz
    if s < 1e-12:
        for i in range(3):
            for j in range(3):
                R[i, j] = 1.0 if i == j else 0.0
        return
    kx, ky, kz = ax / s, ay / s, az / s
    d = 1.0 - c
    R[0, 0], R[0, 1], R[0, 2] = 1.0 - d * (ky * ky + kz * kz), -s * kz + d * kx * ky, s * ky + d * kx * kz
    R[1, 0], R[1, 1], R[1, 2] = s * kz + d * kx * ky, 1.0 - d * (kx * kx + kz * kz), -s * kx + d * ky * kz
    R[2, 0], R[2, 1], R[2, 2] = -s * ky + d * kx * kz, s * kx + d * ky * kz, 1.0 - d * (kx * kx + ky * ky)


@compiled
def _segment_map(R, e, scale, A):  # pragma: no cover
    """A = R^T (I + (scale - 1) e e^T): the segment's rotation, stretched along its new bone."""
    for i in range(3):
        for j in range(3):
            if scale > 1.0:
                acc = 0.0
                for k in range(3):
                    s = (1.0 if k == j else 0.0) + (scale - 1.0) * e[k] * e[j]
                    acc += R[k, i] * s
                A[i, j] = acc
            else:
                A[i, j] = R[j, i]


@compiled
def _move_legs(mesh, index, weights, kept, thigh, shin, bounds, joints, offsets, shares, moved):  # pragma: no cover
    R1, R2 = np.empty((3, 3)), np.empty((3, 3))
    A1, A2, b = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    e, u, v = np.empty(3), np.empty(3), np.empty(3)
    target, new_knee = np.empty(3), np.empty(3)
    for leg in range(len(moved)):
        t = shares[leg]
        if not moved[leg] or t == 0.0:
            continue
        hip, knee, ankle = joints[leg, 0], joints[leg, 1], joints[leg, 2]
        for i in range(3):
            target[i] = ankle[i] + t * offsets[leg, i]
        l_thigh = _norm3(knee[0] - hip[0], knee[1] - hip[1], knee[2] - hip[2])
        l_shin = _norm3(ankle[0] - knee[0], ankle[1] - knee[1], ankle[2] - knee[2])
        scale = max(1.0, _norm3(target[0] - hip[0], target[1] - hip[1], target[2] - hip[2]) / (l_thigh + l_shin))
        # the two-bone solution: the knee in the plane it bends in now, thigh and shin keeping their lengths
        l1, l2 = scale * l_thigh, scale * l_shin
        d = _norm3(target[0] - hip[0], target[1] - hip[1], target[2] - hip[2])
        for i in range(3):
            u[i] = (target[i] - hip[i]) / d
        along = (knee[0] - hip[0]) * u[0] + (knee[1] - hip[1]) * u[1] + (knee[2] - hip[2]) * u[2]
        for i in range(3):
            v[i] = (knee[i] - hip[i]) - along * u[i]
        if _norm3(v[0], v[1], v[2]) < 1e-6 * l1:  # a straight leg bends forward (+Z)
            along = u[2]
            for i in range(3):
                v[i] = (1.0 if i == 2 else 0.0) - along * u[i]
        n = _norm3(v[0], v[1], v[2])
        cos = min(max((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0), 1.0)
        sin = math.sqrt(1.0 - cos * cos)
        for i in range(3):
            new_knee[i] = hip[i] + l1 * (cos * u[i] + sin * (v[i] / n))
        _rotation(knee - hip, new_knee - hip, R1)
        _rotation(ankle - knee, target - new_knee, R2)
        # x -> x A + b per segment: thigh (x - hip) A1 + hip, shin (x - knee) A2 + new knee, foot x + t offset
        n = _norm3(new_knee[0] - hip[0], new_knee[1] - hip[1], new_knee[2] - hip[2])
        for i in range(3):
            e[i] = (new_knee[i] - hip[i]) / n
        _segment_map(R1, e, scale, A1)
        n = _norm3(target[0] - new_knee[0], target[1] - new_knee[1], target[2] - new_knee[2])
        for i in range(3):
            e[i] = (target[i] - new_knee[i]) / n
        _segment_map(R2, e, scale, A2)
        for j in range(3):
            b[0, j] = hip[j] - (hip[0] * A1[0, j] + hip[1] * A1[1, j] + hip[2] * A1[2, j])
            b[1, j] = new_knee[j] - (knee[0] * A2[0, j] + knee[1] * A2[1, j] + knee[2] * A2[2, j])
            b[2, j] = t * offsets[leg, j]
        for r in range(bounds[leg], bounds[leg + 1]):
            row = index[r]
            x0, x1, x2 = np.float64(mesh[row, 0]), np.float64(mesh[row, 1]), np.float64(mesh[row, 2])
            w0, w1, w2 = weights[r, 0], weights[r, 1], weights[r, 2]
            for j in range(3):
                xa1 = x0 * A1[0, j] + x1 * A1[1, j] + x2 * A1[2, j]
                xa2 = x0 * A2[0, j] + x1 * A2[1, j] + x2 * A2[2, j]
                shift = w0 * b[0, j] + w1 * b[1, j] + w2 * b[2, j]
                x = x0 if j == 0 else (x1 if j == 1 else x2)
                mesh[row, j] = np.float32(x * kept[r] + thigh[r] * xa1 + shin[r] * xa2 + shift)


def move_legs(mesh, index, weights, kept, thigh, shin, bounds, joints, offsets, shares, moved):
    """Move the legs of the C-contiguous (n, 3) float32 ``mesh`` in place (``LegRig.move``).

    index : (m,) int64 every leg's vertex rows, leg k's at ``index[bounds[k]:bounds[k + 1]]``
    weights : (m, 3) float64 thigh, shin, foot weight of each; kept, thigh, shin : (m,) float64
    joints : (legs, 3, 3) float64 each leg's hip, knee, ankle on ``mesh``
    offsets : (legs, 3) float64 root-local offsets; shares : (legs,) float64 the share carried
    moved : (legs,) bool the legs to move
    """
    _move_legs(mesh, index, weights, kept, thigh, shin, bounds, joints, offsets, shares, moved)
    return mesh


@compiled
def _feet_world(mesh, index, bounds, local, shares, held, c, s, position, out):  # pragma: no cover
    r00, r02, r20, r22 = np.float32(c), np.float32(-s), np.float32(s), np.float32(c)
    px, py, pz = np.float32(position[0]), np.float32(position[1]), np.float32(position[2])
    for k in range(len(bounds) - 1):
        dx, dy, dz = shares[k] * local[k, 0], shares[k] * local[k, 1], shares[k] * local[k, 2]
        for r in range(bounds[k], bounds[k + 1]):
            row = index[r]
            x, y, z = mesh[row, 0], mesh[row, 1], mesh[row, 2]
            if held:  # as move_legs writes a foot's vertex: float64 sum, cast
                x = np.float32(np.float64(x) + dx)
                y = np.float32(np.float64(y) + dy)
                z = np.float32(np.float64(z) + dz)
            wx = x * r00 + z * r20
            wz = x * r02 + z * r22
            if position[0] != 0.0:
                wx += px
            if position[1] != 0.0:
                y += py
            if position[2] != 0.0:
                wz += pz
            out[r, 0], out[r, 1], out[r, 2] = wx, y, wz


def feet_world(mesh, index, bounds, position, heading, hold=None, out=None):
    """(F, 3) float32: the feet's rows ``index`` of root-local float32 ``mesh`` (foot k's at
    ``index[bounds[k]:bounds[k + 1]]``), moved by ``shares[k] x local[k]`` when ``hold`` =
    (local (feet, 3), shares (feet,)) is given, turned by ``heading`` about +Y and moved to
    ``position``."""
    if out is None:
        out = np.empty((len(index), 3), dtype=np.float32)
    if hold is None:
        local, shares, held = _NO_HOLD, _NO_SHARES, False
        if len(bounds) - 1 > len(_NO_SHARES):
            local, shares = np.zeros((len(bounds) - 1, 3)), np.zeros(len(bounds) - 1)
    else:
        local, shares, held = hold[0], hold[1], True
    position = np.asarray(position, dtype=np.float64)
    _feet_world(mesh, index, bounds, local, shares, held, math.cos(heading), math.sin(heading), position, out)
    return out


_NO_HOLD, _NO_SHARES = np.zeros((4, 3)), np.zeros(4)


@compiled
def _contact_moves(before, after, ground, bounds, moves, found):  # pragma: no cover
    for k in range(len(bounds) - 1):
        best, arg = np.inf, -1
        for r in range(bounds[k], bounds[k + 1]):
            if before[r, 1] < ground and after[r, 1] < ground:
                dx, dz = after[r, 0] - before[r, 0], after[r, 2] - before[r, 2]
                length = dx * dx + dz * dz
                if length < best:
                    best, arg = length, r
        found[k] = arg >= 0
        if arg >= 0:
            moves[k, 0] = after[arg, 0] - before[arg, 0]
            moves[k, 1] = after[arg, 2] - before[arg, 2]
        else:
            moves[k, 0] = moves[k, 1] = 0.0


def contact_moves(before, after, ground, bounds):
    """(moves (feet, 2) float32, found (feet,) bool): ``engine.graph.clock.contact_moves`` for
    float32 stacked feet; a foot without a vertex on the ground in both frames is not found."""
    feet = len(bounds) - 1
    moves, found = np.empty((feet, 2), dtype=np.float32), np.empty(feet, dtype=np.bool_)
    _contact_moves(before, after, np.float32(ground), np.asarray(bounds, dtype=np.int64), moves, found)
    return moves, found


def warm_up():
    """Compile (or load from numba's cache) these kernels for the types a graph stream uses."""
    mesh = np.zeros((6, 3), dtype=np.float32)
    index, bounds = np.arange(6, dtype=np.int64), np.array([0, 3, 6], dtype=np.int64)
    for rows in (mesh, mesh.astype(np.float64)):  # frames; a rest mesh (LegRig)
        ring_means(rows, index, np.array([0, 2, 4, 6], dtype=np.int64))
    rows = np.zeros(6)
    joints = np.zeros((2, 3, 3))
    joints[:, 1, 1], joints[:, 0, 1] = 0.5, 1.0
    move_legs(mesh, index, np.zeros((6, 3)), rows, rows, rows, bounds, joints, np.zeros((2, 3)), np.ones(2),
              np.zeros(2, dtype=np.bool_))
    for hold in (None, (np.zeros((2, 3)), np.zeros(2))):
        feet_world(mesh, index, bounds, np.zeros(3), 0.0, hold)
    contact_moves(mesh, mesh, 0.0, bounds)
    from engine.graph import terms  # the transition search's played candidates (terms.predict)

    points, index = np.zeros((2, 3, 3), dtype=np.float32), np.zeros((1, 2), dtype=np.int64)
    rates, ground = np.zeros((2, 2)), np.zeros((2, 1))
    terms._play_blends(points, points, index, index, np.zeros((1, 2)), rates, rates, rates[:, 0].copy(),
                       rates[:, 0].copy(), ground, ground, terms.FRAME, np.empty((1, 1), dtype=np.float32),
                       np.empty((1, 2, 1, 2), dtype=np.float32), np.empty((1, 2, 1), dtype=np.bool_))


__all__ = ["contact_moves", "feet_world", "move_legs", "ring_means", "warm_up"]
