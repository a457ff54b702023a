"""The real-time player: a motion space driven by high-level parameters on a continuous clock.

``player = Player(space)``; ``player.set_params({"speed": 2.0, "turn_rate": 30})``;
``frame = player.step(dt)`` per display frame. Each step

1. moves the current parameters towards the requested ones with a critically damped spring
   (time constant ``smoothing`` seconds; no overshoot, no jumps),
2. turns them into blend weights with the space's parameter map,
3. advances the phase by dt / duration(w), the blended duration of a cycle (or clip),
4. integrates the blended root velocity and turn rate over the step, so the character travels
   the path it is steered along (paper fig. 8),
5. blends the root-local mesh (linear, hybrid or non-linear) and places it at the root.

Cyclic spaces loop; one-shot spaces (jumps, reaches) stop at the end of the clip unless looping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.blend.phase import phase_samples

MODES = ("linear", "hybrid", "nonlinear")
SMOOTHING = 0.25  # s, the parameter spring's time constant unless asked otherwise
# A player's clock in one float64 array (``Player.clock``), so that a server steps many players'
# clocks in one compiled pass and frames their headers from them (engine/player_steps.py): the
# time, phase, heading, the root (x, y, z), finished, loop and cyclic (1.0 or 0.0) at these indices
TIME, PHASE, HEADING, ROOT, FINISHED, LOOP, CYCLIC = 0, 1, 2, 3, 6, 7, 8
CLOCK_SIZE = 9
# Right after the clock, in the same array, the spring's numbers as a batch of steering players
# reads and writes them (engine/player_steps.py; k parameters): current (k), velocity (k), target
# (k), the last solution's u (k), valid while ``Player._spring_of`` names the arrays they copy
SPRING = CLOCK_SIZE


@dataclass
class PlayerFrame:
    """One played frame.

    time : float (s); phase : float in [0, 1]; weights : (N,) float
    requested, realised : (k,) parameters asked for (after smoothing) and reached
    clamped : bool   the request lies outside what the space can do
    root_position : (3,) float; heading : float (rad about +Y)
    vertices : (n, 3) float32 world positions
    finished : bool  a one-shot clip has reached its end
    """

    time: float
    phase: float
    weights: np.ndarray
    requested: np.ndarray
    realised: np.ndarray
    clamped: bool
    root_position: np.ndarray
    heading: float
    vertices: np.ndarray
    finished: bool


def _critically_damped(x, v, target, dt, tau):
    """Exact step of x'' = -2 w x' - w^2 (x - target), w = 1 / tau: no overshoot.

    x, v, target : (k,) float arrays. Plain Python per component (k is one or two; the
    player steps every frame)."""
    if tau <= 0:
        return target.copy(), np.zeros_like(v)
    xs, vs = _critically_damped_lists(x.tolist(), v.tolist(), target.tolist(), dt, tau)
    return np.array(xs), np.array(vs)


def _critically_damped_lists(x, v, target, dt, tau):
    """``_critically_damped`` on lists of floats (tau > 0), returning lists: the player's step."""
    w = 1.0 / tau
    decay = math.exp(-w * dt)
    xs, vs = [], []
    for xi, vi, ti in zip(x, v, target):
        y = xi - ti
        c = vi + w * y
        xs.append(ti + (y + c * dt) * decay)
        vs.append((vi - w * c * dt) * decay)
    return xs, vs


class Player:
    """Plays a motion space under high-level parameters.

    Parameters
    ----------
    space : MotionSpace   with a parameter map
    mode : str            "linear", "hybrid" (default) or "nonlinear"
    smoothing : float     time constant (s) of the parameter spring; 0 follows requests at once
    loop : bool or None   one-shot spaces: restart at the end (default: cyclic spaces loop, others not)
    params : mapping or sequence or None   initial request (default: the middle of the domain)
    """

    def __init__(self, space, *, mode="hybrid", smoothing=SMOOTHING, loop=None, params=None):
        if space.parameter_map is None:
            raise ValueError(f"{space.name}: the space has no parameter map (build it from a spec)")
        self.space = space
        k = len(space.parameter_map.names)
        self._state = np.zeros(SPRING + 4 * k)  # the clock, then the spring's numbers (SPRING)
        self._clock = self._state[:CLOCK_SIZE]  # (the properties time, phase, ... read and write it)
        self.clock_address = self._clock.ctypes.data  # (fixed while the player lives: the array is never replaced)
        # (current, target, solution) whose numbers _state[SPRING:] holds, or None: the arrays
        # are replaced, never changed in place, so a step in Python (or a request) leaves these
        # behind and engine/player_steps.py copies them again before it reads the spring
        self._spring_of = None
        self._position = self._clock[ROOT:ROOT + 3]
        self._clock[CYCLIC] = 1.0 if space.cyclic else 0.0
        self._track_cache = None
        self._rates = None  # (weights, their rates as one float64 array): Player.settled_rates
        self.map = space.parameter_map
        self.track = space.root_track
        self.names = list(self.map.names)
        self._ranges = np.asarray(self.map.ranges, dtype=float).tolist()
        self.set_mode(mode)
        if not (np.isfinite(smoothing) and smoothing >= 0):
            raise ValueError(f"smoothing must be a non-negative number of seconds, got {smoothing}")
        self.smoothing = float(smoothing)
        self.loop = space.cyclic if loop is None else bool(loop)
        middle = np.array([(lo + hi) / 2 for lo, hi in self.map.domain()])
        self._target = middle
        self._request = middle.copy()  # the last request as asked (not clamped): a {name: value} update keeps the rest
        self._current = middle.copy()
        self._velocity = np.zeros_like(middle)
        self._settled = True
        self.reset()
        if params is not None:
            self.set_params(params, immediate=True)

    @property
    def clock(self):
        """(CLOCK_SIZE,) float64: the clock's state (``TIME``, ``PHASE``, ... index it), stepped in
        place; compiled code reaches it at ``clock_address``."""
        return self._clock

    # the clock's fields: Python floats and bools in, Python floats and bools out

    @property
    def time(self):
        """Seconds played."""
        return self._clock.item(TIME)

    @time.setter
    def time(self, value):
        self._clock[TIME] = value

    @property
    def phase(self):
        """The phase in [0, 1]."""
        return self._clock.item(PHASE)

    @phase.setter
    def phase(self, value):
        self._clock[PHASE] = value

    @property
    def heading(self):
        """The root's heading (rad about +Y)."""
        return self._clock.item(HEADING)

    @heading.setter
    def heading(self, value):
        self._clock[HEADING] = value

    @property
    def position(self):
        """(3,) float64 the root's position (a view of ``clock``: changed in place as it moves)."""
        return self._position

    @property
    def finished(self):
        """A one-shot clip has reached its end."""
        return self._clock.item(FINISHED) != 0.0

    @finished.setter
    def finished(self, value):
        self._clock[FINISHED] = 1.0 if value else 0.0

    @property
    def loop(self):
        """A one-shot space restarts at its end."""
        return self._clock.item(LOOP) != 0.0

    @loop.setter
    def loop(self, value):
        self._clock[LOOP] = 1.0 if value else 0.0

    @property
    def requested(self):
        """(k,) the parameters now (smoothed on their way to ``target``)."""
        return self._current.copy()

    @property
    def asked(self):
        """(k,) the last request as it was asked (before clamping to what can be reached)."""
        return self._request.copy()

    @property
    def target(self):
        """(k,) where the parameters are heading: the reachable part of the last request."""
        return self._target.copy()

    def reset(self):
        """Back to phase 0 at the origin, facing +Z."""
        self.time = 0.0
        self.phase = 0.0
        self._position[:] = 0.0
        self.heading = 0.0
        self.finished = False
        self._solution = self.map.solve(self._current)
        self._last_request = self._solution

    def set_mode(self, mode):
        if mode not in MODES:
            raise ValueError(f"unknown blend mode {mode!r}; choose one of {', '.join(MODES)}")
        self.mode = mode

    def _as_vector(self, params):
        if isinstance(params, dict):
            unknown = sorted(set(params) - set(self.names))
            if unknown:
                raise ValueError(f"unknown parameter(s) {', '.join(unknown)}; this space has {', '.join(self.names)}")
            values = self._request.copy()  # what was asked for, not where the clamp put it
            for name, value in params.items():
                values[self.names.index(name)] = value
        else:
            values = np.asarray(params, dtype=float)
            if values.shape != (len(self.names),):
                raise ValueError(f"expected {len(self.names)} parameters ({', '.join(self.names)}), got {values.shape}")
        values = np.asarray(values, dtype=float)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"parameters must be finite numbers, got {values.tolist()}")
        return values

    def set_params(self, params, *, immediate=False):
        """Request parameters (a {name: value} mapping or a vector in ``names`` order).

        Returns the map's Solution for the request: ``clamped`` and ``message`` say whether it is
        reachable. Unreachable requests are clamped to the nearest reachable parameters. A mapping
        changes only the named parameters of the last request *as it was asked*: a turn clamped at
        high speed lowers the reachable speed only while the turn is asked for, and asking for
        straight ahead again heads back to the speed that was asked.
        """
        target = self._as_vector(params)
        solution = self.map.solve(target)
        self._request = target.copy()
        self._target = solution.realised.copy()  # steer towards what can be reached
        if immediate:
            self._current = self._target.copy()
            self._velocity = np.zeros_like(self._velocity)
            self._solution = self._solve(self._current)
            self._settled = True
        else:
            self._settled = bool(np.array_equal(self._current, self._target) and not np.any(self._velocity))
        self._last_request = solution
        return solution

    def _solve(self, params):
        """The map's solution for ``params``, warm-started from the last one (parameters move
        continuously between steps); a cold start where the warm one does not reach."""
        solution = self.map.solve_near(params, self._solution.u)
        if solution.clamped:
            solution = self.map.solve(params)
        return solution

    def seek(self, phase):
        """Jump to ``phase`` in [0, 1] (the root stays where it is)."""
        phase = float(phase)
        if not np.isfinite(phase):
            raise ValueError(f"phase must be finite, got {phase}")
        self.phase = phase % 1.0 if self.space.cyclic else min(max(phase, 0.0), 1.0)
        self.finished = False

    def _track_at(self, w):
        """(step (P, 3), turn (P,), duration) of the blend at weights w, kept while w is."""
        cache = self._track_cache
        if cache is not None and cache[4] is w:  # the same weights array (never changed in place)
            return cache[1:4]
        key = w.tobytes()
        if cache is None or cache[0] != key:
            step, turn = self.track.rates(w)
            cache = (key, step.tolist(), turn.tolist(), self.track.duration(w), w)
        else:
            cache = cache[:4] + (w,)
        self._track_cache = cache
        return cache[1:4]

    def settled_rates(self):
        """The address of one float64 array, kept while the weights are, holding what a settled
        step reads (engine/player_steps.py): the phase samples P, the blend's duration, then per
        sample the root's step (x, y, z) and turn per unit phase (``_track_at``'s numbers); 0
        where the duration is 0 (``advance`` raises there)."""
        w = self._solution.weights
        kept = self._rates
        if kept is not None and kept[0] is w:
            return kept[2]
        step, turn, duration = self._track_at(w)
        rates = np.empty(2 + 4 * len(turn))
        rates[0], rates[1] = len(turn), duration
        table = rates[2:].reshape(-1, 4)
        table[:, :3], table[:, 3] = step, turn
        self._rates = (w, rates, rates.ctypes.data if duration != 0.0 else 0)
        return self._rates[2]

    @property
    def weights(self):
        """(N,) the blend weights now (read-only view; do not modify)."""
        return self._solution.weights

    @property
    def realised(self):
        """(k,) the parameters the current weights realise (read-only view)."""
        return self._solution.realised

    @property
    def clamped(self):
        """Whether the last request lay outside what the space can do."""
        return bool(self._last_request.clamped)

    @property
    def state_key(self):
        """A tuple of objects that stay the same (``is``) while ``requested``, ``realised``,
        ``weights``, ``clamped`` and ``mode`` do (they are replaced, never changed in place): a
        caller deriving something from those every frame can keep it while they do."""
        return self._current, self._solution, self._last_request, self.mode

    def reported(self):
        """(mode, requested, realised, clamped, weights): the parameters' fields a frame reports,
        the arrays themselves (replaced, never changed in place: do not modify them)."""
        solution = self._solution
        return self.mode, self._current, solution.realised, bool(self._last_request.clamped), solution.weights

    @property
    def settled(self):
        """The parameters have reached their target (the weights stay fixed until a new request)."""
        return self._settled

    def step(self, dt, out=None, local=False):
        """Advance the clock by ``dt`` seconds and return the frame there (``frame(out, local)``)."""
        self.advance(dt)
        return self.frame(out=out, local=local)

    def advance(self, dt):
        """Advance the clock by ``dt`` seconds: parameters, weights, phase and root (no blend)."""
        dt = float(dt)
        if not (dt >= 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a non-negative number of seconds, got {dt}")
        if not self._settled:
            target = self._target.tolist()
            if self.smoothing <= 0:  # (as _critically_damped steps)
                xs, vs = target, [0.0] * len(target)
            else:
                xs, vs = _critically_damped_lists(self._current.tolist(), self._velocity.tolist(), target, dt,
                                                  self.smoothing)
            # settled to a millionth of each range: stop moving (the weights then stay fixed,
            # which lets the blender use its phase tables)
            if all(abs(x - t) <= 1e-6 * r and abs(v) * dt <= 1e-6 * r for x, t, v, r in
                   zip(xs, target, vs, self._ranges)):
                self._current, self._velocity = self._target.copy(), np.zeros_like(self._velocity)
                self._settled = True
            else:
                self._current, self._velocity = np.array(xs), np.array(vs)
            self._solution = self._solve(self._current)
        w = self._solution.weights
        clock = self._clock
        time_, phase, heading, x, _, z, finished, loop, cyclic = clock.tolist()
        if finished == 0.0 and dt > 0:
            track = self.track
            if self._settled:  # fixed weights: the whole cycle's rates, kept
                step, turn, duration = self._track_at(w)
            else:              # moving weights: only the two samples this step needs (``dot``: the
                wn = w / np.add.reduce(w)  # numbers of ``@``, with less overhead for these sizes)
                duration = float(wn.dot(track.durations))
            cyclic, wraps = cyclic != 0.0, cyclic != 0.0 or loop != 0.0
            d_phase = dt / duration
            if not wraps:
                d_phase = min(d_phase, 1.0 - phase)
            middle = phase + 0.5 * d_phase
            p0, p1, a = phase_samples(middle % 1.0 if wraps else middle, len(track.turn_rate), cyclic)
            if self._settled:
                s0, s1, t0, t1 = step[p0], step[p1], turn[p0], turn[p1]
            else:
                s0, s1 = wn.dot(track.root_rate[p0]).tolist(), wn.dot(track.root_rate[p1]).tolist()
                t0, t1 = float(track.turn_rate[p0].dot(wn)), float(track.turn_rate[p1].dot(wn))
            sx, sz = s0[0] + a * (s1[0] - s0[0]), s0[2] + a * (s1[2] - s0[2])
            t = t0 + a * (t1 - t0)
            heading_middle = heading + 0.5 * t * d_phase
            c, s = math.cos(heading_middle), math.sin(heading_middle)  # rot_y(heading_middle) @ step
            clock[ROOT] = x + (c * sx + s * sz) * d_phase
            clock[ROOT + 2] = z + (c * sz - s * sx) * d_phase
            clock[HEADING] = heading + t * d_phase
            phase += d_phase
            if wraps:
                phase %= 1.0
            elif phase >= 1.0 - 1e-12:
                phase, clock[FINISHED] = 1.0, 1.0
            clock[PHASE] = phase
        clock[TIME] = time_ + dt

    def frame(self, out=None, local=False):
        """The frame at the current state (nothing advances).

        ``local`` leaves the vertices in the root's frame (the root transform is in the frame's
        ``root_position`` and ``heading``): what a renderer that places the mesh itself wants.
        """
        w = self._solution.weights
        mesh = self.space.frame_blender(self.mode).blend(w, self.phase)
        vertices = np.empty((len(mesh), 3), dtype=np.float32) if out is None else out
        if local:
            vertices[:] = mesh
        else:
            c, s = math.cos(self.heading), math.sin(self.heading)
            RT = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]], dtype=np.float32)  # R^T, R about +Y
            np.matmul(np.asarray(mesh, dtype=np.float32), RT, out=vertices)  # one BLAS product
            # the root position column by column: a (3,) broadcast over (n, 3) rows is 3x slower
            for axis, x in enumerate(self.position.tolist()):
                if x != 0.0:
                    vertices[:, axis] += np.float32(x)
        return PlayerFrame(time=self.time, phase=self.phase, weights=w.copy(), requested=self._current.copy(),
                           realised=self._solution.realised.copy(), clamped=self._last_request.clamped,
                           root_position=self.position.copy(), heading=float(self.heading), vertices=vertices,
                           finished=self.finished)
