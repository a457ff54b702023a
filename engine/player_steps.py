"""Players stepped together: ``advance_together(players, dts)``.

A settled player (fixed weights) steps its clock: phase, root and heading from the rates of its
weights, kept while they are. The settled players of a tick step in one compiled pass
(:func:`_step_settled`) straight on their clocks (``Player.clock``, reached through their
addresses: no per-player gathering or setting), the operations of ``Player.advance`` in its
order: 0.05 us a player instead of 1.5.

A player whose parameters are on their way to a request (``Player.advance`` with the spring
still moving) does, every frame, a spring step, a warm Newton solve on the parameter map's
sheet, the weights at the solution and the blended duration and root rates at the two phase
samples the step needs: a dozen numpy calls on arrays of two to four numbers, 15-20 us in all.
Here the steps of every such player of one space are one compiled call (:func:`_step_moving`)
that reads each player's spring (current, velocity, target, last u) where it lies, after its
clock in one array (``Player._state``, at ``clock_address``; copied there only when a request,
a reset or a step alone replaced those arrays, ``Player._spring_of``) and a pass that writes the
clocks and springs back (:func:`_set_clocks`); what stays per player in Python is the views and
the ``Solution`` the player's fields are (replaced every step, never changed in place):
the same operations in the same order, the Newton solve the same compiled function
(``parameter_map._newton_square_compiled``), and the products of weights and rates through the
very BLAS functions numpy's ``dot`` calls for them (``cblas_ddot`` and ``cblas_dgemv`` of the
OpenBLAS numpy's wheel bundles, whose sums of four terms come out in its kernels' own order and
rounding, not a plain loop's): the same floats, so the same frames
(``tests/engine/test_player_steps.py``).

The players it does not take step one at a time (``Player.advance``): subclasses of Player,
steps it would refuse (a negative or non-finite dt), settled blends of duration 0, steering
players whose parameters settle in this step, whose request lies outside the reachable domain
(the cold solve), whose Newton step meets a singular Jacobian, that follow requests at once
(``smoothing`` 0), on a one-dimensional sheet or with more than two parameters, and every
steering player when numpy's BLAS is not the OpenBLAS of numpy's wheels (its functions cannot
then be called from compiled code) or its products there are not numpy's (checked once,
:func:`_blas_agrees`).
"""

from __future__ import annotations

import ctypes
import glob
import math
import os

import numpy as np
from numba import carray

from engine.jit import compiled, float64_pointer
from engine.parameters.parameter_map import Solution, _newton_square_compiled
from engine.player import CLOCK_SIZE, CYCLIC, FINISHED, HEADING, LOOP, PHASE, ROOT, SPRING, TIME, Player


def _numpy_openblas():
    """The path of the OpenBLAS numpy's wheels bundle (64-bit integers, ``scipy_`` symbols), or
    None where numpy is built otherwise."""
    folder = os.path.join(os.path.dirname(os.path.dirname(np.__file__)), "numpy.libs")
    for path in sorted(glob.glob(os.path.join(folder, "libscipy_openblas64_*.so"))):
        try:
            library = ctypes.CDLL(path)
            library.scipy_cblas_ddot64_, library.scipy_cblas_dgemv64_  # noqa: B018 - both present
        except (OSError, AttributeError):
            continue
        return path
    return None


_OPENBLAS = _numpy_openblas()


@compiled
def _pymax(a, b):  # pragma: no cover (compiled)
    return b if b > a else a  # Python's max(a, b): the first of equals


@compiled
def _pymin(a, b):  # pragma: no cover (compiled)
    return b if b < a else a


@compiled
def _phase_samples(phase, n, cyclic):  # pragma: no cover (compiled)
    """engine.blend.phase.phase_samples."""
    if cyclic:
        x = (phase % 1.0) * n
        p0 = int(x) % n
        return p0, (p0 + 1) % n, x - int(x)
    x = _pymin(_pymax(phase, 0.0), 1.0) * (n - 1)
    p0 = min(int(x), n - 2)
    return p0, p0 + 1, x - p0


@compiled
def _step_settled(clocks, rates, dts):  # pragma: no cover (compiled)
    """Player.advance of K settled players (fixed weights) from their clocks' and settled rates'
    addresses (``Player.clock_address``, ``Player.settled_rates``; (K,) int64 each), dts (K,)
    float64 (finite, >= 0): the same operations in the same order, on the arrays in place."""
    for k in range(len(clocks)):
        clock = carray(float64_pointer(clocks[k]), (CLOCK_SIZE,))
        dt = dts[k]
        if clock[FINISHED] == 0.0 and dt > 0:
            head = carray(float64_pointer(rates[k]), (2,))
            P = int(head[0])
            rate = carray(float64_pointer(rates[k]), (2 + 4 * P,))
            phase, heading = clock[PHASE], clock[HEADING]
            cyclic = clock[CYCLIC] != 0.0
            wraps = cyclic or clock[LOOP] != 0.0
            d_phase = dt / rate[1]
            if not wraps:
                d_phase = _pymin(d_phase, 1.0 - phase)
            middle = phase + 0.5 * d_phase
            p0, p1, a = _phase_samples(middle % 1.0 if wraps else middle, P, cyclic)
            i0, i1 = 2 + 4 * p0, 2 + 4 * p1
            sx, sz = rate[i0] + a * (rate[i1] - rate[i0]), rate[i0 + 2] + a * (rate[i1 + 2] - rate[i0 + 2])
            t = rate[i0 + 3] + a * (rate[i1 + 3] - rate[i0 + 3])
            heading_middle = heading + 0.5 * t * d_phase
            c, s = math.cos(heading_middle), math.sin(heading_middle)
            clock[ROOT] = clock[ROOT] + (c * sx + s * sz) * d_phase
            clock[ROOT + 2] = clock[ROOT + 2] + (c * sz - s * sx) * d_phase
            clock[HEADING] = heading + t * d_phase
            phase += d_phase
            if wraps:
                phase %= 1.0
            elif phase >= 1.0 - 1e-12:
                phase, clock[FINISHED] = 1.0, 1.0
            clock[PHASE] = phase
        clock[TIME] = clock[TIME] + dt


if _OPENBLAS is not None:
    import llvmlite.binding
    from numba import types

    llvmlite.binding.load_library_permanently(_OPENBLAS)
    _ddot = types.ExternalFunction("scipy_cblas_ddot64_", types.float64(
        types.int64, types.voidptr, types.int64, types.voidptr, types.int64))
    _dgemv = types.ExternalFunction("scipy_cblas_dgemv64_", types.void(
        types.int32, types.int32, types.int64, types.int64, types.float64, types.voidptr, types.int64,
        types.voidptr, types.int64, types.float64, types.voidptr, types.int64))
    ROW_MAJOR, TRANS = 101, 112  # CBLAS enums

    @compiled
    def _dot(x, y):  # pragma: no cover (compiled)
        """``float(x.dot(y))`` for contiguous (n,) float64 arrays: numpy's 0. + cblas_ddot."""
        return 0.0 + _ddot(len(x), x.ctypes, 1, y.ctypes, 1)

    @compiled
    def _vector_matrix(x, A, out):  # pragma: no cover (compiled)
        """``x.dot(A)`` into ``out`` for (n,) and C-contiguous (n, 3) float64: numpy's gemv."""
        _dgemv(ROW_MAJOR, TRANS, A.shape[0], A.shape[1], 1.0, A.ctypes, A.shape[1], x.ctypes, 1, 0.0, out.ctypes, 1)

    @compiled
    def _weights(u0, u1, kind, chain, left, right, corners, w):  # pragma: no cover (compiled)
        """Layout.weights of a fan (kind 0) or a grid (kind 1) at (u0, u1), into zeroed ``w``."""
        u0, u1 = _pymin(_pymax(u0, 0.0), 1.0), _pymin(_pymax(u1, 0.0), 1.0)
        if kind == 1:
            a, b = u0, u1
            w[corners[0]] += (1 - a) * (1 - b)
            w[corners[1]] += a * (1 - b)
            w[corners[2]] += (1 - a) * b
            w[corners[3]] += a * b
            return
        d = 2.0 * u1 - 1.0
        share = 1.0 - abs(d)
        L = len(chain)
        if L == 1:
            w[chain[0]] += share
        else:
            x = _pymin(_pymax(u0, 0.0), 1.0) * (L - 1)
            i = min(int(x), L - 2)
            a = x - i
            w[chain[i]] += share * (1.0 - a)
            w[chain[i + 1]] += share * a
        w[left] += _pymax(d, 0.0)
        w[right] += _pymax(-d, 0.0)

    @compiled
    def _step_moving(clocks, dts, taus, values, last, ranges, bounds, kind, chain, left, right, corners, durations,
                     root_rate, turn_rate, cyclic, W, pairs, out, done):  # pragma: no cover (compiled)
        """Player.advance of K players whose parameters move (see the module docstring).

        clocks : (K,) int64       the players' ``clock_address``: their clocks and, after them
            (``SPRING``), their springs' current (2), velocity (2), target (2) and the last
            solution's u (2) (read here, not changed)
        dts, taus : (K,) float64  the steps and the springs' time constants (``smoothing``)
        pairs : (K, 4, 2) float64 current, velocity, u, realised
        out : (K, 6) float64      phase, heading, x, z, time, finished
        W : (K, N) float64 zeroed: the weights;  done : (K,) bool: False where the player must
            step on its own (nothing of it is then to be used)
        """
        P = turn_rate.shape[0]
        s0, s1 = root_rate.shape[1], root_rate.shape[2]
        rates0, rates1 = np.empty(s1), np.empty(s1)
        wn = np.empty(s0)
        for k in range(len(clocks)):
            done[k] = False
            row = carray(float64_pointer(clocks[k]), (SPRING + 8,))[SPRING:]
            dt, tau = dts[k], taus[k]
            if not (dt >= 0 and math.isfinite(dt)) or not tau > 0:
                continue
            # the spring (engine.player._critically_damped_lists)
            ws = 1.0 / tau
            decay = math.exp(-ws * dt)
            settled = True
            for i in range(2):
                xi, vi, ti = row[i], row[2 + i], row[4 + i]
                y = xi - ti
                c = vi + ws * y
                x_new = ti + (y + c * dt) * decay
                v_new = (vi - ws * c * dt) * decay
                pairs[k, 0, i], pairs[k, 1, i] = x_new, v_new
                if not (abs(x_new - ti) <= 1e-6 * ranges[i] and abs(v_new) * dt <= 1e-6 * ranges[i]):
                    settled = False
            if settled:
                continue
            # ParameterMap.solve_near, warm from the last solution
            q0 = _pymin(_pymax(pairs[k, 0, 0], bounds[0, 0]), bounds[0, 1])
            q1 = _pymin(_pymax(pairs[k, 0, 1], bounds[1, 0]), bounds[1, 1])
            u0 = _pymin(_pymax(row[6], 0.0), 1.0)
            u1 = _pymin(_pymax(row[7], 0.0), 1.0)
            ok, u0, u1, at0, at1 = _newton_square_compiled(values, last, ranges[0], ranges[1], q0, q1, u0, u1)
            if not ok or abs(at0 - pairs[k, 0, 0]) > 0.005 * ranges[0] or abs(at1 - pairs[k, 0, 1]) > 0.005 * ranges[1]:
                continue  # the general solver, or the cold solve of a clamped request
            pairs[k, 2, 0], pairs[k, 2, 1], pairs[k, 3, 0], pairs[k, 3, 1] = u0, u1, at0, at1
            w = W[k]
            _weights(u0, u1, kind, chain, left, right, corners, w)
            clock = carray(float64_pointer(clocks[k]), (CLOCK_SIZE,))
            phase, heading, x, z, time = clock[PHASE], clock[HEADING], clock[ROOT], clock[ROOT + 2], clock[TIME]
            finished, loop = clock[FINISHED] != 0.0, clock[LOOP] != 0.0
            if not finished and dt > 0:
                total = 0.0
                for i in range(len(w)):
                    total += w[i]  # np.add.reduce of a few values: in order
                for i in range(len(w)):
                    wn[i] = w[i] / total
                duration = _dot(wn, durations)
                d_phase = dt / duration
                if not cyclic and not loop:
                    d_phase = _pymin(d_phase, 1.0 - phase)
                middle = phase + 0.5 * d_phase
                p0, p1, a = _phase_samples(middle % 1.0 if cyclic or loop else middle, P, cyclic)
                _vector_matrix(wn, root_rate[p0], rates0)
                _vector_matrix(wn, root_rate[p1], rates1)
                t0, t1 = _dot(turn_rate[p0], wn), _dot(turn_rate[p1], wn)
                sx, sz = rates0[0] + a * (rates1[0] - rates0[0]), rates0[2] + a * (rates1[2] - rates0[2])
                t = t0 + a * (t1 - t0)
                heading_middle = heading + 0.5 * t * d_phase
                c, s = math.cos(heading_middle), math.sin(heading_middle)
                x = x + (c * sx + s * sz) * d_phase
                z = z + (c * sz - s * sx) * d_phase
                heading += t * d_phase
                phase += d_phase
                if cyclic or loop:
                    phase %= 1.0
                elif phase >= 1.0 - 1e-12:
                    phase, finished = 1.0, True
            out[k, 0], out[k, 1], out[k, 2], out[k, 3] = phase, heading, x, z
            out[k, 4], out[k, 5] = time + dt, 1.0 if finished else 0.0
            done[k] = True


_AGREES = []  # [bool] once checked


def _blas_agrees():
    """Whether the compiled products give numpy's floats here (checked once, on a few hundred
    random weights: a numpy whose ``dot`` sums in another order turns the batch off)."""
    if _OPENBLAS is None:
        return False
    if not _AGREES:
        rng = np.random.default_rng(0)
        out, same = np.empty(3), True
        for _ in range(256):
            w = rng.random(4)
            w = w / np.add.reduce(w)
            A, d = rng.standard_normal((4, 3)), rng.uniform(0.5, 2.0, 4)
            _vector_matrix(w, A, out)
            same = same and _dot(w, d) == float(w.dot(d)) and out.tobytes() == w.dot(A).tobytes()
        _AGREES.append(same)
    return _AGREES[0]


def _takes(player):
    """Whether ``player`` may step in a batch: an engine Player (not a subclass), steering (not
    settled, smoothing > 0), two parameters on a two-dimensional fan or grid."""
    if type(player) is not Player or player._settled or not player.smoothing > 0:
        return False
    layout = player.map.layout
    return layout.kind in ("fan", "grid") and len(player.names) == 2


def _space_arrays(player):
    """The compiled step's arrays of ``player``'s space (kept on its parameter map)."""
    cached = getattr(player.map, "_steps_arrays", None)
    if cached is not None and cached[0] is player.track:
        return cached[1]
    pmap, layout, track = player.map, player.map.layout, player.track
    arrays = (pmap._values_array, pmap._last, np.array(pmap._ranges_list), np.array(pmap._solve_bounds),
              0 if layout.kind == "fan" else 1, np.array(layout.chain or (0,), dtype=np.int64), layout.left,
              layout.right, np.array(layout.corners or (0, 0, 0, 0), dtype=np.int64),
              # writable C-order copies (a space's mapped arrays would be another type to numba)
              np.array(track.durations, dtype=np.float64), np.array(track.root_rate, dtype=np.float64, order="C"),
              np.array(track.turn_rate, dtype=np.float64, order="C"), bool(track.cyclic))
    pmap._steps_arrays = (track, arrays)
    return arrays


def advance_together(players, dts):
    """``player.advance(dt)`` for the players of ``players`` (with their ``dts``, seconds) that
    can step together: the settled ones in one compiled call (:func:`_step_settled`, on their
    clocks in place), the steering ones of each space in one compiled call per space. Returns the
    indices of the others, for the caller to step one by one (``Player.advance``, which raises
    where it must). Every compiled call that may raise is made before any player changes: if
    one raises, no player has been stepped."""
    moving = _blas_agrees()
    rest, groups, clocks, rates, steps = [], {}, [], [], []
    for index, player in enumerate(players):
        if type(player) is Player:
            if player._settled:
                dt = dts[index]
                if 0.0 <= dt < math.inf:  # (Player.advance raises on the others)
                    kept = player._rates  # (settled_rates(), its usual case inline)
                    address = kept[2] if kept is not None and kept[0] is player._solution.weights \
                        else player.settled_rates()
                    if address:
                        clocks.append(player.clock_address)
                        rates.append(address)
                        steps.append(dt)
                        continue
            elif moving and _takes(player):
                groups.setdefault(id(player.map), []).append(index)
                continue
        rest.append(index)
    stepped = [(members, _step_group([players[i] for i in members], [dts[i] for i in members]))
               for members in groups.values()]
    if clocks:  # (raises nothing: no division by zero, every address a live player's)
        _step_settled(np.array(clocks, dtype=np.int64), np.array(rates, dtype=np.int64),
                      np.array(steps, dtype=np.float64))
    for members, results in stepped:
        rest.extend(_commit([players[i] for i in members], members, *results))
    return rest


def _step_group(players, dts):
    """The compiled step of one space's steering players: (clocks, W, pairs, out, done)
    (``_step_moving``). A player's spring is read where it lies, after its clock: copied there
    first only when the player's parameters changed outside a batch (a request, a step alone)."""
    K = len(players)
    clocks, taus = [], []
    for player in players:
        kept = player._spring_of
        if kept is None or kept[0] is not player._current or kept[1] is not player._target \
                or kept[2] is not player._solution:
            _copy_spring(player)
        clocks.append(player.clock_address)
        taus.append(player.smoothing)
    clocks = np.array(clocks, dtype=np.int64)
    W = np.zeros((K, players[0].map.layout.n_sources))
    pairs, out = np.empty((K, 4, 2)), np.empty((K, 6))
    done = np.empty(K, dtype=np.bool_)
    _step_moving(clocks, np.array(dts, dtype=np.float64), np.array(taus, dtype=np.float64),
                 *_space_arrays(players[0]), W, pairs, out, done)
    return clocks, W, pairs, out, done


def _copy_spring(player):
    """Copy ``player``'s current, velocity, target and last u into its spring (after its clock)."""
    current, target, solution = player._current, player._target, player._solution
    player._state[SPRING:SPRING + 8] = np.concatenate((current, player._velocity, target, solution.u))
    player._spring_of = (current, target, solution)


@compiled
def _set_clocks(clocks, pairs, out, done):  # pragma: no cover (compiled)
    """The clocks and springs (``clock_address``) of the players ``_step_moving`` stepped
    (``done``) from its ``pairs`` and ``out``: phase, heading, root x and z, time, finished;
    current, velocity and u (the target stays)."""
    for k in range(len(clocks)):
        if done[k]:
            state = carray(float64_pointer(clocks[k]), (SPRING + 8,))
            state[PHASE], state[HEADING], state[ROOT], state[ROOT + 2] = out[k, 0], out[k, 1], out[k, 2], out[k, 3]
            state[TIME], state[FINISHED] = out[k, 4], out[k, 5]
            for i in range(2):
                state[SPRING + i], state[SPRING + 2 + i] = pairs[k, 0, i], pairs[k, 1, i]
                state[SPRING + 6 + i] = pairs[k, 2, i]


def _commit(players, indices, clocks, W, pairs, out, done):
    """Set the players' state from ``_step_moving``'s results; returns the indices of those it
    did not step."""
    _set_clocks(clocks, pairs, out, done)
    rest = []
    # (views of the results, made in two C loops: replaced, never changed in place: Player.state_key)
    views, weights = list(pairs.reshape(-1, 2)), list(W)
    for k, (player, flag) in enumerate(zip(players, done.tolist())):
        if not flag:
            rest.append(indices[k])
            continue
        c = views[4 * k]
        solution = Solution(weights[k], views[4 * k + 2], c, views[4 * k + 3], False)
        player._current, player._velocity, player._solution = c, views[4 * k + 1], solution
        player._spring_of = (c, player._target, solution)  # (the numbers _set_clocks wrote)
    return rest


def warm_up():
    """Compile (or load from numba's cache) the steps (a server does so before it serves)."""
    state = np.zeros((1, SPRING + 8))
    state[0, CYCLIC] = 1.0
    clocks = np.array([state.ctypes.data], dtype=np.int64)
    rates = np.array([2.0, 1.0, 0, 0, 0, 0, 0, 0, 0, 0])
    _step_settled(clocks, np.array([rates.ctypes.data], dtype=np.int64), np.array([0.01]))
    pairs, out, done = np.zeros((1, 4, 2)), np.zeros((1, 6)), np.zeros(1, dtype=np.bool_)
    _set_clocks(clocks, pairs, out, done)
    if not _blas_agrees():
        return
    values = np.zeros((2, 2, 2))
    values[1, :, 0] = 1.0
    values[:, 1, 1] = 1.0
    state[0, SPRING + 4:SPRING + 6] = 0.5
    one = np.zeros(1, dtype=np.int64)
    _step_moving(clocks, np.array([0.01]), np.array([0.25]), values, 1, np.ones(2), np.array([[-1.0, 2.0], [-1.0, 2.0]]),
                 0, one, 0, 0, np.zeros(4, dtype=np.int64), np.ones(1), np.zeros((2, 1, 3)), np.zeros((2, 1)), True,
                 np.zeros((1, 1)), pairs, out, done)
