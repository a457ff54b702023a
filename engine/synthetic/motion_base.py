"""What every procedural motion shares: the ``Motion`` record, the reference body's stance
constants, and the torso, arm and standing-feet poses that gaits, jumps and reaches build on.

Conventions: Y up, the character starts at the origin facing +Z, its left is +X; headings are
radians about +Y (positive = turning left); angles in user-facing parameters are degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from engine.rotations import rot_x, rot_y, rot_z
from engine.synthetic.kinematics import ANKLE_HEIGHT

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


def sample_one_shot(pose, fps):
    """Sample a one-shot motion: ``pose(t)`` -> (R, P, root, heading, events) for times ``t``
    (frames,), with ``events["end_time"]`` its length. Returns (times, pose_at, R, P, root,
    heading, events): the frames at ``fps`` up to and including the end, and ``pose_at(t)`` ->
    (R, P, root, heading) for the Motion."""
    end = pose(np.zeros(1))[4]["end_time"]
    times = np.arange(int(np.ceil(end * fps)) + 1) / fps

    def pose_at(t):
        R, P, root, heading, _ = pose(np.asarray(t, dtype=float))
        return R, P, root, heading

    return (times, pose_at, *pose(times))
