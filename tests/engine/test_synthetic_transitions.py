"""Motions that connect the others (engine.synthetic.transitions): idles, stops, starts and the
true continuous performance."""

import numpy as np
import pytest

from engine.synthetic import SequenceSpec, build_body, jump, make_sequence, reach
from engine.synthetic.kinematics import ANKLE_HEIGHT
from engine.synthetic.ramps import Ramp
from engine.synthetic.skeleton import JOINT_INDEX
from engine.synthetic.transitions import performance, stand, walk_transition


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


def test_ramp_distance_is_the_integral_of_its_speed():
    for kind in ("stop", "start"):
        ramp = Ramp(kind, 0.5, 1.7)
        t = np.linspace(0, 3, 30001)
        integral = np.concatenate([[0], np.cumsum(0.5 * (ramp.amount(t[1:]) + ramp.amount(t[:-1])) * np.diff(t))])
        assert np.abs(ramp.distance(t, 1.0) - integral).max() < 1e-6
    assert Ramp("stop", 0, 1).distance(np.array([5.0]), 2.0)[0] == pytest.approx(1.0)  # v * span / 2
    with pytest.raises(ValueError, match="after its start"):
        Ramp("stop", 1.0, 1.0)


def test_still_stand_is_exactly_the_pose_jumps_start_in(body):
    still = stand(body.skeleton, breath=0.0, fps=15)
    leap = jump(body.skeleton, 0.3, 0.5, fps=15)
    assert np.array_equal(still.positions[0], leap.positions[0])
    assert np.array_equal(still.rotations[0], leap.rotations[0])
    # a reach starts with the pelvis tilted a little more and the palm placed (within 2 cm)
    assert np.abs(still.positions[0] - reach(body.skeleton, 1.2, fps=15).positions[0]).max() < 0.02


def test_stand_loops_exactly(body):
    idle = stand(body.skeleton, period=1.2, breath=0.01, sway=0.02, cycles=2.0, fps=15)
    N = idle.frames_per_cycle
    assert idle.cyclic and len(idle.times) == 2 * N
    assert np.abs(idle.positions[N:] - idle.positions[:N]).max() < 1e-12
    assert np.ptp(idle.positions[:, JOINT_INDEX["pelvis"], 1]) == pytest.approx(0.01 * body.skeleton.scale, rel=1e-3)


@pytest.mark.parametrize("kind", ["stop", "start"])
def test_walks_stop_to_and_start_from_the_stand_with_planted_feet(body, kind):
    motion = walk_transition(body.skeleton, 1.2, kind, walk=0.8, fps=30)
    still = stand(body.skeleton, breath=0.0, fps=30).positions[0]
    standing = -1 if kind == "stop" else 0
    offset = np.array([0.0, 0.0, motion.root_position[standing, 2]])
    assert np.abs(motion.positions[standing] - offset - still).max() < 1e-4
    speed = np.linalg.norm(np.diff(motion.root_position, axis=0), axis=1) * 30
    assert speed.max() == pytest.approx(1.2, rel=1e-3) and speed[standing] < 1e-9
    for side in ("l", "r"):  # a flat foot on the ground does not move
        ankle = motion.positions[:, JOINT_INDEX[f"ankle_{side}"]]
        flat = np.abs(ankle[:, 1] - ANKLE_HEIGHT * body.skeleton.scale) < 1e-9
        steps = np.linalg.norm(np.diff(ankle, axis=0), axis=1)[flat[1:] & flat[:-1]]
        # (the first / last steps are only millimetres long, and their foot barely lifts)
        assert len(steps) > 10 and steps.max() < 2e-3


def test_performance_is_continuous_across_its_pieces(body):
    motion = performance(body.skeleton, 1.0, 0.3, 0.6, walk=0.6, fps=15)
    events = motion.events
    assert 0 < events["stop_frame"] < events["jump_frame"] < events["take_off_frame"] < events["landing_frame"] \
        < events["start_piece_frame"] < events["start_frame"] < len(motion.times)
    step = np.linalg.norm(np.diff(motion.positions, axis=0), axis=2).max(axis=1)
    for seam in (events["jump_frame"], events["start_piece_frame"]):
        assert step[seam - 2:seam + 2].max() < 1e-4  # standing still on both sides of a seam
    assert motion.root_position[-1, 2] > motion.root_position[events["start_frame"], 2] + 0.3


def test_make_sequence_kinds(body):
    _, V, measured = make_sequence(body, SequenceSpec("idle", "stand", {"breath": 0.008, "sway": 0.02}), fps=15)
    assert measured["com_bob"] > 0.002 and measured["com_sway"] > 0.01
    motion, V, measured = make_sequence(body, SequenceSpec("stop", "gait_stop", {"speed": 1.0, "walk": 0.6}), fps=15)
    assert motion.kind == "gait_stop" and not motion.cyclic
    assert measured["speed"] == pytest.approx(1.0, abs=0.1)
    with pytest.raises(ValueError, match="walking speed"):
        make_sequence(body, SequenceSpec("stop", "gait_stop", {"speed": 3.0}), fps=15)
