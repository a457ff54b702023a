"""Procedural motions with physical parameters: gaits (walk, jog, run, turns), jumps, reaches.

Each generator returns a ``Motion``: joint transforms per frame plus the root trajectory, the
requested parameters and key events. Everything is a function of time, so a cyclic motion is
exactly periodic in its root frame: frame k + N equals frame k moved by one cycle's root motion.

Conventions: Y up, the character starts at the origin facing +Z, its left is +X; headings are
radians about +Y (positive = turning left); angles in user-facing parameters are degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from engine.rotations import rot_x, rot_y, rot_z
from engine.synthetic.kinematics import (
    ANKLE_HEIGHT,
    PoseTargets,
    foot_pose,
    hermite,
    keyframes,
    minimum_jerk,
    pose_joints,
    smoothstep,
    softmin,
)
from engine.synthetic.skeleton import FOREARM, JOINT_INDEX

GRAVITY = 9.81
STANCE_WIDTH = 0.09  # lateral ankle offset from the path, reference body (m)
STAND_PELVIS = 0.975  # standing pelvis height, knees slightly soft (reference body, m)


@dataclass
class Motion:
    """A generated motion clip.

    Attributes
    ----------
    name, kind : str                 kind is "gait", "jump" or "reach"
    fps : float
    times : (frames,) float array    seconds
    rotations : (frames, J, 3, 3)    joint segment world rotations
    positions : (frames, J, 3)       joint world positions
    root_position : (frames, 3)      root trajectory on the ground plane (y = 0)
    heading : (frames,)              root heading, radians about +Y
    cyclic : bool
    frames_per_cycle : int or None   N such that frame k + N repeats frame k in the root frame
    params : dict                    requested physical parameters
    events : dict                    key events as frame indices (contacts, take-off, peaks)
    pose_at : callable or None       pose_at(times) -> (rotations, positions, root, heading),
                                     used to evaluate the motion off the frame grid
    """

    name: str
    kind: str
    fps: float
    times: np.ndarray
    rotations: np.ndarray
    positions: np.ndarray
    root_position: np.ndarray
    heading: np.ndarray
    cyclic: bool
    frames_per_cycle: int | None
    params: dict
    events: dict = field(default_factory=dict)
    pose_at: object = None


def _arm_direction(chest_rot, swing, abduction, side_sign):
    """Upper-arm world direction: hanging, swung forward by ``swing``, abducted outwards."""
    hang = np.array([0.0, -1.0, 0.0])
    swing = np.asarray(swing, dtype=float)
    abduction = np.broadcast_to(np.asarray(abduction, dtype=float), swing.shape)
    local = np.einsum("fab,fbc,c->fa", rot_z(side_sign * abduction), rot_x(-swing), hang)
    return np.einsum("fab,fb->fa", chest_rot, local)


def _torso(lean, yaw_counter, head_level):
    """Local rotations along the torso chain: lean shared by spine and chest, head kept level."""
    spine = rot_x(0.45 * lean) @ rot_y(0.4 * yaw_counter)
    chest = rot_x(0.55 * lean) @ rot_y(0.6 * yaw_counter)
    neck = rot_x(-0.5 * head_level)
    head = rot_x(-0.5 * head_level)
    return spine, chest, neck, head


# --------------------------------------------------------------------------------------------
# Gaits
# --------------------------------------------------------------------------------------------

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


# --------------------------------------------------------------------------------------------
# Standing poses shared by jumps and reaches
# --------------------------------------------------------------------------------------------

def _standing_feet(t, z, scale):
    """Both feet flat on the ground at forward position z (frames,)."""
    feet = {}
    for side, sign in (("l", 1.0), ("r", -1.0)):
        flat = np.stack([np.full_like(t, sign * STANCE_WIDTH * scale), np.full_like(t, ANKLE_HEIGHT * scale),
                         z], axis=1)
        feet[side] = flat
    return feet


def _relaxed_arms(chest_rot, t, swing=None):
    f = len(t)
    swing = np.zeros(f) if swing is None else swing
    arm_dir, elbow = {}, {}
    for side, sign in (("l", 1.0), ("r", -1.0)):
        arm_dir[side] = _arm_direction(chest_rot, swing, np.radians(8.0) * np.ones(f), sign)
        elbow[side] = np.radians(12.0) + 0.3 * np.maximum(swing, 0)
    return arm_dir, elbow


# --------------------------------------------------------------------------------------------
# Jumps
# --------------------------------------------------------------------------------------------

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
    _, _, _, _, events = _jump_pose(skeleton, np.zeros(1), rise, distance, palm_offset)
    frames = int(np.ceil(events["end_time"] * fps)) + 1
    times = np.arange(frames) / fps

    def pose_at(t):
        R, P, root, heading, _ = _jump_pose(skeleton, np.asarray(t, dtype=float), rise, distance, palm_offset)
        return R, P, root, heading

    R, P, root, heading, events = _jump_pose(skeleton, times, rise, distance, palm_offset)
    frame_events = {k.replace("_time", "_frame"): int(round(v * fps)) for k, v in events.items()
                    if k != "end_time"}
    frame_events["take_off_frame"] = int(np.ceil(events["take_off_time"] * fps))
    frame_events["landing_frame"] = int(np.ceil(events["landing_time"] * fps))
    return Motion(name=name or "jump", kind="jump", fps=float(fps), times=times, rotations=R, positions=P,
                  root_position=root, heading=heading, cyclic=False, frames_per_cycle=None,
                  params={"rise": float(rise), "distance": float(distance)}, events=frame_events,
                  pose_at=pose_at)


# --------------------------------------------------------------------------------------------
# Reaches
# --------------------------------------------------------------------------------------------

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
    _, _, _, _, events = _reach_pose(skeleton, np.zeros(1), target_height, palm_offset, side)
    frames = int(np.ceil(events["end_time"] * fps)) + 1
    times = np.arange(frames) / fps

    def pose_at(t):
        R, P, root, heading, _ = _reach_pose(skeleton, np.asarray(t, dtype=float), target_height, palm_offset, side)
        return R, P, root, heading

    R, P, root, heading, events = _reach_pose(skeleton, times, target_height, palm_offset, side)
    return Motion(name=name or "reach", kind="reach", fps=float(fps), times=times, rotations=R, positions=P,
                  root_position=root, heading=heading, cyclic=False, frames_per_cycle=None,
                  params={"target_height": float(target_height), "side": side},
                  events={"peak_frame": int(round(events["peak_time"] * fps))}, pose_at=pose_at)
