"""Steering players stepped together (engine/player_steps.py): the numbers of Player.advance."""

import random
from types import SimpleNamespace

import numpy as np
import pytest

from engine import player_steps
from engine.motion_space import MotionSpace
from engine.parameters import Layout, ParameterMap, RootTrack
from engine.player import Player

pytestmark = pytest.mark.skipif(player_steps._OPENBLAS is None, reason="numpy is not built with its wheels' OpenBLAS")


@pytest.fixture(scope="module")
def fan_space(built_steer):
    """speed x turn_rate (cyclic): a speed chain and a left and a right turn (the shared steer space)."""
    with MotionSpace.open(built_steer / "steer.mspace") as space:
        yield space


@pytest.fixture(scope="module")
def grid_space(fan_space):
    """A one-shot space on a grid sheet (jump_height x jump_distance), from the fan's arrays: a
    measured-looking parameter map (bilinear in u with a bend) and the fan's root motion, not
    cyclic (building four real jumps takes a minute)."""
    axis = np.linspace(0.0, 1.0, 11)
    U0, U1 = np.meshgrid(axis, axis, indexing="ij")
    values = np.stack([0.2 + 0.25 * U0 + 0.03 * U0 * U1, 0.3 + 0.7 * U1 - 0.05 * U0 * U1 ** 2], axis=-1)
    grid = ParameterMap(layout=Layout("grid", 4, corners=(0, 2, 1, 3)), names=["jump_height", "jump_distance"],
                        units=["m", "m"], axes=[axis, axis], values=values)
    track = fan_space.root_track
    return SimpleNamespace(name="grid", cyclic=False, parameter_map=grid,
                           root_track=RootTrack(track.durations, track.root_rate, track.turn_rate, cyclic=False))


def _state(player):
    return (player.phase, player.heading, player.time, player.finished, player.position.tobytes(),
            player._current.tobytes(), player._velocity.tobytes(), player.weights.tobytes(),
            player.realised.tobytes(), player._solution.u.tobytes(), player._settled, player.clamped)


def _run(space, seed, steps=240, loop=None):
    """Two sets of players under the same requests and steps, one stepped together, one by one:
    (steps taken together, steps in all); asserts every state equal bit for bit after each step."""
    rng = random.Random(seed)
    domain = space.parameter_map.domain()
    smoothing = [0.25, 0.1, 0.6, 0.0, 0.25, 0.4]
    together = [Player(space, smoothing=s, loop=loop) for s in smoothing * 3]
    alone = [Player(space, smoothing=s, loop=loop) for s in smoothing * 3]
    for a, b in zip(together, alone):
        phase = rng.random()
        a.seek(phase)
        b.seek(phase)
    taken = 0
    for _ in range(steps):
        for a, b in zip(together, alone):
            if rng.random() < 0.05:  # inside the domain, or outside it (clamped: the cold solve)
                margin = 0.0 if rng.random() < 0.7 else 0.5
                request = [rng.uniform(lo - margin * (hi - lo), hi + margin * (hi - lo)) for lo, hi in domain]
                a.set_params(request)
                b.set_params(request)
            if rng.random() < 0.01:
                a.reset()
                b.reset()
        dts = [rng.choice([0.0, rng.uniform(0.0, 0.05)]) for _ in together]
        rest = player_steps.advance_together(together, dts)
        for k in rest:
            together[k].advance(dts[k])
        for b, dt in zip(alone, dts):
            b.advance(dt)
        taken += len(together) - len(rest)
        for a, b in zip(together, alone):
            assert _state(a) == _state(b)
    return taken, steps * len(together)


def test_steering_players_stepped_together_are_bit_for_bit_one_by_one(fan_space):
    taken, total = _run(fan_space, seed=1)
    assert taken > total / 3  # most steering steps were made together


def test_one_shot_players_on_a_grid_too(grid_space):
    for loop in (False, True):
        taken, total = _run(grid_space, seed=2, loop=loop)
        assert taken > total / 3


def test_unfit_players_are_left_to_step_alone(fan_space):
    settled = Player(fan_space)
    instant = Player(fan_space, smoothing=0.0)
    steering = Player(fan_space)
    instant.set_params([2.0, 10.0])
    steering.set_params([2.0, 10.0])
    before = steering.weights
    assert player_steps.advance_together([settled, instant, steering], [0.02, 0.02, 0.02]) == [1]
    assert steering.weights is not before and not steering.settled
    assert settled.time == 0.02 and instant.time == 0.0  # the instant one not stepped: the caller steps it
    assert player_steps.advance_together([steering], [float("nan")]) == [0]  # Player.advance raises on it
    assert player_steps.advance_together([settled], [-1.0]) == [0]


@pytest.mark.parametrize("space", ["fan_space", "grid_space"])
def test_settled_players_stepped_together_are_bit_for_bit_one_by_one(space, request):
    """Settled players (fixed weights) step on their clocks in one compiled pass: the numbers of
    Player.advance, looping or not, to a one-shot clip's end and after it."""
    space = request.getfixturevalue(space)
    rng = random.Random(3)
    domain = space.parameter_map.domain()
    together, alone = [], []
    for k in range(12):
        request = [rng.uniform(lo, hi) for lo, hi in domain]
        for players in (together, alone):
            player = Player(space, loop=bool(k % 2), params=request)
            player.seek(0.1 * k)
            players.append(player)
    for _ in range(150):
        dts = [rng.choice([0.0, rng.uniform(0.0, 0.05)]) for _ in together]
        assert player_steps.advance_together(together, dts) == []
        for b, dt in zip(alone, dts):
            b.advance(dt)
        for a, b in zip(together, alone):
            assert _state(a) == _state(b)
    assert any(player.finished for player in alone) == (not space.cyclic)


def test_a_players_clock_is_its_fields(fan_space):
    """Player.clock holds time, phase, heading, the root, finished and loop: the properties read
    and write it, Python floats and bools in and out, the root a view of it."""
    from engine.player import CLOCK_SIZE, FINISHED, HEADING, LOOP, PHASE, ROOT, TIME

    player = Player(fan_space, loop=False)
    player.seek(0.25)
    player.heading, player.time, player.finished = 1.5, 2.0, True
    player.position[2] = 3.0
    clock = player.clock
    assert clock.shape == (CLOCK_SIZE,) and player.clock_address == clock.ctypes.data
    assert (clock[TIME], clock[PHASE], clock[HEADING], clock[FINISHED]) == (2.0, 0.25, 1.5, 1.0)
    assert clock[ROOT + 2] == 3.0 and clock[LOOP] == 0.0
    assert type(player.phase) is float and type(player.finished) is bool and player.loop is False
    player.reset()
    assert clock.tolist()[:LOOP] == [0.0] * LOOP and player.position.tolist() == [0.0, 0.0, 0.0]


def test_the_products_are_numpys_own():
    """The compiled dot and vector-matrix products give numpy's floats (its BLAS, its order), as
    the module's own check finds before it steps any player together."""
    assert player_steps._blas_agrees()
    rng = np.random.default_rng(0)
    out = np.empty(3)
    for _ in range(2000):
        w = rng.random(4)
        w = w / np.add.reduce(w)
        R, d = rng.standard_normal((4, 3)), rng.uniform(0.5, 2.0, 4)
        assert player_steps._dot(w, d) == float(w.dot(d))
        player_steps._vector_matrix(w, R, out)
        assert out.tobytes() == w.dot(R).tobytes()


def test_a_steering_players_spring_is_read_where_it_lies(fan_space):
    """A batch reads a steering player's spring from its state array (after the clock) and
    writes it back; a request, a step alone or a reset in between makes it copy the spring
    again: every state bit for bit as one by one, and the spring the player's numbers."""
    from engine.player import SPRING

    together, alone = Player(fan_space, smoothing=0.3), Player(fan_space, smoothing=0.3)
    for player in (together, alone):
        player.set_params([2.0, 20.0])

    def spring(player):
        return np.concatenate((player._current, player._velocity, player._target, player._solution.u))

    rng = random.Random(4)
    stepped = 0
    for step in range(300):
        dt = rng.uniform(0.005, 0.03)
        if step % 37 == 5:  # a new request: a new target the spring must take
            request = [rng.uniform(1.0, 2.5), rng.uniform(-30.0, 30.0)]
            together.set_params(request)
            alone.set_params(request)
        if step % 53 == 7:
            together.reset()
            alone.reset()
        if step % 11 == 3:  # a step outside a batch
            together.advance(dt)
        else:
            rest = player_steps.advance_together([together], [dt])
            stepped += not rest
            if rest:
                together.advance(dt)
            else:
                assert together._state[SPRING:SPRING + 8].tobytes() == spring(together).tobytes()
        alone.advance(dt)
        assert _state(together) == _state(alone)
    assert stepped > 150
