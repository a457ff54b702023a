"""One motion space played on a clock at fixed blend weights: the phase, the root's step and
the root-local mesh. The graph player runs one (or two, across a transition) of these and
integrates their blended root steps itself.
"""

from __future__ import annotations

import math

import numpy as np

from engine.blend.phase import phase_samples


class NodeClock:
    """A motion space at weights ``w`` and a phase that advances with time.

    Parameters
    ----------
    space : MotionSpace
    weights : (N,) float array   blend weights (not all zero)
    phase : float                start phase in [0, 1]
    tables : bool                blend linear and hybrid frames through the space's phase tables
                                 (``MotionSpace.frame_blender``: exact up to float32 rounding, one
                                 interpolation a frame at weights that recur) instead of blending
                                 every frame; a stream says True, a recording False (its bytes then
                                 depend only on the weights and the phase)

    Attributes
    ----------
    phase : float
    finished : bool   a one-shot space has reached its last frame (it then holds it)
    """

    def __init__(self, space, weights, phase=0.0, *, tables=False):
        self.space, self.tables = space, bool(tables)
        self.cyclic = bool(space.cyclic)
        self.set_weights(weights)
        self.phase = float(phase) % 1.0 if self.cyclic else min(max(float(phase), 0.0), 1.0)
        self.finished = not self.cyclic and self.phase >= 1.0

    def set_weights(self, weights):
        """Blend at ``weights`` from now on (the phase stays)."""
        self.weights = self.space.check_weights(weights)
        track = self.space.root_track
        step, turn = track.rates(self.weights)
        self._step = step[:, [0, 2]].tolist()
        self._turn = turn.tolist()
        self.duration = track.duration(self.weights)

    def advance(self, dt):
        """Advance ``dt`` seconds.

        Returns
        -------
        dx, dz : float   the root's displacement in its own frame at the start of the step
        turn : float     heading change (radians about +Y)
        """
        if self.finished or dt <= 0:
            return 0.0, 0.0, 0.0
        d_phase = dt / self.duration
        if not self.cyclic:
            d_phase = min(d_phase, 1.0 - self.phase)
        middle = self.phase + 0.5 * d_phase
        p0, p1, a = phase_samples(middle % 1.0 if self.cyclic else middle, len(self._turn), self.cyclic)
        s0, s1 = self._step[p0], self._step[p1]
        sx, sz = s0[0] + a * (s1[0] - s0[0]), s0[1] + a * (s1[1] - s0[1])
        t = self._turn[p0] + a * (self._turn[p1] - self._turn[p0])
        half = 0.5 * t * d_phase  # the step's heading at its middle (midpoint rule, as Player)
        c, s = math.cos(half), math.sin(half)
        self.phase += d_phase
        if self.cyclic:
            self.phase %= 1.0
        elif self.phase >= 1.0 - 1e-12:
            self.phase, self.finished = 1.0, True
        return (c * sx + s * sz) * d_phase, (c * sz - s * sx) * d_phase, t * d_phase

    def mesh(self, mode="hybrid", out=None):
        """(n, 3) the root-local blended mesh at the current phase (the blender's buffer: copy it
        to keep it; ``out``: a C-contiguous (n, 3) float32 array written and returned instead, for
        the linear and hybrid modes, whose blends are float32). Without ``tables`` the space's own
        blender, not its phase-table cache: the bytes depend only on the weights and the phase, so
        a replay gives the same frames."""
        if self.tables and mode != "nonlinear":
            return self.space.frame_blender(mode).blend(self.weights, self.phase, out=out)
        return self.space.blender(mode).blend(self.weights, self.phase, out=out)


def place(mesh, position, heading, out=None):
    """(n, 3) float32 world vertices: root-local ``mesh`` turned by ``heading`` about +Y and moved
    to ``position``."""
    c, s = math.cos(heading), math.sin(heading)
    RT = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]], dtype=np.float32)  # R^T, R about +Y
    vertices = np.empty((len(mesh), 3), dtype=np.float32) if out is None else out
    np.matmul(np.asarray(mesh, dtype=np.float32), RT, out=vertices)
    for axis, x in enumerate(np.asarray(position, dtype=float).tolist()):
        if x != 0.0:
            vertices[:, axis] += np.float32(x)
    return vertices


def move(position, heading, dx, dz, turn):
    """The root after a local step (dx, dz, turn) taken from ``position``, ``heading``."""
    c, s = math.cos(heading), math.sin(heading)
    return (np.array([position[0] + c * dx + s * dz, position[1], position[2] + c * dz - s * dx]),
            heading + turn)


def foot_vertices(rest, height=0.06):
    """(left, right) int arrays: the rest mesh's vertices less than ``height`` metres above its
    lowest point (the feet), by side (+X is the character's left)."""
    rest = np.asarray(rest)
    low = np.flatnonzero(rest[:, 1] < rest[:, 1].min() + height)
    return low[rest[low, 0] > 0], low[rest[low, 0] <= 0]


def foot_slide(before, after, ground):
    """Horizontal travel (m) of a foot's contact between two frames: of the foot's vertices below
    ``ground`` in both, the one that moved least (the point it pivots on), or 0 off the ground.

    before, after : (f, 3) float arrays   the foot's vertices in two consecutive frames
    """
    down = (before[:, 1] < ground) & (after[:, 1] < ground)
    if not down.any():
        return 0.0, None
    moves = (after[down] - before[down])[:, [0, 2]]
    lengths = np.einsum("ij,ij->i", moves, moves)
    k = int(np.argmin(lengths))
    return float(np.sqrt(lengths[k])), moves[k]


def contact_moves(before, after, ground, bounds):
    """``foot_slide``'s move for several feet at once: per foot, the (2,) horizontal move (float32
    for float32 frames) of its vertex on the ground in both frames that moved least, or None when
    none is; the same numbers as ``foot_slide`` foot by foot.

    before, after : (F, 3) float arrays   the feet's vertices stacked, foot k in rows
                                          ``bounds[k]:bounds[k + 1]``
    bounds : sequence of ints             (feet + 1) row bounds
    """
    down = (before[:, 1] < ground) & (after[:, 1] < ground)
    moves = (after - before)[:, [0, 2]]
    lengths = np.einsum("ij,ij->i", moves, moves)
    lengths[~down] = np.inf
    out = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        if hi > lo:
            k = lo + int(np.argmin(lengths[lo:hi]))  # the first of the least, as over the foot's own
            out.append(moves[k] if down[k] else None)
        else:
            out.append(None)
    return out
