"""What the transition search predicts beyond the seam's dissimilarity, by playing the blend
over a few vertices: how large the frames' steps will be against the motions' own, and how far
the legs will carry a foot held on the ground.

Each node keeps, per weight sample, a fine table of its motion (``NodeProfile``: every 1/45 s of
its cycle or clip at the slowest weights): the root-local places of a few vertices (those that
move fastest anywhere in the graph and an even spread of the rest), each foot's centroid and
whether it is on the ground, and the root's velocity and turn. ``predict`` plays candidate
transitions on these tables as the player does (both nodes advancing from the leave and entry
phases, meshes and root steps blended with the smooth step) and measures them as
``evaluate`` does:

- **smoothness**: the largest step of a vertex between consecutive frames across the blend (from
  the last frame before it), over the largest of the two nodes' own (1.0 = as smooth as captured);
- **foot drift**: the distance a foot travels while it is on the ground in consecutive frames of
  the blend (what ``feet.FootPins`` holds back, so what the leg must carry), the worse foot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.graph.clock import NodeClock, foot_vertices
from engine.jit import compiled

RATE = 45.0          # table entries per second of motion, at the node's slowest weights
FRAME = 1.0 / 30.0   # seconds per predicted frame


def _smooth(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


@dataclass
class NodeProfile:
    """Fine tables of a node's motion per weight sample (K samples, P entries over the phase).

    points : (K, P, V, 3) float32   root-local places of the tracked vertices; the last F are the
                                    feet's centroids
    ground : (K, P, F) bool         the foot has a vertex on the ground
    velocity : (K, P, 2) float      the root's root-local xz velocity (m/s)
    turn : (K, P) float             its turn rate (rad/s)
    duration : (K,) float           seconds of a cycle (or clip)
    largest : (K,) float            the largest step of a tracked vertex over one frame of its own
                                    motion, in the world (the root's step included)
    cyclic : bool
    """

    points: np.ndarray
    ground: np.ndarray
    velocity: np.ndarray
    turn: np.ndarray
    duration: np.ndarray
    largest: np.ndarray
    cyclic: bool

    def index(self, k, phase):
        """Table entries nearest ``phase`` (array) at weight sample ``k``."""
        P = self.points.shape[1]
        if self.cyclic:
            return np.rint(np.asarray(phase) * P).astype(np.int64) % P
        return np.clip(np.rint(np.asarray(phase) * (P - 1)).astype(np.int64), 0, P - 1)


def tracked_vertices(graph, count=48):
    """Vertex indices the predictions follow: per node, those that move fastest over its clips
    (hands, feet, head), and an even spread of the rest."""
    fastest = []
    per_node = max(8, count // (2 * len(graph.nodes)))
    for node in graph.nodes:
        sources = np.asarray(node.space.container["sources"])  # (phases, N, n, 3)
        speed = np.linalg.norm(np.diff(sources, axis=0), axis=-1).max(axis=(0, 1))
        fastest.append(np.argsort(speed)[-per_node:])
    n = graph.nodes[0].space.n_vertices
    spread = np.linspace(0, n - 1, count // 2).round().astype(np.int64)
    return np.unique(np.concatenate(fastest + [spread]))


def node_profile(node, vertices, contact=0.01):
    """The ``NodeProfile`` of a graph node following ``vertices`` (``tracked_vertices``); blends
    with a linear blender of its own, so it may run in a thread beside a stream's blending."""
    space, samples = node.space, node.samples
    blender = space.new_blender("linear")
    rest = np.asarray(space.container["rest"])
    feet = foot_vertices(rest)
    ground = float(rest[:, 1].min()) + contact
    durations = np.asarray(samples.durations, dtype=float)
    P = max(8, int(math.ceil(durations.max() * RATE)))
    phases = np.arange(P) / P if space.cyclic else np.linspace(0.0, 1.0, P)
    K, V, F = len(samples.weights), len(vertices), len(feet)
    points = np.zeros((K, P, V + F, 3), dtype=np.float32)
    on_ground = np.zeros((K, P, F), dtype=bool)
    velocity, turn = np.zeros((K, P, 2)), np.zeros((K, P))
    tiny = 1e-4
    for k, w in enumerate(samples.weights):
        clock = NodeClock(space, w, 0.0)
        for p, phase in enumerate(phases):
            clock.phase, clock.finished = float(phase), False
            if not space.cyclic and phase >= 1.0:  # a one-shot's last frame: the step before it
                clock.phase = 1.0 - tiny / clock.duration
            mesh = np.asarray(blender.blend(clock.weights, clock.phase))
            points[k, p, :V] = mesh[vertices]
            for f, foot in enumerate(feet):
                points[k, p, V + f] = mesh[foot].mean(0)
                on_ground[k, p, f] = bool((mesh[foot, 1] < ground).any())
            dx, dz, t = clock.advance(tiny)
            velocity[k, p], turn[k, p] = (dx / tiny, dz / tiny), t / tiny
    profile = NodeProfile(points=points, ground=on_ground, velocity=velocity, turn=turn, duration=durations,
                          largest=np.zeros(K), cyclic=bool(space.cyclic))
    for k in range(K):  # its own motion's largest step, over a cycle (or the clip) from four starts
        frames = int(math.ceil(durations[k] / FRAME)) + 1
        starts = np.arange(4) / 4.0 * FRAME / durations[k]
        steps = _play(profile, k, starts, profile, k, starts, np.zeros(4, dtype=int), frames, own=True)[0]
        profile.largest[k] = steps.max()
    return profile


def own_windows(profile, phases, lengths):
    """(K, M, lengths) the largest own step of a tracked vertex over a blend of each length
    starting at each of ``phases`` (the node's phase samples; the frame before included): what
    the motion alone contributes to the smoothness of a transition timed there."""
    K = len(profile.duration)
    frames = max(int(math.ceil(max(lengths) / FRAME)) + 1, 2)
    out = np.zeros((K, len(phases), len(lengths)))
    for k in range(K):
        starts = np.asarray(phases, dtype=float) - FRAME / profile.duration[k]
        if not profile.cyclic:
            starts = np.maximum(starts, 0.0)
        steps = _play(profile, k, starts, profile, k, starts, np.zeros(len(phases), dtype=int), frames, own=True)[0]
        for i, length in enumerate(lengths):
            n = int(round(length / FRAME)) + 1
            out[k, :, i] = steps[:, :n].max(1)
    return out


def _entries(a, ka, phase_a, b, kb, phase_b, frames_n, count, own):
    """(ia, ib, s) (C, count + 1): each candidate's frames' table entries in ``a`` and ``b`` and
    the blend's weight of ``b`` there (0 throughout for ``own`` or a candidate of 0 frames)."""
    t = np.arange(count + 1) * FRAME                                  # (T,)
    ia = a.index(ka, phase_a[:, None] + t[None, :] / a.duration[ka])  # (C, T)
    ib = b.index(kb, phase_b[:, None] + t[None, :] / b.duration[kb])
    if own:
        return ia, ib, np.zeros((len(phase_a), count + 1))
    n = np.maximum(frames_n, 1)[:, None]
    return ia, ib, np.where(frames_n[:, None] > 0, _smooth(np.arange(count + 1)[None, :] / n), 0.0)


def _play(a, ka, phase_a, b, kb, phase_b, frames_n, count, *, own=False):
    """Play candidates: ``phase_a`` / ``phase_b`` (C,) the phases the blend leaves and enters at,
    ``frames_n`` (C,) its frames (0: the source alone); ``count`` frames after the first.
    Returns (C, count) the largest tracked-vertex step of each frame, (C, count + 1, F, 2) the
    feet's world xz and (C, count + 1, F) whether each is on the ground."""
    C = len(phase_a)
    ia, ib, s = _entries(a, ka, phase_a, b, kb, phase_b, frames_n, count, own)
    sv = s[:, :, None]
    local = a.points[ka][ia]                                          # (C, T, V, 3) float32
    if not own:
        local += s[:, :, None, None].astype(np.float32) * (b.points[kb][ib] - local)
    vel = a.velocity[ka][ia] * (1 - sv) + b.velocity[kb][ib] * sv   # (C, T, 2)
    rate = a.turn[ka][ia] * (1 - s) + b.turn[kb][ib] * s            # (C, T)
    root = np.zeros((C, count + 1, 2))
    if rate.any():  # turning: the root's steps and the mesh turned by the heading
        heading = np.concatenate([np.zeros((C, 1)), np.cumsum(rate[:, 1:] * FRAME, axis=1)], axis=1)
        c, si = np.cos(heading), np.sin(heading)
        hx = c[:, :-1] * vel[:, 1:, 0] + si[:, :-1] * vel[:, 1:, 1]
        hz = c[:, :-1] * vel[:, 1:, 1] - si[:, :-1] * vel[:, 1:, 0]
        root[:, 1:, 0], root[:, 1:, 1] = np.cumsum(hx * FRAME, axis=1), np.cumsum(hz * FRAME, axis=1)
        cf, sf = c[:, :, None].astype(np.float32), si[:, :, None].astype(np.float32)
        x, z = local[..., 0].copy(), local[..., 2]
        local[..., 0] = cf * x + sf * z
        local[..., 2] = cf * z - sf * x
    else:
        root[:, 1:] = np.cumsum(vel[:, 1:] * FRAME, axis=1)
    world = local
    world[..., 0] += root[:, :, None, 0].astype(np.float32)
    world[..., 2] += root[:, :, None, 1].astype(np.float32)
    d = world[:, 1:] - world[:, :-1]
    steps = np.sqrt(np.einsum("ctvk,ctvk->ctv", d, d).max(-1))       # (C, count)
    F = a.ground.shape[2]
    feet = world[:, :, -F:, :][..., [0, 2]]
    down = (a.ground[ka][ia] * (1 - sv) + b.ground[kb][ib] * sv) >= 0.5
    return steps, feet, down


@compiled
def _play_blends(pa, pb, ia, ib, s, va, vb, ta, tb, ga, gb, frame, steps, feet, down):  # pragma: no cover
    """``_play`` of blends (not ``own``), one candidate at a time in one pass: the same float32
    and float64 operations in the same order (its turning branch; without a turn it gives the
    same numbers, cos 0 = 1 and sin 0 = 0 being exact)."""
    C, T = ia.shape
    V, F = pa.shape[1], ga.shape[1]
    prev = np.empty((V, 3), dtype=np.float32)
    cur = np.empty((V, 3), dtype=np.float32)
    for c in range(C):
        heading = 0.0
        rx = rz = 0.0
        for t in range(T):
            i, j, st = ia[c, t], ib[c, t], s[c, t]
            if t > 0:  # the root's step: this frame's velocity turned by the last frame's heading
                vx = va[i, 0] * (1 - st) + vb[j, 0] * st
                vz = va[i, 1] * (1 - st) + vb[j, 1] * st
                ch, sh = math.cos(heading), math.sin(heading)
                rx += (ch * vx + sh * vz) * frame
                rz += (ch * vz - sh * vx) * frame
                heading += (ta[i] * (1 - st) + tb[j] * st) * frame
            cf, sf = np.float32(math.cos(heading)), np.float32(math.sin(heading))
            sv = np.float32(st)
            fx, fz = np.float32(rx), np.float32(rz)
            largest = np.float32(0.0)
            for v in range(V):
                x = pa[i, v, 0] + sv * (pb[j, v, 0] - pa[i, v, 0])
                y = pa[i, v, 1] + sv * (pb[j, v, 1] - pa[i, v, 1])
                z = pa[i, v, 2] + sv * (pb[j, v, 2] - pa[i, v, 2])
                wx = cf * x + sf * z + fx
                wz = cf * z - sf * x + fz
                cur[v, 0], cur[v, 1], cur[v, 2] = wx, y, wz
                if t > 0:
                    dx, dy, dz = wx - prev[v, 0], y - prev[v, 1], wz - prev[v, 2]
                    d = dx * dx + dy * dy + dz * dz
                    if d > largest:
                        largest = d
            if t > 0:
                steps[c, t - 1] = math.sqrt(largest)
            for f in range(F):
                feet[c, t, f, 0] = cur[V - F + f, 0]
                feet[c, t, f, 1] = cur[V - F + f, 2]
                down[c, t, f] = ga[i, f] * (1 - st) + gb[j, f] * st >= 0.5
            prev, cur = cur, prev


def predict(a, ka, phase_a, b, kb, phase_b, lengths):
    """Per candidate (arrays (C,): leave phase of ``a``, entry phase of ``b``, blend seconds):
    (smoothness ratio, foot drift m), module notes."""
    frames_n = np.maximum(np.rint(np.asarray(lengths) / FRAME).astype(int), 1)
    count = int(frames_n.max())
    phase_a, phase_b = np.asarray(phase_a, float), np.asarray(phase_b, float)
    ia, ib, s = _entries(a, ka, phase_a, b, kb, phase_b, frames_n, count, False)
    C, F = len(phase_a), a.ground.shape[2]
    steps = np.empty((C, count), dtype=np.float32)
    feet = np.empty((C, count + 1, F, 2), dtype=np.float32)
    down = np.empty((C, count + 1, F), dtype=np.bool_)
    _play_blends(a.points[ka], b.points[kb], ia, ib, s, a.velocity[ka], b.velocity[kb], a.turn[ka], b.turn[kb],
                 a.ground[ka].astype(np.float64), b.ground[kb].astype(np.float64), FRAME, steps, feet, down)
    inside = np.arange(count)[None, :] < frames_n[:, None]           # frames of each blend
    ratio = np.where(inside, steps, 0.0).max(1) / max(a.largest[ka], b.largest[kb], 1e-9)
    moved = np.sqrt(((feet[:, 1:] - feet[:, :-1]) ** 2).sum(-1))       # (C, count, F)
    held = down[:, 1:] & down[:, :-1] & inside[:, :, None]
    drift = np.where(held, moved, 0.0).sum(1).max(-1)
    return ratio, drift
