"""Gaits: walk, jog and run at a requested speed, straight or turning (``gait``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.rotations import rot_x, rot_y, rot_z
from engine.synthetic.kinematics import (
    ANKLE_HEIGHT,
    PoseTargets,
    foot_pose,
    minimum_jerk,
    pose_joints,
    smoothstep,
    softmin,
)
from engine.synthetic.motion_base import GRAVITY, STANCE_WIDTH, STAND_PELVIS, Motion, _arm_direction, _torso


@dataclass(frozen=True)
class GaitParameters:
    """Gait shape as a function of speed (reference body of 1.75 m)."""

    speed: float
    turn_rate: float  # rad/s, positive = left
    period: float  # seconds per cycle (two steps)
    duty: float  # fraction of the cycle a foot is on the ground
    runness: float  # 0 walk .. 1 run
    ramp: object = None  # ramps.Ramp: starting from / stopping to a standing pose (straight gaits)

    @classmethod
    def for_speed(cls, speed, turn_rate, fps, ramp=None):
        runness = float(smoothstep(1.6, 2.6, speed))
        step_frequency = 1.45 + 0.35 * speed  # steps per second, grows with speed
        frames = max(8, int(round(2.0 / step_frequency * fps)))  # whole frames per cycle
        duty = 0.60 - 0.27 * runness
        return cls(speed=float(speed), turn_rate=float(turn_rate), period=frames / fps, duty=duty,
                   runness=runness, ramp=ramp)

    def amount(self, t):
        """(frames,) how much of the gait is on at times t: 1 without a ramp, 0 standing still."""
        return np.ones_like(t) if self.ramp is None else self.ramp.amount(t)

    @property
    def stride(self):
        return self.speed * self.period


def _path(gait, t):
    """Root path: constant speed along a straight line or a circle of radius v / omega."""
    v, w = gait.speed, gait.turn_rate
    heading = w * t
    if gait.ramp is not None:
        distance = gait.ramp.distance(t, v)
        return np.stack([np.zeros_like(t), np.zeros_like(t), distance], axis=1), np.zeros_like(t)
    if abs(w) < 1e-9:
        pos = np.stack([np.zeros_like(t), np.zeros_like(t), v * t], axis=1)
    else:
        pos = np.stack([(v / w) * (1 - np.cos(w * t)), np.zeros_like(t), (v / w) * np.sin(w * t)], axis=1)
    return pos, heading


def _roll_centre(heel_strike, toe_off, scale):
    """(frames,) forward offset that centres the ankle's progression over a stance rolled from
    ``heel_strike`` to ``toe_off`` (radians, arrays) on the mid-stance root position."""
    f = len(heel_strike)
    rolled, _ = foot_pose(np.zeros((2 * f, 3)), np.zeros(2 * f), np.concatenate([heel_strike, -toe_off]), scale)
    return -0.5 * (rolled[:f, 2] + rolled[f:, 2])


def _gait_feet(gait, t, side_sign, offset, scale):
    """Ankle target and foot rotation of one foot over time (planted during stance).

    With a ramp, every step's heel strike, toe-off and lift scale with its length relative to a
    full stride, so a foot whose next step has no length stays flat where it is."""
    T, beta = gait.period, gait.duty
    r = gait.runness
    phase = t / T - offset
    k = np.floor(phase)
    local = phase - k
    stance = local < beta
    heel_full = np.radians(16.0 - 10.0 * r)
    toe_full = np.radians(34.0 + 24.0 * r)

    def step_length(index):
        """(frames,) length of the step landing at footfall ``index``, as a fraction of a stride."""
        if gait.ramp is None:
            return np.ones_like(index)
        here = gait.ramp.distance((index + offset + beta / 2) * T, gait.speed)
        before = gait.ramp.distance((index - 1 + offset + beta / 2) * T, gait.speed)
        return np.clip((here - before) / gait.stride, 0.0, 1.0)

    def rolls(index):
        """Heel strike landing at ``index`` and toe-off leaving it (radians, (frames,))."""
        return heel_full * step_length(index), toe_full * step_length(index + 1)

    def footfall(index):
        t_mid = (index + offset + beta / 2) * T
        pos, heading = _path(gait, t_mid)
        lateral = STANCE_WIDTH * (1.0 - 0.3 * r) * side_sign * scale
        heel, toe = rolls(index)
        # Rolling over the heel and ball moves the ankle forward during stance; centre that
        # progression on the mid-stance root position.
        forward = _roll_centre(heel, toe, scale)
        flat = pos + np.einsum("fab,fb->fa", rot_y(heading),
                               np.stack([np.full_like(forward, lateral), np.zeros_like(forward), forward], 1))
        flat[:, 1] = ANKLE_HEIGHT * scale
        return flat, heading

    def stance_pitch(sigma, heel, toe):
        return heel * (1 - smoothstep(0.0, 0.2, sigma)) - toe * smoothstep(0.55, 1.0, sigma)

    heel_now, toe_now = rolls(k)
    heel_next, toe_next = rolls(k + 1)
    flat_now, yaw_now = footfall(k)
    flat_next, yaw_next = footfall(k + 1)
    ones = np.ones_like(t)
    sigma = np.clip(local / beta, 0.0, 1.0)
    ankle_stance, rot_stance = foot_pose(flat_now, yaw_now, stance_pitch(sigma, heel_now, toe_now), scale)
    # Swing from this footfall's toe-off to the next footfall's heel strike.
    a0, _ = foot_pose(flat_now, yaw_now, stance_pitch(ones, heel_now, toe_now), scale)
    a1, _ = foot_pose(flat_next, yaw_next, stance_pitch(0 * ones, heel_next, toe_next), scale)
    u = np.clip((local - beta) / (1 - beta), 0.0, 1.0)
    m = minimum_jerk(u)[:, None]
    lift = (0.07 + 0.02 * gait.speed + 0.16 * r) * scale * step_length(k + 1)
    bump = np.sin(np.pi * u ** (0.8 - 0.25 * r)) ** 2
    ankle_swing = a0 + (a1 - a0) * m
    ankle_swing[:, 1] += lift * bump
    yaw_swing = yaw_now + (yaw_next - yaw_now) * m[:, 0]
    pitch_swing = (-toe_now + (heel_next + toe_now) * minimum_jerk(u)
                   - np.radians(10 * r) * bump * step_length(k + 1))
    rot_swing = rot_y(yaw_swing) @ rot_x(-pitch_swing)
    ankle = np.where(stance[:, None], ankle_stance, ankle_swing)
    rotation = np.where(stance[:, None, None], rot_stance, rot_swing)
    return ankle, rotation, stance


def _gait_pose(skeleton, gait, t, palm_offset):
    s = skeleton.scale
    T, beta, r, v = gait.period, gait.duty, gait.runness, gait.speed
    phase = t / T
    root, heading = _path(gait, t)
    Rh = rot_y(heading)
    amount = gait.amount(t)

    def mix(standing, moving):
        """The gait's value, eased towards the standing pose's (``stand``) by a ramp."""
        return moving if gait.ramp is None else standing + (moving - standing) * amount

    ankle_l, foot_l, stance_l = _gait_feet(gait, t, +1.0, 0.0, s)
    ankle_r, foot_r, stance_r = _gait_feet(gait, t, -1.0, 0.5, s)

    # Pelvis: bounce (highest at mid-stance when walking, lowest when running), sway over the
    # stance foot, and a height limit so both legs can reach their ankles.
    bounce = (0.018 * (1 - r) - 0.03 * r) * np.cos(4 * np.pi * (phase - beta / 2))
    design = (STAND_PELVIS - 0.012 * v + bounce) * s
    sway = mix(0.0, (0.022 * (1 - r) + 0.008 * r) * np.cos(2 * np.pi * (phase - beta / 2)) * s)
    limits = []
    for ankle, sign in ((ankle_l, 1.0), (ankle_r, -1.0)):
        hip = root + np.einsum("fab,b->fa", Rh, np.array([0.10 * sign * s, 0, 0]))
        horizontal = np.linalg.norm((ankle - hip)[:, [0, 2]], axis=1)
        reach = 0.995 * skeleton.leg_length
        limits.append(ankle[:, 1] + np.sqrt(np.maximum(reach**2 - horizontal**2, 0.0)) + 0.05 * s)
    height = mix(STAND_PELVIS * s, softmin(np.stack([design] + limits), 0.012 * s))
    pelvis_pos = root + np.einsum("fab,fb->fa", Rh, np.stack([sway, np.zeros_like(t), np.zeros_like(t)], 1))
    pelvis_pos[:, 1] = height

    lean = mix(np.radians(3.0), np.radians(3.0 + 2.5 * v))
    turn_roll = -0.6 * np.arctan(v * gait.turn_rate / GRAVITY) * np.ones_like(t)
    pelvis_yaw = mix(0.0, -np.radians(3.0 + 2.0 * v) * np.cos(2 * np.pi * phase))
    pelvis_roll = mix(0.0, np.radians(2.0 * (1 - r)) * np.cos(2 * np.pi * (phase - beta / 2)))
    tilt = mix(0.45 * np.radians(3.0), np.radians(2.0 + 1.5 * v) * np.ones_like(t))
    pelvis_rot = Rh @ rot_z(turn_roll + pelvis_roll) @ rot_y(pelvis_yaw) @ rot_x(tilt)
    counter = -2.2 * pelvis_yaw
    lean_t = lean * np.ones_like(t) + mix(0.0, np.radians(2.0) * r * np.cos(4 * np.pi * phase))
    spine, chest, neck, head = _torso(lean_t, counter, mix(1.3 * np.radians(3.0), lean_t + tilt))

    # Arms: swing opposite the same-side leg, more and with more elbow flexion at speed.
    chest_rot = pelvis_rot @ spine @ chest
    swing_amp = np.radians(12.0 + 9.0 * v)
    arm_dir, elbow = {}, {}
    for side, sign in (("l", 1.0), ("r", -1.0)):
        swing = mix(0.0, -sign * swing_amp * np.cos(2 * np.pi * phase) + np.radians(4.0 * r))
        arm_dir[side] = _arm_direction(chest_rot, swing, mix(np.radians(8.0), np.radians(9.0 + 3 * r)), sign)
        if gait.ramp is None:
            elbow[side] = np.radians(15.0 + 14.0 * v) + 0.5 * np.maximum(swing, 0) * (0.5 + r)
        else:
            elbow[side] = (mix(np.radians(12.0), np.radians(15.0 + 14.0 * v))
                           + mix(0.3, 0.5 * (0.5 + r)) * np.maximum(swing, 0))

    knee_pole = np.einsum("fab,b->fa", Rh, np.array([0.0, 0.0, 1.0]))
    targets = PoseTargets(
        pelvis_position=pelvis_pos, pelvis_rotation=pelvis_rot, spine=spine, chest=chest, neck=neck,
        head=head, arm_dir=arm_dir, elbow_flex=elbow, palm_target={}, arm_pole={},
        ankle={"l": ankle_l, "r": ankle_r}, foot_rotation={"l": foot_l, "r": foot_r}, knee_pole=knee_pole)
    R, P = pose_joints(skeleton, targets, palm_offset)
    return R, P, root, heading, (stance_l, stance_r)


def gait(skeleton, speed, *, turn_rate=0.0, fps=30.0, cycles=2.0, start_phase=0.0, name=None,
         palm_offset=0.07):
    """Walk, jog or run at ``speed`` m/s, straight or turning at ``turn_rate`` deg/s.

    Parameters
    ----------
    skeleton : Skeleton
    speed : float          mean root speed, 0.5 to 6 m/s; walking below ~1.6, running above ~2.6
    turn_rate : float      degrees per second about +Y, positive turns left; |rate| <= 120
    fps : float            frames per second
    cycles : float         clip length in gait cycles (two steps each)
    start_phase : float    phase of the first frame in [0, 1): 0 is the left heel strike

    Returns
    -------
    Motion   cyclic, with a whole number of frames per cycle

    Notes
    -----
    Cadence grows with speed (1.45 + 0.35 v steps/s) and is rounded so a cycle spans a whole
    number of frames; the stride then follows from speed x period, so the mean speed is exact.
    Stance feet are planted (no sliding); legs are posed by two-bone IK; duty factor drops from
    0.60 (walk) to 0.33 (run, with a flight phase).
    """
    if not 0.5 <= speed <= 6.0:
        raise ValueError(f"speed must be between 0.5 and 6 m/s, got {speed}")
    if abs(turn_rate) > 120.0:
        raise ValueError(f"turn_rate must be within +-120 deg/s, got {turn_rate}")
    if fps <= 0 or cycles <= 0:
        raise ValueError("fps and cycles must be positive")
    g = GaitParameters.for_speed(speed, np.radians(turn_rate), fps)
    N = int(round(g.period * fps))
    frames = max(2, int(round(cycles * N)))
    t0 = start_phase * g.period
    times = t0 + np.arange(frames) / fps

    def pose_at(t):
        R, P, root, heading, _ = _gait_pose(skeleton, g, np.asarray(t, dtype=float), palm_offset)
        return R, P, root, heading

    R, P, root, heading, (stance_l, stance_r) = _gait_pose(skeleton, g, times, palm_offset)
    strikes_l = np.flatnonzero(stance_l[1:] & ~stance_l[:-1]) + 1
    strikes_r = np.flatnonzero(stance_r[1:] & ~stance_r[:-1]) + 1
    kind_name = "walk" if g.runness < 0.5 else "run"
    return Motion(
        name=name or kind_name, kind="gait", fps=float(fps), times=times, rotations=R, positions=P,
        root_position=root, heading=heading, cyclic=True, frames_per_cycle=N,
        params={"speed": float(speed), "turn_rate": float(turn_rate), "period": g.period,
                "duty_factor": g.duty, "stride_length": g.stride, "gait": kind_name},
        events={"left_heel_strikes": strikes_l.tolist(), "right_heel_strikes": strikes_r.tolist()},
        pose_at=pose_at)
