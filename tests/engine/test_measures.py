"""Motion parameters measured on mesh sequences."""

import numpy as np
import pytest

from engine import measures


def _circle_walk(speed, turn_deg, fps=30.0, N=32, frames=70, sway=0.03, bounce=0.02):
    """Centre of mass on a circle (or line) with in-cycle sway and bounce of period N frames."""
    t = np.arange(frames) / fps
    w = np.radians(turn_deg)
    heading = w * t
    if w == 0:
        x, z = np.zeros_like(t), speed * t
    else:
        x, z = speed / w * (1 - np.cos(heading)), speed / w * np.sin(heading)
    phase = 2 * np.pi * np.arange(frames) / N
    lateral = sway * np.sin(phase)
    x = x + lateral * np.cos(heading)
    z = z - lateral * np.sin(heading)
    y = 1.0 + bounce * np.cos(2 * phase)
    return np.stack([x, y, z], axis=1)


@pytest.mark.parametrize("speed,turn", [(1.3, 0.0), (1.2, 45.0), (1.0, -90.0), (4.0, 20.0)])
def test_gait_speed_and_turn_rate_of_an_exact_path(speed, turn):
    com = _circle_walk(speed, turn, sway=0.0)
    measured_speed, measured_turn = measures.gait_speed_and_turn_rate(com, 30.0, 32)
    assert measured_speed == pytest.approx(speed, rel=1e-9)
    assert measured_turn == pytest.approx(turn, abs=1e-7)


def test_sway_and_bounce_barely_change_the_measured_speed():
    speed, turn = measures.gait_speed_and_turn_rate(_circle_walk(1.2, 45.0), 30.0, 32)
    assert speed == pytest.approx(1.2, rel=0.01)
    assert turn == pytest.approx(45.0, rel=0.01)


def test_gait_measure_needs_a_whole_cycle():
    with pytest.raises(ValueError, match="at least 33 frames"):
        measures.gait_speed_and_turn_rate(np.zeros((20, 3)), 30.0, 32)


def test_jump_height_distance_and_reach():
    t = np.linspace(0, 1, 41)
    com = np.stack([np.zeros_like(t), 1.0 + 0.4 * np.sin(np.pi * t), 1.2 * t], axis=1)
    assert measures.jump_height(com) == pytest.approx(0.4)
    assert measures.jump_distance(com) == pytest.approx(1.2)
    V = np.zeros((5, 3, 3))
    V[:, :, 1] = np.array([1.0, 1.5, 2.0, 1.4, 1.0])[:, None]  # the hand goes up and back
    assert measures.reach_height(V, [0, 1, 2]) == pytest.approx(2.0)
    V[:, :, 1] = np.array([0.8, 0.6, 0.5, 0.6, 0.8])[:, None]  # ... or down to a low target
    assert measures.reach_height(V, [0, 1]) == pytest.approx(0.5)
