"""The synthetic capture generator: body, motions, dynamics, unstructured re-meshing."""

import numpy as np
import pytest
import trimesh

from engine import measures
from engine.rotations import rot_y
from engine.surface import SurfaceQuery, enclosed_volume
from engine.synthetic import SequenceSpec, animate, build_body, gait, generate_sequence_data, make_sequence
from engine.synthetic.capture import unstructured_capture
from engine.synthetic.dynamics import GARMENT, SOFT_TISSUE, secondary_motion
from engine.synthetic.kinematics import ANKLE_HEIGHT
from engine.synthetic.skeleton import JOINT_INDEX
from engine.synthetic.skinning import skin_dual_quaternion


@pytest.fixture(scope="module")
def body():
    return build_body(1500)


def _root_local(V, motion, k):
    """Frame k expressed in its root frame (root translation and heading removed)."""
    return (V[k] - motion.root_position[k]) @ rot_y(motion.heading[k])


@pytest.mark.parametrize("n", [1000, 3000])
def test_body_is_a_watertight_closed_surface_of_the_requested_size(n):
    body = build_body(n)
    mesh = trimesh.Trimesh(body.V, body.F, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.euler_number == 2  # one closed genus-0 surface
    assert enclosed_volume(body.V, body.F) > 0.04  # outward oriented, a human's volume (m^3)
    assert abs(len(body.V) - n) <= 0.02 * n
    assert 1.73 < body.V[:, 1].max() <= 1.76 and abs(body.V[:, 1].min()) < 0.005  # feet on the ground
    assert body.V[:, 2].max() > 0.15  # facing +Z: toes and nose point forwards
    np.testing.assert_allclose(body.weight.sum(axis=1), 1.0, atol=1e-12)


def test_body_resolution_is_validated():
    with pytest.raises(ValueError, match="between 1000 and 50000"):
        build_body(500)
    with pytest.raises(ValueError, match="between 1000 and 50000"):
        build_body(60_000)


def test_rest_pose_skinning_is_the_identity(body):
    sk = body.skeleton
    J = len(sk.names)
    R = np.tile(np.eye(3), (1, J, 1, 1))
    V = skin_dual_quaternion(body.V, sk.rest, R, sk.rest[None], body.weight_index, body.weight)
    np.testing.assert_allclose(V[0], body.V, atol=1e-12)


@pytest.mark.parametrize("turn_rate", [0.0, 40.0, -60.0])
def test_cyclic_gait_loops_exactly(body, turn_rate):
    motion = gait(body.skeleton, 1.3, turn_rate=turn_rate, cycles=2.0, start_phase=0.37)
    V = animate(body, motion)
    N = motion.frames_per_cycle
    assert len(V) == 2 * N
    worst = max(np.abs(_root_local(V, motion, k + N) - _root_local(V, motion, k)).max() for k in range(N))
    assert worst < 1e-6 * body.size
    # ... and the cycle is not trivially constant: the body really moves within it.
    assert np.abs(_root_local(V, motion, N // 2) - _root_local(V, motion, 0)).max() > 0.1


@pytest.mark.parametrize("speed", [0.8, 1.5, 3.0, 4.5])
def test_measured_walk_speed_matches_request(body, speed):
    motion, V, measured = make_sequence(body, SequenceSpec("g", "gait", {"speed": speed, "cycles": 1.5}))
    assert measured["speed"] == pytest.approx(speed, rel=0.02)
    # The root trajectory agrees: displacement over whole cycles divided by their duration.
    N = motion.frames_per_cycle
    root_speed = np.linalg.norm(motion.root_position[N] - motion.root_position[0]) / (N / motion.fps)
    assert root_speed == pytest.approx(speed, rel=0.02)


def test_gait_cadence_and_stride_grow_with_speed(body):
    slow, fast = gait(body.skeleton, 1.0, cycles=1), gait(body.skeleton, 3.5, cycles=1)
    assert fast.params["period"] < slow.params["period"]
    assert fast.params["stride_length"] > slow.params["stride_length"]
    assert fast.params["duty_factor"] < 0.5 < slow.params["duty_factor"]  # running has a flight phase


def test_turn_rate_matches_request(body):
    _, _, measured = make_sequence(body, SequenceSpec("t", "gait", {"speed": 1.2, "turn_rate": -45.0}))
    assert measured["turn_rate"] == pytest.approx(-45.0, rel=0.02)
    assert measured["speed"] == pytest.approx(1.2, rel=0.02)


def test_stance_feet_do_not_slide(body):
    motion = gait(body.skeleton, 1.4, cycles=1, start_phase=0.0)
    ankle = motion.positions[:, JOINT_INDEX["ankle_l"]]
    N, duty = motion.frames_per_cycle, motion.params["duty_factor"]
    flat = [k for k in range(N) if 0.25 < k / N / duty < 0.5]  # foot flat: between heel and ball rolls
    assert len(flat) >= 3
    assert np.ptp(ankle[flat], axis=0).max() < 1e-9
    assert ankle[flat, 1] == pytest.approx(ANKLE_HEIGHT * body.skeleton.scale)


@pytest.mark.parametrize("height,distance", [(0.25, 0.0), (0.45, 1.1)])
def test_jump_height_and_distance_match_request(body, height, distance):
    motion, V, measured = make_sequence(body, SequenceSpec("j", "jump", {"height": height, "distance": distance}))
    assert measured["height"] == pytest.approx(height, rel=0.02)
    assert measured["distance"] == pytest.approx(distance, abs=0.02 * max(distance, 0.1))
    # Airborne between take-off and landing: the lowest point of the body leaves the ground.
    to, land = motion.events["take_off_frame"], motion.events["landing_frame"]
    assert V[(to + land) // 2, :, 1].min() > 0.05


@pytest.mark.parametrize("height", [0.7, 1.95])
def test_reach_height_matches_request(body, height):
    _, V, measured = make_sequence(body, SequenceSpec("r", "reach", {"height": height}))
    assert measured["height"] == pytest.approx(height, rel=0.02)
    assert measures.reach_height(V, body.hand_vertices("r")) == pytest.approx(height, rel=0.02)


def test_captures_have_dynamics_beyond_skinning(body):
    motion = gait(body.skeleton, 3.0, cycles=1)
    skinned = skin_dual_quaternion(body.V, body.skeleton.rest, motion.rotations, motion.positions,
                                   body.weight_index, body.weight)
    lag = np.linalg.norm(animate(body, motion) - skinned, axis=2)
    assert 0.003 < lag.max() < 0.05  # millimetres to centimetres, never more than the caps
    belly, feet = body.soft_tissue > 0.5, body.segment == JOINT_INDEX["ankle_l"]
    assert lag[:, belly].max() > 10 * max(lag[:, feet].max(), 1e-9)  # soft parts move, shoes do not


def test_unstructured_frames_have_own_connectivity_and_lie_on_the_true_surface(body):
    motion = gait(body.skeleton, 1.3, cycles=0.25)
    V = animate(body, motion)[:3]
    noise = 0.001
    frames = unstructured_capture(V, body.F, body.colors, seed=3, noise=noise)
    counts = {len(Vu) for Vu, _, _ in frames}
    assert len(counts) == 3 and all(0.8 * len(body.V) <= c <= 1.2 * len(body.V) for c in counts)
    for k, (Vu, Fu, Cu) in enumerate(frames):
        mesh = trimesh.Trimesh(Vu, Fu, process=False)
        assert mesh.is_watertight and enclosed_volume(Vu, Fu) > 0
        distance = SurfaceQuery(V[k], body.F).closest(Vu)[3]
        assert distance.max() < 5 * noise
        assert 0.5 * noise < distance.mean() < 1.1 * noise  # E|N(0, s)| = 0.80 s
        assert Cu.shape == Vu.shape and np.all((Cu >= 0) & (Cu <= 1))


def test_generation_is_reproducible(body):
    spec = SequenceSpec("walk", "gait", {"speed": 1.1, "cycles": 0.5})
    a = generate_sequence_data(body, spec, fps=15, seed=7)
    b = generate_sequence_data(body, spec, fps=15, seed=7)
    np.testing.assert_array_equal(a["vertices"], b["vertices"])
    for (Va, Fa, _), (Vb, Fb, _) in zip(a["unstructured"], b["unstructured"]):
        np.testing.assert_array_equal(Va, Vb)
        np.testing.assert_array_equal(Fa, Fb)
    np.testing.assert_array_equal(a["truth"]["template_positions"], a["vertices"].astype(np.float32))


@pytest.mark.parametrize("kwargs,match", [
    (dict(speed=9.0), "speed"), (dict(speed=1.0, turn_rate=500.0), "turn_rate")])
def test_gait_parameters_are_validated(body, kwargs, match):
    with pytest.raises(ValueError, match=match):
        gait(body.skeleton, **kwargs)


def test_cyclic_dynamics_are_the_steady_state_of_a_simulation_from_rest(body):
    """The periodic solution equals what the springs settle into after a few cycles from rest,
    with no glitch where a cycle wraps (the frame after the last is the first moved onwards)."""
    motion = gait(body.skeleton, 1.3, cycles=5.0, start_phase=0.0)
    skinned = skin_dual_quaternion(body.V, body.skeleton.rest, motion.rotations, motion.positions,
                                   body.weight_index, body.weight)
    dt = 1.0 / motion.fps
    R, P, _, _ = motion.pose_at(np.array([motion.times[0] - dt, motion.times[-1] + dt]))
    before, after = skin_dual_quaternion(body.V, body.skeleton.rest, R, P, body.weight_index, body.weight)
    transient = secondary_motion(skinned, motion.heading, motion.fps,
                                 {SOFT_TISSUE: body.soft_tissue, GARMENT: body.garment},
                                 periodic=False, before=before, after=after)
    periodic = animate(body, motion) - skinned
    last = slice(4 * motion.frames_per_cycle, 5 * motion.frames_per_cycle)
    assert np.abs(transient[last] - periodic[last]).max() < 1e-4
    assert np.abs(transient[last]).max() > 0.005  # and the dynamics are not negligible
