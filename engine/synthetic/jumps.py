"""Countermovement jumps to a requested rise and distance (``jump``)."""

from __future__ import annotations

import numpy as np

from engine.rotations import rot_x, rot_y
from engine.synthetic.kinematics import (
    PoseTargets,
    foot_pose,
    hermite,
    keyframes,
    minimum_jerk,
    pose_joints,
    smoothstep,
)
from engine.synthetic.motion_base import (
    GRAVITY,
    STAND_PELVIS,
    Motion,
    _relaxed_arms,
    _standing_feet,
    _torso,
    sample_one_shot,
)


def _jump_pose(skeleton, t, height_rise, distance, palm_offset):
    """Countermovement jump: crouch, push-off, ballistic flight, landing, recovery."""
    s = skeleton.scale
    D = distance
    stand = STAND_PELVIS * s
    crouch = (0.10 + 0.12 * height_rise / 0.5 + 0.03 * D) * s
    t_crouch0, t_crouch1 = 0.3, 0.8
    t_to = t_crouch1 + 0.25
    y_to = stand + 0.035 * s
    z_to, z_land = 0.12 * D, 0.88 * D
    vy = np.sqrt(2 * GRAVITY * max(height_rise, 1e-4))
    flight = 2 * vy / GRAVITY
    t_land = t_to + flight
    vz = (z_land - z_to) / flight
    t_absorb, t_stand = t_land + 0.25, t_land + 0.8

    pelvis = np.zeros((len(t), 3))
    zero = np.zeros(3)
    segs = [
        (0.0, t_crouch0, [0, stand, 0], [0, stand, 0], zero, zero),
        (t_crouch0, t_crouch1, [0, stand, 0], [0, stand - crouch, -0.04 * s], zero, zero),
        (t_crouch1, t_to, [0, stand - crouch, -0.04 * s], [0, y_to, z_to], zero, [0, vy, vz]),
        (t_land, t_absorb, [0, y_to, z_land], [0, stand - 0.7 * crouch, D - 0.02 * s], [0, -vy, vz], zero),
        (t_absorb, t_stand, [0, stand - 0.7 * crouch, D - 0.02 * s], [0, stand, D], zero, zero),
    ]
    for a, b, p0, p1, v0, v1 in segs:
        m = (t >= a) & (t < b)
        if np.any(m):
            pelvis[m] = hermite(a, b, np.array(p0, float), np.array(p1, float), np.asarray(v0, float),
                                np.asarray(v1, float), t[m])
    m = (t >= t_to) & (t < t_land)
    tf = t[m] - t_to
    pelvis[m] = np.stack([np.zeros_like(tf), y_to + vy * tf - 0.5 * GRAVITY * tf**2, z_to + vz * tf], 1)
    pelvis[t >= t_stand] = [0, stand, D]

    # Feet: flat at z=0, rolling onto the balls for push-off; tucked in flight; landing on the
    # balls then flat at z=D.
    toe = np.radians(35.0)
    pitch = np.zeros_like(t)
    on_ground_before = t < t_to
    pitch[on_ground_before] = -toe * smoothstep(t_to - 0.15, t_to, t[on_ground_before])
    after = t >= t_land
    pitch[after] = -np.radians(20.0) * (1 - smoothstep(t_land, t_land + 0.12, t[after]))
    feet_before = _standing_feet(t, np.zeros_like(t), s)
    feet_after = _standing_feet(t, np.full_like(t, D), s)
    yaw = np.zeros_like(t)
    ankle, foot_rot = {}, {}
    for side in ("l", "r"):
        a_before, r_before = foot_pose(feet_before[side], yaw, np.where(on_ground_before, pitch, -toe), s)
        a_after, r_after = foot_pose(feet_after[side], yaw, np.where(after, pitch, -np.radians(20.0)), s)
        # In flight the ankles move with the pelvis from their take-off to landing offsets,
        # tucked up towards the body.
        i_to = np.array([t_to])
        i_land = np.array([t_land])
        a_to, _ = foot_pose(_standing_feet(i_to, np.zeros(1), s)[side], np.zeros(1), np.array([-toe]), s)
        a_ld, _ = foot_pose(_standing_feet(i_land, np.full(1, D), s)[side], np.zeros(1),
                            np.array([-np.radians(20.0)]), s)
        r_to = a_to[0] - np.array([0, y_to, z_to])
        r_ld = a_ld[0] - np.array([0, y_to, z_land])
        u = np.clip((t - t_to) / flight, 0, 1)
        tuck = (0.08 + 0.35 * height_rise) * s * np.sin(np.pi * u)
        rel = r_to + (r_ld - r_to) * minimum_jerk(u)[:, None]
        rel[:, 1] += tuck
        rel[:, 2] -= 0.3 * tuck
        a_flight = pelvis + rel
        flight_pitch = -toe + (toe - np.radians(20.0)) * minimum_jerk(u)
        ankle[side] = np.where(on_ground_before[:, None], a_before, np.where(after[:, None], a_after, a_flight))
        foot_rot[side] = np.where(on_ground_before[:, None, None], r_before,
                                  np.where(after[:, None, None], r_after, rot_x(flight_pitch)))

    # Torso lean and arm swing keyed on the phases (degrees).
    key_t = [0.0, t_crouch0, t_crouch1, t_to, t_to + 0.4 * flight, t_land, t_absorb, t_stand]
    lean = np.radians(keyframes(key_t, [3, 3, 35, -2, 8, 15, 28, 3], t))
    swing = np.radians(keyframes(key_t, [0, 0, -55, 150 if height_rise > 0.35 else 110, 70, 40, 25, 0], t))
    Rh = rot_y(np.zeros_like(t))
    pelvis_rot = Rh @ rot_x(0.45 * lean)
    spine, chest, neck, head = _torso(lean, np.zeros_like(t), 1.3 * lean)
    chest_rot = pelvis_rot @ spine @ chest
    arm_dir, elbow = _relaxed_arms(chest_rot, t, swing)
    targets = PoseTargets(
        pelvis_position=pelvis, pelvis_rotation=pelvis_rot, spine=spine, chest=chest, neck=neck, head=head,
        arm_dir=arm_dir, elbow_flex=elbow, palm_target={}, arm_pole={}, ankle=ankle, foot_rotation=foot_rot,
        knee_pole=np.tile([0.0, 0.0, 1.0], (len(t), 1)))
    R, P = pose_joints(skeleton, targets, palm_offset)
    root = np.stack([pelvis[:, 0], np.zeros_like(t), pelvis[:, 2]], 1)
    events = {"take_off_time": t_to, "landing_time": t_land, "apex_time": t_to + flight / 2,
              "end_time": t_stand + 0.3}
    return R, P, root, np.zeros_like(t), events


def jump(skeleton, rise, distance, *, fps=30.0, name=None, palm_offset=0.07):
    """Countermovement jump with a given flight rise and horizontal distance.

    Parameters
    ----------
    rise : float       apex of the pelvis above its take-off height in metres (0.05 .. 0.8);
                       ``jump_to`` calibrates it to a requested centre-of-mass jump height
    distance : float   forward distance between standing positions before and after (0 .. 2 m)

    Returns
    -------
    Motion   non-cyclic, standing still at both ends
    """
    if not 0.02 <= rise <= 0.9:
        raise ValueError(f"jump rise must be between 0.02 and 0.9 m, got {rise}")
    if not 0.0 <= distance <= 2.0:
        raise ValueError(f"jump distance must be between 0 and 2 m, got {distance}")
    times, pose_at, R, P, root, heading, events = sample_one_shot(
        lambda t: _jump_pose(skeleton, t, rise, distance, palm_offset), fps)
    frame_events = {k.replace("_time", "_frame"): int(round(v * fps)) for k, v in events.items()
                    if k != "end_time"}
    frame_events["take_off_frame"] = int(np.ceil(events["take_off_time"] * fps))
    frame_events["landing_frame"] = int(np.ceil(events["landing_time"] * fps))
    return Motion(name=name or "jump", kind="jump", fps=float(fps), times=times, rotations=R, positions=P,
                  root_position=root, heading=heading, cyclic=False, frames_per_cycle=None,
                  params={"rise": float(rise), "distance": float(distance)}, events=frame_events,
                  pose_at=pose_at)
