"""Time-warping: periods, cycle alignment, events of one-shot clips."""

import numpy as np
import pytest

from engine.root_motion import estimate_root_motion
from engine.synthetic import animate, build_body, gait, jump, reach
from engine.timewarp import (
    align_cycle,
    best_circular_shift,
    cycle_at,
    detect_events,
    estimate_period,
    piecewise_warp,
    sample_frames,
)

P = 24


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


def _local(body, motion, period=None):
    V = animate(body, motion)
    return estimate_root_motion(V, body.F, motion.fps, period=period, reference=body.V).local


@pytest.mark.parametrize("speed", [0.8, 1.6, 3.0, 4.5])
def test_period_is_found_on_the_meshes(body, speed):
    motion = gait(body.skeleton, speed, cycles=2.2, start_phase=0.2)
    rough = _local(body, motion)  # no period known yet: short smoothing window
    assert estimate_period(rough, motion.fps) == pytest.approx(motion.frames_per_cycle, abs=0.15)


def test_warping_a_cycle_onto_itself_is_the_identity(body):
    motion = gait(body.skeleton, 1.4, cycles=2.0)
    N = motion.frames_per_cycle
    cycle = cycle_at(_local(body, motion, N), 3.0, N, P)
    np.testing.assert_allclose(align_cycle(cycle, cycle), np.arange(P), atol=1e-9)


def test_a_shifted_cycle_is_aligned_back(body):
    motion = gait(body.skeleton, 1.4, cycles=2.0)
    N = motion.frames_per_cycle
    cycle = cycle_at(_local(body, motion, N), 0.0, N, P)
    shifted = np.roll(cycle, -7, axis=0)  # starts 7 samples later
    assert best_circular_shift(cycle, shifted) == pytest.approx(P - 7, abs=0.05)
    warp = align_cycle(cycle, shifted)
    np.testing.assert_allclose(np.mod(warp, P), np.mod(np.arange(P) - 7, P), atol=1e-9)


def test_jump_events_are_take_off_and_landing(body):
    motion = jump(body.skeleton, 0.4, 0.8)
    events = detect_events(_local(body, motion), model_size=1.75)
    assert events.kind == "jump"
    take_off, landing = events.times
    assert take_off == pytest.approx(motion.events["take_off_frame"], abs=1.0)
    assert landing == pytest.approx(motion.events["landing_frame"], abs=1.0)


def test_reach_event_is_the_peak(body):
    motion = reach(body.skeleton, 1.9)
    events = detect_events(_local(body, motion), model_size=1.75)
    assert events.kind == "peak" and events.times[0] == pytest.approx(motion.events["peak_frame"], abs=2)


def test_piecewise_warp_maps_events_to_common_phases():
    warp = piecewise_warp([20.0, 35.0], 61, [0.25, 0.5])
    np.testing.assert_allclose(warp([0.0, 0.25, 0.5, 1.0]), [0.0, 20.0, 35.0, 60.0])
    assert np.all(np.diff(warp(np.linspace(0, 1, 50))) > 0)


def test_sample_frames_interpolates_linearly():
    frames = np.arange(5.0)[:, None, None] * np.ones((1, 2, 3))
    np.testing.assert_allclose(sample_frames(frames, [0.5, 3.25])[:, 0, 0], [0.5, 3.25])
