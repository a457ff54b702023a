"""Reaches of one hand to a requested height in front (``reach``)."""

from __future__ import annotations

import numpy as np

from engine.rotations import rot_x
from engine.synthetic.kinematics import (
    PoseTargets,
    foot_pose,
    minimum_jerk,
    pose_joints,
)
from engine.synthetic.motion_base import STAND_PELVIS, Motion, _relaxed_arms, _standing_feet, _torso, sample_one_shot
from engine.synthetic.skeleton import FOREARM, JOINT_INDEX


def _reach_pose(skeleton, t, target_height, palm_offset, side="r"):
    """Reach the palm of one hand to a point at ``target_height`` in front, then return."""
    s = skeleton.scale
    H = target_height / s  # work in reference-body units
    sign = 1.0 if side == "l" else -1.0
    t_go, t_there, t_hold, t_back, t_end = 0.3, 1.1, 1.5, 2.3, 2.6
    u_out = minimum_jerk((t - t_go) / (t_there - t_go))
    u_back = minimum_jerk((t - t_hold) / (t_back - t_hold))
    engage = np.where(t < t_hold, u_out, 1 - u_back)

    # Low targets: bend knees and hips; high targets: rise on the toes and lean back a little.
    low = np.clip((1.05 - H) / 0.55, 0.0, 1.0)
    high = np.clip((H - 1.75) / 0.3, 0.0, 1.0)
    crouch = (0.22 * low) * s * engage
    lean = np.radians(55.0 * low - 4.0 * high + 3.0) * engage + np.radians(3.0) * (1 - engage)
    tiptoe = np.radians(25.0) * high * engage
    pelvis = np.stack([np.zeros_like(t), STAND_PELVIS * s - crouch, -0.08 * low * s * engage], 1)
    pelvis[:, 1] += (0.04 * s) * np.sin(tiptoe) / np.sin(np.radians(25.0)) * (high > 0)
    pelvis_rot = rot_x(0.5 * lean)
    spine, chest, neck, head = _torso(lean, -sign * np.radians(8.0) * engage, 0.6 * lean)
    chest_rot = pelvis_rot @ spine @ chest
    arm_dir, elbow = _relaxed_arms(chest_rot, t)

    feet = _standing_feet(t, np.zeros_like(t), s)
    ankle, foot_rot = {}, {}
    for fs in ("l", "r"):
        ankle[fs], foot_rot[fs] = foot_pose(feet[fs], np.zeros_like(t), -tiptoe, s)

    # The palm travels from where the relaxed arm holds it to the target along a min-jerk path.
    targets = PoseTargets(
        pelvis_position=pelvis, pelvis_rotation=pelvis_rot, spine=spine, chest=chest, neck=neck, head=head,
        arm_dir=arm_dir, elbow_flex=elbow, palm_target={}, arm_pole={}, ankle=ankle, foot_rotation=foot_rot,
        knee_pole=np.tile([0.0, 0.0, 1.0], (len(t), 1)))
    R0, P0 = pose_joints(skeleton, targets, palm_offset)
    e, w = P0[:, JOINT_INDEX[f"elbow_{side}"]], P0[:, JOINT_INDEX[f"wrist_{side}"]]
    relaxed_palm = w + (w - e) / FOREARM / s * palm_offset * s
    forward = 0.42 - 0.22 * high + 0.05 * low
    goal = np.array([sign * 0.17 * s, target_height, forward * s])
    palm = relaxed_palm + (goal - relaxed_palm) * engage[:, None]
    targets.palm_target = {side: palm}
    pole = np.array([sign * 0.5, -0.7, -0.5])
    targets.arm_pole = {side: np.tile(pole / np.linalg.norm(pole), (len(t), 1))}
    targets.arm_dir = {k: v for k, v in arm_dir.items() if k != side}
    R, P = pose_joints(skeleton, targets, palm_offset)
    root = np.zeros((len(t), 3))
    events = {"peak_time": 0.5 * (t_there + t_hold), "end_time": t_end}
    return R, P, root, np.zeros_like(t), events


def reach(skeleton, target_height, *, side="r", fps=30.0, name=None, palm_offset=0.07):
    """Reach one hand to a point at ``target_height`` metres in front of the body and back.

    Parameters
    ----------
    target_height : float   height of the palm's target (0.5 .. 2.1 m for a 1.75 m body)
    side : "l" or "r"

    Returns
    -------
    Motion   non-cyclic
    """
    lo, hi = 0.5 * skeleton.scale, 2.1 * skeleton.scale
    if not lo <= target_height <= hi:
        raise ValueError(f"reach height must be between {lo:.2f} and {hi:.2f} m, got {target_height}")
    if side not in ("l", "r"):
        raise ValueError(f"side must be 'l' or 'r', got {side!r}")
    times, pose_at, R, P, root, heading, events = sample_one_shot(
        lambda t: _reach_pose(skeleton, t, target_height, palm_offset, side), fps)
    return Motion(name=name or "reach", kind="reach", fps=float(fps), times=times, rotations=R, positions=P,
                  root_position=root, heading=heading, cyclic=False, frames_per_cycle=None,
                  params={"target_height": float(target_height), "side": side},
                  events={"peak_frame": int(round(events["peak_time"] * fps))}, pose_at=pose_at)
