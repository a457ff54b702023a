"""Layouts, parameter maps (weights <-> high-level parameters) and blended root tracks."""

import numpy as np
import pytest

from engine.parameters import Layout, ParameterMap, RootTrack


def test_layout_weights_are_exact_at_the_sources():
    chain = Layout("chain", 3, chain=(2, 0, 1))
    np.testing.assert_allclose(chain.weights([0.0]), [0, 0, 1])
    np.testing.assert_allclose(chain.weights([0.5]), [1, 0, 0])
    np.testing.assert_allclose(chain.weights([0.75]), [0.5, 0.5, 0])
    grid = Layout("grid", 4, corners=(0, 1, 2, 3))
    np.testing.assert_allclose(grid.weights([1.0, 0.0]), [0, 1, 0, 0])
    np.testing.assert_allclose(grid.weights([0.5, 0.5]), [0.25] * 4)
    fan = Layout("fan", 4, chain=(0, 1), left=2, right=3)
    np.testing.assert_allclose(fan.weights([0.3, 0.5]), [0.7, 0.3, 0, 0])  # straight ahead
    np.testing.assert_allclose(fan.weights([0.3, 1.0]), [0, 0, 1, 0])  # full left
    np.testing.assert_allclose(fan.weights([0.3, 0.25]), [0.35, 0.15, 0, 0.5])
    for layout in (chain, grid, fan):
        for u in np.random.default_rng(0).uniform(0, 1, (20, layout.dims)):
            w = layout.weights(u)
            assert w.sum() == pytest.approx(1.0) and np.all(w >= 0)


@pytest.mark.parametrize("kwargs,match", [
    (dict(kind="star", n_sources=2), "unknown layout"), (dict(kind="chain", n_sources=2, chain=(0,)), "at least 2"),
    (dict(kind="grid", n_sources=4, corners=(0, 1, 2)), "exactly 4"), (dict(kind="chain", n_sources=2, chain=(0, 0)), "distinct")])
def test_bad_layouts_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Layout(**kwargs)


def _analytic_map():
    """A 2-D map with a known, smooth, non-linear parameter function."""
    layout = Layout("grid", 4, corners=(0, 1, 2, 3))

    def measure(w):
        u = np.array([w[1] + w[3], w[2] + w[3]])  # bilinear weights -> (u0, u1)
        return np.array([0.3 + 0.25 * u[1] + 0.02 * u[0] * u[1], 0.3 + 0.9 * u[0] ** 1.2])

    return ParameterMap.sample(layout, ["jump_height", "jump_distance"], measure, resolution=21), measure


def test_parameter_map_inverts_reachable_requests():
    pmap, measure = _analytic_map()
    for target in ([0.4, 0.6], [0.33, 1.1], [0.55, 0.35]):
        solution = pmap.solve(target)
        assert not solution.clamped
        np.testing.assert_allclose(measure(solution.weights), target, atol=2e-3)  # the true function


def test_unreachable_requests_are_clamped_and_flagged():
    pmap, measure = _analytic_map()
    solution = pmap.solve([0.9, 0.8])  # higher than any jump
    assert solution.clamped and "outside the reachable domain" in solution.message
    assert solution.realised[0] == pytest.approx(pmap.domain()[0][1], abs=0.01)  # as high as it goes
    with pytest.raises(ValueError, match="finite"):
        pmap.solve([np.nan, 0.5])


@pytest.mark.parametrize("far", [1e3, 1e12, 1e16, 1e300])
def test_requests_however_far_out_clamp_to_the_nearest_end(far):
    # squared distances from 1e16 away lose the differences between the reachable points: such a
    # request once clamped to the lowest corner of the map instead of the highest
    pmap, _ = _analytic_map()
    (h_lo, h_hi), (d_lo, d_hi) = pmap.domain()
    middle = (d_lo + d_hi) / 2
    up = pmap.solve([far, middle])
    assert up.clamped and up.realised[0] == pytest.approx(h_hi, abs=0.01)
    down = pmap.solve([-far, middle])
    assert down.clamped and down.realised[0] == pytest.approx(h_lo, abs=0.01)
    assert pmap.solve([far, middle]).realised.tolist() == pmap.solve([10.0, middle]).realised.tolist()
    np.testing.assert_array_equal(up.requested, [far, middle])  # what was asked is kept
    with pytest.raises(ValueError, match="expected 2 parameters"):
        pmap.solve([0.4])


def test_the_unrolled_newton_solver_agrees_with_the_general_gauss_newton():
    pmap, _ = _analytic_map()
    rng = np.random.default_rng(2)
    (lo0, hi0), (lo1, hi1) = pmap.domain()
    for _ in range(300):  # reachable and unreachable requests, from random starts
        p = [rng.uniform(lo0 - 0.1, hi0 + 0.1), rng.uniform(lo1 - 0.2, hi1 + 0.2)]
        u = rng.uniform(0, 1, 2).tolist()
        u_fast, at_fast = pmap._newton_square(p, u)
        u_general, at_general = pmap._gauss_newton_general(p, u)
        np.testing.assert_allclose(u_fast, u_general, atol=1e-9)
        np.testing.assert_allclose(at_fast, at_general, atol=1e-9)


def test_root_track_integrates_straight_and_turning_paths():
    P, T = 16, 1.2
    forward = np.zeros((P, 2, 3))
    forward[:, :, 2] = [1.5 * T, 1.5 * T]  # 1.5 m/s in both sources, per unit phase
    turn = np.zeros((P, 2))
    turn[:, 1] = np.radians(90)  # the second source turns 90 degrees per cycle
    track = RootTrack(np.array([T, T]), forward, turn, cyclic=True)
    position, heading = track.integrate([1.0, 0.0])
    np.testing.assert_allclose(position[-1], [0, 0, 1.5 * T], atol=1e-12)
    position, heading = track.integrate([0.0, 1.0])
    assert heading[-1] == pytest.approx(np.radians(90))
    radius = 1.5 * T / np.radians(90)  # arc length / angle
    np.testing.assert_allclose(position[-1], [radius, 0, radius], rtol=1e-3)


def test_root_after_whole_cycles_composes_the_cycle_step():
    rng = np.random.default_rng(5)
    P = 16
    track = RootTrack(durations=np.array([0.9]), root_rate=rng.normal(0.3, 0.1, (P, 1, 3)),
                      turn_rate=rng.normal(0.4, 0.2, (P, 1)), cyclic=True)
    w = np.array([1.0])
    step, turn = track.integrate(w)
    position, heading = np.zeros(3), 0.0
    for _ in range(7):   # one cycle at a time, rotated by the heading so far
        c, s = np.cos(heading), np.sin(heading)
        position = position + np.array([c * step[-1, 0] + s * step[-1, 2], 0.0, -s * step[-1, 0] + c * step[-1, 2]])
        heading += turn[-1]
    root, h, phase = track.after(w, 7 * 0.9 + 0.45)
    partial_root, partial_heading, half = track.after(w, 0.45)
    c, s = np.cos(heading), np.sin(heading)
    expected = position + np.array([c * partial_root[0] + s * partial_root[2], 0.0,
                                    -s * partial_root[0] + c * partial_root[2]])
    assert phase == pytest.approx(0.5) and half == pytest.approx(0.5)
    np.testing.assert_allclose(root, expected, atol=1e-12)
    assert h == pytest.approx(heading + partial_heading)


def test_root_after_stops_a_one_shot_clip_at_its_end():
    track = RootTrack(durations=np.array([2.0]), root_rate=np.tile([0.0, 0.0, 1.5], (8, 1, 1)),
                      turn_rate=np.zeros((8, 1)), cyclic=False)
    root, heading, phase = track.after(np.array([1.0]), 5.0)
    assert phase == 1.0 and heading == 0.0
    np.testing.assert_allclose(root, [0.0, 0.0, 1.5], atol=1e-12)


def test_fan_weights_are_the_chain_share_and_the_turns_exactly():
    """A two-source fan's weights (computed inline) are _chain_weights' of the speed chain scaled
    by the share left from the turn, plus the turn: the same floats, bit for bit."""
    layout = Layout("fan", 4, chain=(1, 0), left=3, right=2)
    rng = np.random.default_rng(5)
    for u in [[0.0, 0.0], [1.0, 1.0], [0.5, 0.5], [-0.2, 1.3]] + rng.random((200, 2)).tolist():
        expected = [0.0] * 4
        d = 2.0 * min(max(u[1], 0.0), 1.0) - 1.0
        layout._chain_weights(min(max(u[0], 0.0), 1.0), layout.chain, expected, 1.0 - abs(d))
        expected[3] += max(d, 0.0)
        expected[2] += max(-d, 0.0)
        assert layout.weights(u).tolist() == expected
        assert layout.weights(np.array(u)).tolist() == expected
