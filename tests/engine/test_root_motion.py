"""Root motion: root transforms and root-local meshes estimated from the meshes alone."""

import numpy as np
import pytest

from engine.rotations import rot_y
from engine.root_motion import _moving_average, estimate_root_motion
from engine.synthetic import animate, build_body, gait, jump


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


def test_moving_average_removes_a_periodic_component_exactly():
    for period in (31, 32):
        k = np.arange(2 * period + 3)
        trend = 0.4 * k
        x = trend + 2.0 * np.sin(2 * np.pi * k / period) + 0.5 * np.cos(6 * np.pi * k / period + 1.0)
        np.testing.assert_allclose(_moving_average(x, period, periodic=True), trend, atol=1e-10)


@pytest.mark.parametrize("speed,turn_rate", [(1.3, 0.0), (1.1, 45.0), (3.5, 0.0), (1.0, -60.0)])
def test_root_velocity_and_turn_rate_match_the_motion(body, speed, turn_rate):
    motion = gait(body.skeleton, speed, turn_rate=turn_rate, cycles=2.0, start_phase=0.3)
    root = estimate_root_motion(animate(body, motion), body.F, motion.fps, period=motion.frames_per_cycle,
                                reference=body.V)
    v = root.velocity()
    assert np.degrees(root.turn_rate()).mean() == pytest.approx(turn_rate, abs=0.05)
    assert np.degrees(root.turn_rate()).std() < 0.05  # steady
    assert np.linalg.norm(v[:, [0, 2]], axis=1).std() < 1e-3 * speed  # in-cycle bounce filtered out
    # The centre of mass's path is the root path (in a turn it runs a little inside the pelvis's).
    assert v[:, 2].mean() == pytest.approx(speed, rel=0.02 if turn_rate == 0 else 0.05)
    assert abs(v[:, 0].mean()) < 0.05 * speed  # the root faces where it goes (a turn crabs slightly)
    N = motion.frames_per_cycle
    worst = max(np.abs(root.local[k + N] - root.local[k]).max() for k in range(N))
    assert worst < 0.002  # root-local frames repeat every cycle


def test_root_local_frames_do_not_depend_on_where_the_capture_was_made(body):
    motion = gait(body.skeleton, 1.3, cycles=2.0)
    V = animate(body, motion)
    moved = np.einsum("ab,fnb->fna", rot_y(np.radians(70.0)), V) + np.array([4.0, 0.0, -2.5])
    a = estimate_root_motion(V, body.F, motion.fps, period=motion.frames_per_cycle, reference=body.V)
    b = estimate_root_motion(moved, body.F, motion.fps, period=motion.frames_per_cycle, reference=body.V)
    np.testing.assert_allclose(b.local, a.local, atol=1e-9)
    np.testing.assert_allclose(b.heading - a.heading, np.radians(70.0), atol=1e-9)
    np.testing.assert_allclose(b.world(), moved, atol=1e-9)  # and the split is lossless


def test_jump_root_travels_the_jump_distance(body):
    motion = jump(body.skeleton, 0.35, 0.9)
    root = estimate_root_motion(animate(body, motion), body.F, motion.fps, reference=body.V)
    travel = root.position[-1] - root.position[0]
    assert travel[2] == pytest.approx(0.9, abs=0.03) and abs(travel[0]) < 0.01
    assert np.ptp(root.heading) < np.radians(3)
