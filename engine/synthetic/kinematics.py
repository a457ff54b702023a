"""Posing the synthetic skeleton: torso forward kinematics, two-bone limb IK, foot placement.

All functions are vectorised over frames. Positions are world coordinates (metres); a segment's
world rotation maps its rest orientation to the posed one (rest joint frames are world aligned).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.rotations import axis_angle_matrix, frame_from_direction, rot_x, rot_y
from engine.synthetic.skeleton import FOREARM, JOINT_INDEX, JOINTS, SHIN, THIGH, UPPER_ARM

ANKLE_HEIGHT = 0.08  # rest ankle joint above the sole (reference body, m)
HEEL_BACK = 0.06  # heel contact behind the ankle
BALL_FORWARD = 0.12  # ball of the foot ahead of the ankle
ARM_POLE_REST = np.array([0.0, 0.0, -1.0])  # elbows point backwards
LEG_POLE_REST = np.array([0.0, 0.0, 1.0])  # knees point forwards


def smoothstep(e0, e1, x):
    """Cubic smooth step from 0 at e0 to 1 at e1."""
    t = np.clip((np.asarray(x, dtype=float) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def minimum_jerk(u):
    """Quintic ease 0 -> 1 with zero velocity and acceleration at both ends."""
    u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u * u)


def keyframes(times, values, t):
    """Minimum-jerk interpolation through keys (value held outside the key range).

    Parameters
    ----------
    times : (k,) increasing float array
    values : (k, ...) float array
    t : (frames,) float array

    Returns
    -------
    (frames, ...) float array
    """
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    t = np.asarray(t, dtype=float)
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    u = minimum_jerk((t - times[i]) / (times[i + 1] - times[i]))
    u = u.reshape(u.shape + (1,) * (values.ndim - 1))
    return values[i] + (values[i + 1] - values[i]) * u


def hermite(t0, t1, p0, p1, v0, v1, t):
    """Cubic Hermite curve between (t0, p0, v0) and (t1, p1, v1) evaluated at t (vectorised)."""
    h = t1 - t0
    s = ((np.asarray(t, dtype=float) - t0) / h)[:, None]
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1


def softmin(values, k):
    """Smooth minimum over the first axis (log-sum-exp with temperature k)."""
    values = np.asarray(values, dtype=float)
    m = values.min(axis=0)
    return m - k * np.log(np.sum(np.exp(-(values - m) / k), axis=0))


def foot_pose(flat_ankle, yaw, pitch, scale):
    """Ankle position and foot rotation for a foot rolling on its heel or ball.

    Parameters
    ----------
    flat_ankle : (frames, 3)   ankle position with the foot flat on the ground
    yaw : (frames,)            foot heading (radians about +Y)
    pitch : (frames,)          toes-up angle; > 0 pivots on the heel, < 0 on the ball
    scale : float              body scale

    Returns
    -------
    ankle : (frames, 3) float array
    rotation : (frames, 3, 3) float array   world rotation of the foot segment
    """
    pitch = np.asarray(pitch, dtype=float)
    Ryaw = rot_y(yaw)
    Rpitch = rot_x(-pitch)
    heel = np.stack([np.zeros_like(pitch), np.full_like(pitch, ANKLE_HEIGHT), np.full_like(pitch, HEEL_BACK)], 1)
    ball = np.stack([np.zeros_like(pitch), np.full_like(pitch, ANKLE_HEIGHT), np.full_like(pitch, -BALL_FORWARD)], 1)
    offset = np.where((pitch >= 0)[:, None], heel, ball) * scale  # pivot -> ankle, flat foot frame
    pivot = flat_ankle - np.einsum("fab,fb->fa", Ryaw, offset)
    ankle = pivot + np.einsum("fab,fbc,fc->fa", Ryaw, Rpitch, offset)
    return ankle, Ryaw @ Rpitch


def two_bone_ik(root, target, upper, lower, pole):
    """Analytic two-bone IK: joint position and segment directions reaching ``target``.

    Parameters
    ----------
    root : (frames, 3)     shoulder or hip position
    target : (frames, 3)   end-effector target (wrist or ankle, or a point along the lower bone)
    upper, lower : float   bone lengths
    pole : (frames, 3)     direction the middle joint (elbow, knee) should point to

    Returns
    -------
    upper_dir, lower_dir : (frames, 3) unit directions
    hinge : (frames, 3)    the joint's hinge axis (shared by both segments)
    reach : (frames,)      distance from root to the reached point (target clamped if too far)
    """
    delta = target - root
    dist = np.linalg.norm(delta, axis=1)
    u = delta / dist[:, None]
    d = np.clip(dist, abs(upper - lower) * 1.01 + 1e-6, (upper + lower) * 0.9995)
    cos_a = np.clip((upper**2 + d**2 - lower**2) / (2 * upper * d), -1.0, 1.0)
    v = pole - np.sum(pole * u, axis=1, keepdims=True) * u
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    knee = root + upper * (cos_a[:, None] * u + np.sqrt(1 - cos_a**2)[:, None] * v)
    upper_dir = (knee - root) / upper
    lower_dir = root + d[:, None] * u - knee
    lower_dir /= np.linalg.norm(lower_dir, axis=1, keepdims=True)
    hinge = np.cross(upper_dir, v)
    hinge /= np.linalg.norm(hinge, axis=1, keepdims=True)
    return upper_dir, lower_dir, hinge, d


def flexed_limb(upper_dir, flex, bend_towards):
    """Directions of a limb along ``upper_dir`` with its middle joint flexed.

    Parameters
    ----------
    upper_dir : (frames, 3)     upper segment direction
    flex : (frames,)            flexion angle in radians
    bend_towards : (frames, 3)  the lower segment swings towards this direction

    Returns
    -------
    lower_dir : (frames, 3)
    hinge : (frames, 3)   hinge axis in the ``upper_dir x pole`` convention of ``two_bone_ik``,
                          where the pole (the way the joint points) is opposite ``bend_towards``
    """
    axis = np.cross(upper_dir, bend_towards)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    lower_dir = np.einsum("fab,fb->fa", axis_angle_matrix(axis, flex), upper_dir)
    return lower_dir, -axis


def segment_rotation(direction, hinge, rest_direction, rest_pole):
    """World rotation of a limb segment with the given direction and hinge axis.

    The rest frame is (rest hinge, rest direction, rest pole); the posed frame keeps the hinge,
    so flexion about it never twists the segment.
    """
    pole = np.cross(hinge, direction)
    posed = frame_from_direction(direction, pole)
    rest = frame_from_direction(rest_direction, rest_pole)
    return posed @ rest.T


@dataclass
class PoseTargets:
    """Per-frame pose description, turned into joint transforms by ``pose_joints``.

    All arrays have a leading frames axis. Angles in radians; positions in world metres.
    """

    pelvis_position: np.ndarray  # (f, 3)
    pelvis_rotation: np.ndarray  # (f, 3, 3) world
    spine: np.ndarray  # (f, 3, 3) local rotations along the torso chain
    chest: np.ndarray
    neck: np.ndarray
    head: np.ndarray
    arm_dir: dict  # side -> (f, 3) upper-arm direction in world, or None when IK drives it
    elbow_flex: dict  # side -> (f,)
    palm_target: dict  # side -> (f, 3) world palm target (reaching arm) or None
    arm_pole: dict  # side -> (f, 3) direction the elbow points when IK drives the arm
    ankle: dict  # side -> (f, 3) ankle target
    foot_rotation: dict  # side -> (f, 3, 3)
    knee_pole: np.ndarray  # (f, 3)


def pose_joints(skeleton, targets, palm_offset):
    """Joint world rotations and positions for a pose description.

    Parameters
    ----------
    skeleton : Skeleton
    targets : PoseTargets
    palm_offset : float   distance from wrist to palm centre along the forearm (reaching IK)

    Returns
    -------
    rotations : (frames, J, 3, 3) float array
    positions : (frames, J, 3) float array
    """
    s = skeleton.scale
    rest = skeleton.rest
    f = len(targets.pelvis_position)
    R = np.zeros((f, len(JOINTS), 3, 3))
    P = np.zeros((f, len(JOINTS), 3))

    def put(name, rotation, position):
        R[:, JOINT_INDEX[name]] = rotation
        P[:, JOINT_INDEX[name]] = position

    def child(parent, name):
        i, j = JOINT_INDEX[parent], JOINT_INDEX[name]
        return P[:, i] + np.einsum("fab,b->fa", R[:, i], rest[j] - rest[i])

    put("pelvis", targets.pelvis_rotation, targets.pelvis_position)
    chain = (("pelvis", "spine", targets.spine), ("spine", "chest", targets.chest),
             ("chest", "neck", targets.neck), ("neck", "head", targets.head))
    for parent, name, local in chain:
        put(name, R[:, JOINT_INDEX[parent]] @ local, child(parent, name))
    chest_rot = R[:, JOINT_INDEX["chest"]]
    forward = chest_rot[:, :, 2]
    for side in ("l", "r"):
        shoulder = child("chest", f"shoulder_{side}")
        rest_dir = rest[JOINT_INDEX[f"elbow_{side}"]] - rest[JOINT_INDEX[f"shoulder_{side}"]]
        rest_dir /= np.linalg.norm(rest_dir)
        if targets.palm_target.get(side) is not None:
            upper_dir, lower_dir, hinge, _ = two_bone_ik(
                shoulder, targets.palm_target[side], UPPER_ARM * s, (FOREARM + palm_offset) * s,
                targets.arm_pole[side])
        else:
            upper_dir = targets.arm_dir[side]
            lower_dir, hinge = flexed_limb(upper_dir, targets.elbow_flex[side], forward)
        upper_rot = segment_rotation(upper_dir, hinge, rest_dir, ARM_POLE_REST)
        lower_rot = segment_rotation(lower_dir, hinge, rest_dir, ARM_POLE_REST)
        elbow = shoulder + UPPER_ARM * s * upper_dir
        wrist = elbow + FOREARM * s * lower_dir
        put(f"shoulder_{side}", upper_rot, shoulder)
        put(f"elbow_{side}", lower_rot, elbow)
        put(f"wrist_{side}", lower_rot, wrist)

        hip = child("pelvis", f"hip_{side}")
        leg_rest = rest[JOINT_INDEX[f"knee_{side}"]] - rest[JOINT_INDEX[f"hip_{side}"]]
        leg_rest /= np.linalg.norm(leg_rest)
        thigh_dir, shin_dir, knee_hinge, _ = two_bone_ik(hip, targets.ankle[side], THIGH * s, SHIN * s,
                                                         targets.knee_pole)
        knee = hip + THIGH * s * thigh_dir
        ankle = knee + SHIN * s * shin_dir
        put(f"hip_{side}", segment_rotation(thigh_dir, knee_hinge, leg_rest, LEG_POLE_REST), hip)
        put(f"knee_{side}", segment_rotation(shin_dir, knee_hinge, leg_rest, LEG_POLE_REST), knee)
        put(f"ankle_{side}", targets.foot_rotation[side], ankle)
    return R, P
