"""The real-time player: parameters -> weights -> phase, root and blended meshes on a clock."""

import numpy as np
import pytest

from engine.motion_space import MotionSpace
from engine.player import Player, _critically_damped


@pytest.fixture(scope="module")
def gait_space(export_spaces):
    """The shared speed chain (gaits at 0.9 and 2.6 m/s)."""
    return export_spaces["speed"]


@pytest.fixture(scope="module")
def jump_space(export_spaces):
    """The shared jump-distance chain (0.3 and 1.0 m)."""
    return export_spaces["jump"]


def test_the_map_spans_the_sources_speeds(gait_space):
    lo, hi = gait_space.parameter_map.domain()[0]
    assert lo == pytest.approx(0.9, rel=0.03) and hi == pytest.approx(2.6, rel=0.03)


@pytest.mark.parametrize("speed", [1.0, 1.6, 2.4])
def test_player_travels_at_the_requested_speed(gait_space, speed):
    player = Player(gait_space, smoothing=0.2, params={"speed": speed})
    dt = 1 / 60
    for _ in range(120):
        frame = player.step(dt)
    start = frame.root_position.copy()
    for _ in range(240):  # four seconds: whole cycles average out
        frame = player.step(dt)
    realised = np.linalg.norm((frame.root_position - start)[[0, 2]]) / 4.0
    lo, hi = gait_space.parameter_map.domain()[0]
    assert abs(realised - speed) <= 0.05 * (hi - lo)
    assert abs(frame.heading) < np.radians(3)  # straight gaits stay straight
    assert not frame.clamped and frame.realised[0] == pytest.approx(speed, abs=0.01)
    assert frame.vertices.dtype == np.float32 and frame.vertices.shape == (gait_space.n_vertices, 3)
    # The body is where the root is: its horizontal centroid follows the root.
    assert np.linalg.norm(frame.vertices.mean(axis=0)[[0, 2]] - frame.root_position[[0, 2]]) < 0.15


def test_parameter_changes_are_smoothed_without_overshoot(gait_space):
    player = Player(gait_space, smoothing=0.3, params={"speed": 1.0})
    player.set_params({"speed": 2.4})
    values = [player.step(1 / 60).requested[0] for _ in range(180)]
    assert values[0] < 1.1  # no jump
    assert np.all(np.diff(values) >= -1e-12) and max(values) <= 2.4 + 1e-9  # monotone, no overshoot
    assert values[-1] == pytest.approx(2.4, abs=0.01)


def test_critically_damped_step_is_exact_and_composes():
    x, v = np.array([0.0]), np.array([0.0])
    one = _critically_damped(x, v, np.array([1.0]), 0.5, 0.2)
    half = _critically_damped(*_critically_damped(x, v, np.array([1.0]), 0.25, 0.2), np.array([1.0]), 0.25, 0.2)
    np.testing.assert_allclose(one, half, atol=1e-12)


def test_unreachable_requests_are_clamped(gait_space):
    player = Player(gait_space, smoothing=0.0)
    solution = player.set_params({"speed": 9.0})
    assert solution.clamped and "clamped" in solution.message
    frame = player.step(1 / 60)
    assert frame.clamped and frame.requested[0] == pytest.approx(gait_space.parameter_map.domain()[0][1], abs=0.02)


@pytest.fixture(scope="module")
def fan_space(built_steer):
    """speed x turn_rate: a speed chain (0.9, 2.6 m/s) and turns of +-40 deg/s at 1.5 m/s (the shared steer space)."""
    with MotionSpace.open(built_steer / "steer.mspace") as space:
        yield space


def test_a_clamped_turn_does_not_lower_the_speed_asked_for(fan_space):
    """Issue 15 item 1: speed asked, a turn clamped (the reachable speed drops), the turn released:
    the player heads back to the speed that was asked, not the clamped one."""
    player = Player(fan_space, smoothing=0.0, params={"speed": 2.2, "turn_rate": 0.0})
    assert not player.clamped and player.target[0] == pytest.approx(2.2, abs=1e-6)
    turning = player.set_params({"turn_rate": 36.0})
    assert turning.clamped and player.target[0] < 2.1  # the fast turns are out of reach
    straight = player.set_params({"turn_rate": 0.0})
    assert not straight.clamped
    assert player.target[0] == pytest.approx(2.2, abs=1e-6)
    assert player.step(1 / 60).requested[0] == pytest.approx(2.2, abs=1e-6)


def test_one_shot_clip_plays_once_and_travels_its_distance(jump_space):
    player = Player(jump_space, smoothing=0.0, params={"jump_distance": 0.7})
    frames = [player.step(1 / 30) for _ in range(200)]
    assert frames[-1].finished and frames[-1].phase == 1.0
    travelled = np.linalg.norm(frames[-1].root_position[[0, 2]])
    assert travelled == pytest.approx(0.7, abs=0.05 * 0.7)
    looping = Player(jump_space, smoothing=0.0, loop=True, params={"jump_distance": 0.7})
    assert not any(looping.step(1 / 30).finished for _ in range(200))


def test_bad_requests_are_clear_errors(gait_space):
    player = Player(gait_space)
    with pytest.raises(ValueError, match="unknown parameter"):
        player.set_params({"sped": 1.0})
    with pytest.raises(ValueError, match="finite"):
        player.set_params({"speed": float("inf")})
    with pytest.raises(ValueError, match="dt"):
        player.step(-0.1)
    with pytest.raises(ValueError, match="unknown blend mode"):
        player.set_mode("cubic")
    player.set_mode("nonlinear")
    assert player.step(1 / 60).vertices.shape == (gait_space.n_vertices, 3)


def test_state_key_stays_the_same_objects_exactly_while_the_frame_fields_do(gait_space):
    player = Player(gait_space, smoothing=0.2)
    player.advance(0.1)
    key = player.state_key
    for _ in range(5):  # settled: the same objects
        player.advance(1 / 60)
        assert all(a is b for a, b in zip(key, player.state_key))
    fields = (player.requested, player.realised, player.weights, player.clamped, player.mode)
    player.set_params({"speed": 2.0})
    changed = player.state_key
    assert any(a is not b for a, b in zip(key, changed))
    player.advance(1 / 60)  # moving: new objects every step, and new values
    assert any(a is not b for a, b in zip(changed, player.state_key))
    assert not np.array_equal(player.requested, fields[0])
    player.set_mode("linear")
    assert player.state_key[3] == "linear"
