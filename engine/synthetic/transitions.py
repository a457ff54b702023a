"""Motions that connect the others, for motion graphs: standing idles, walks that stop to a
stand and start from one, and a continuous performance (walk, stop, jump, start, walk).

All of them stand in exactly the pose a jump and a reach start and end in (``_stand_pose`` with
no breathing is the jump's first frame), so the pieces of ``performance`` join without a seam and
the standing idle is the pose the graph's one-shots leave from and return to.
"""

from __future__ import annotations

import numpy as np

from engine.rotations import rot_x
from engine.synthetic.kinematics import PoseTargets, foot_pose, pose_joints
from engine.synthetic.gaits import GaitParameters, _gait_pose
from engine.synthetic.jumps import jump
from engine.synthetic.motion_base import STAND_PELVIS, Motion, _relaxed_arms, _standing_feet, _torso
from engine.synthetic.ramps import Ramp


def _stand_pose(skeleton, t, period, breath, sway, palm_offset):
    """Standing at the origin facing +Z; breathing lifts the pelvis by ``breath`` metres and
    sways it sideways by ``sway`` metres once per ``period`` seconds (0, 0: the jump's start)."""
    s = skeleton.scale
    cycle = 2 * np.pi * t / period
    lean = np.radians(3.0) + np.radians(1.5) * (breath / 0.01) * np.sin(cycle)
    pelvis = np.stack([sway * s * np.sin(cycle), STAND_PELVIS * s - breath * s * (0.5 - 0.5 * np.cos(cycle)),
                       np.zeros_like(t)], 1)
    pelvis_rot = rot_x(0.45 * lean)
    spine, chest, neck, head = _torso(lean, np.zeros_like(t), 1.3 * lean)
    chest_rot = pelvis_rot @ spine @ chest
    arm_dir, elbow = _relaxed_arms(chest_rot, t)
    feet = _standing_feet(t, np.zeros_like(t), s)
    ankle, foot_rot = {}, {}
    for side in ("l", "r"):
        ankle[side], foot_rot[side] = foot_pose(feet[side], np.zeros_like(t), np.zeros_like(t), s)
    targets = PoseTargets(
        pelvis_position=pelvis, pelvis_rotation=pelvis_rot, spine=spine, chest=chest, neck=neck, head=head,
        arm_dir=arm_dir, elbow_flex=elbow, palm_target={}, arm_pole={}, ankle=ankle, foot_rotation=foot_rot,
        knee_pole=np.tile([0.0, 0.0, 1.0], (len(t), 1)))
    R, P = pose_joints(skeleton, targets, palm_offset)
    root = np.zeros((len(t), 3))
    return R, P, root, np.zeros_like(t)


def stand(skeleton, *, period=2.0, breath=0.008, sway=0.0, cycles=1.0, fps=30.0, name=None, palm_offset=0.07):
    """A standing idle: breathing (the pelvis dips by ``breath`` m) and an optional sideways
    weight shift of ``sway`` m, once per ``period`` seconds.

    Returns
    -------
    Motion   cyclic (kind "stand"), in place
    """
    if not 0.5 <= period <= 10.0:
        raise ValueError(f"stand period must be between 0.5 and 10 s, got {period}")
    if not (0.0 <= breath <= 0.05 and 0.0 <= sway <= 0.1):
        raise ValueError(f"stand breath must be within 0..0.05 m and sway within 0..0.1 m, got {breath}, {sway}")
    N = max(4, int(round(period * fps)))
    exact = N / fps  # a whole number of frames per cycle
    frames = max(2, int(round(cycles * N)))
    times = np.arange(frames) / fps

    def pose_at(t):
        return _stand_pose(skeleton, np.asarray(t, dtype=float), exact, breath, sway, palm_offset)

    R, P, root, heading = pose_at(times)
    return Motion(name=name or "stand", kind="stand", fps=float(fps), times=times, rotations=R, positions=P,
                  root_position=root, heading=heading, cyclic=True, frames_per_cycle=N,
                  params={"period": exact, "breath": float(breath), "sway": float(sway)}, events={},
                  pose_at=pose_at)


def walk_transition(skeleton, speed, kind, *, walk=1.0, ramp=1.2, hold=0.4, fps=30.0, name=None, palm_offset=0.07):
    """A straight walk that slows to a stand (``kind`` "stop") or sets off from one ("start").

    Parameters
    ----------
    speed : float   walking speed before the stop / after the start, 0.5 .. 1.6 m/s
    walk : float    seconds of full-speed walking before the stop / after the start
    ramp : float    seconds over which the speed eases (cubic) between full and zero
    hold : float    seconds standing still after the stop / before the start (beyond the gait
                    period the feet need to finish or begin stepping)

    Returns
    -------
    Motion   non-cyclic, kind "gait_stop" or "gait_start"; events give the ramp's frames

    Notes
    -----
    The root travels the exact integral of the eased speed; every step's length, foot roll and
    lift follow it, so the feet stay planted and the last (first) steps have no length. Standing,
    the pose is the jump's and the idle's (``_stand_pose``).
    """
    if kind not in ("stop", "start"):
        raise ValueError(f"walk transition kind must be 'stop' or 'start', got {kind!r}")
    if not 0.5 <= speed <= 1.6:
        raise ValueError(f"a walk that stops or starts needs a walking speed of 0.5..1.6 m/s, got {speed}")
    if walk < 0 or ramp <= 0 or hold < 0:
        raise ValueError("walk and hold must be >= 0 and ramp > 0 seconds")
    # A foot's last step lands up to a gait period after the speed reaches zero (and the first
    # one lifts up to a period before it leaves zero): stand still ``hold`` seconds beyond that.
    period = GaitParameters.for_speed(speed, 0.0, fps).period
    if kind == "stop":
        r = Ramp("stop", walk, walk + ramp)
    else:
        r = Ramp("start", hold + period, hold + period + ramp)
    g = GaitParameters.for_speed(speed, 0.0, fps, ramp=r)
    frames = int(round((walk + ramp + period + hold) * fps)) + 1
    times = np.arange(frames) / fps

    def pose_at(t):
        R, P, root, heading, _ = _gait_pose(skeleton, g, np.asarray(t, dtype=float), palm_offset)
        return R, P, root, heading

    R, P, root, heading = pose_at(times)
    events = {"ramp_start_frame": int(round(r.start * fps)), "ramp_end_frame": int(round(r.end * fps))}
    return Motion(name=name or f"walk_{kind}", kind=f"gait_{kind}", fps=float(fps), times=times, rotations=R,
                  positions=P, root_position=root, heading=heading, cyclic=False, frames_per_cycle=None,
                  params={"speed": float(speed), "period": g.period, "ramp_s": float(ramp)}, events=events,
                  pose_at=pose_at)


def performance(skeleton, speed, rise, distance, *, walk=1.0, ramp=1.2, hold=0.4, fps=30.0, name=None,
                palm_offset=0.07):
    """The true continuous performance a motion graph imitates: walk, stop, jump, start, walk.

    Parameters
    ----------
    speed : float            walking speed (0.5 .. 1.6 m/s)
    rise, distance : float   the jump's (``motions.jump``)

    Returns
    -------
    Motion   non-cyclic (kind "performance"), straight along +Z; events: ``stop_frame`` (the
             speed starts easing to zero), ``jump_frame`` (the jump piece starts, standing),
             ``take_off_frame``, ``landing_frame``, ``start_piece_frame`` (the start piece
             begins, standing) and ``start_frame`` (the speed starts rising)
    """
    stop = walk_transition(skeleton, speed, "stop", walk=walk, ramp=ramp, hold=hold, fps=fps, palm_offset=palm_offset)
    leap = jump(skeleton, rise, distance, fps=fps, palm_offset=palm_offset)
    start = walk_transition(skeleton, speed, "start", walk=walk, ramp=ramp, hold=hold, fps=fps,
                            palm_offset=palm_offset)
    pieces = []  # (motion, first global time, forward offset)
    t0, z0 = 0.0, 0.0
    for motion in (stop, leap, start):
        pieces.append((motion, t0, z0))
        t0 += len(motion.times) / fps
        z0 += float(motion.root_position[-1, 2])
    total = t0

    def pose_at(t):
        t = np.asarray(t, dtype=float)
        index = np.clip(np.searchsorted([p[1] for p in pieces], t, side="right") - 1, 0, len(pieces) - 1)
        R = np.empty((len(t),) + stop.rotations.shape[1:])
        P = np.empty((len(t),) + stop.positions.shape[1:])
        root = np.zeros((len(t), 3))
        for k, (motion, start_time, z) in enumerate(pieces):
            chosen = index == k
            if np.any(chosen):
                Rk, Pk, rootk, _ = motion.pose_at(t[chosen] - start_time)
                R[chosen], P[chosen] = Rk, Pk + np.array([0.0, 0.0, z])
                root[chosen] = rootk + np.array([0.0, 0.0, z])
        return R, P, root, np.zeros_like(t)

    times = np.arange(int(round(total * fps))) / fps
    R, P, root, heading = pose_at(times)
    jump_frame = len(stop.times)
    events = {"stop_frame": stop.events["ramp_start_frame"], "jump_frame": jump_frame,
              "take_off_frame": jump_frame + leap.events["take_off_frame"],
              "landing_frame": jump_frame + leap.events["landing_frame"],
              "start_piece_frame": jump_frame + len(leap.times),
              "start_frame": jump_frame + len(leap.times) + start.events["ramp_start_frame"]}
    return Motion(name=name or "performance", kind="performance", fps=float(fps), times=times, rotations=R,
                  positions=P, root_position=root, heading=heading, cyclic=False, frames_per_cycle=None,
                  params={"speed": float(speed), "rise": float(rise), "distance": float(distance)}, events=events,
                  pose_at=pose_at)
