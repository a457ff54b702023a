"""BVH motion capture: parsing and forward kinematics.

A BVH file is a joint hierarchy (offsets from the parent, channel lists) followed by one line of
channel values per frame. Rotation channels compose intrinsically in the order the file lists
them (``Zrotation Yrotation Xrotation`` is R = Rz Ry Rx); a joint's world transform is its
parent's followed by its offset (plus any position channels) and its rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.rotations import rot_x, rot_y, rot_z

_AXIS_ROTATION = {"Xrotation": rot_x, "Yrotation": rot_y, "Zrotation": rot_z}
_AXIS_POSITION = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


class BvhError(ValueError):
    """A BVH text that cannot be parsed; the message names the source and the line."""


@dataclass(frozen=True)
class Bvh:
    """A parsed BVH take.

    Attributes
    ----------
    names : tuple of str            joint names in file order (End Sites excluded)
    parents : (J,) int array        parent index, -1 for the root
    offsets : (J, 3) float array    offset from the parent joint, file units
    channels : tuple of tuples      channel names of each joint
    motion : (frames, C) float array   channel values, C = total channel count
    frame_time : float              seconds per frame
    """

    names: tuple
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple
    motion: np.ndarray
    frame_time: float

    @property
    def fps(self):
        return 1.0 / self.frame_time

    @property
    def frames(self):
        return len(self.motion)

    def index(self, name):
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no joint {name!r} in this take") from None


def parse_bvh(text, source="<bvh>"):
    """Parse the text of a BVH file.

    Parameters
    ----------
    text : str
    source : str   name used in error messages

    Returns
    -------
    bvh : Bvh
    """
    lines = text.splitlines()
    names, parents, offsets, channels = [], [], [], []
    stack = []  # joint index per open brace (-2 for an End Site)
    pending = None
    i = 0
    while i < len(lines):
        tokens = lines[i].split()
        i += 1
        if not tokens:
            continue
        key = tokens[0]
        if key == "HIERARCHY":
            continue
        if key in ("ROOT", "JOINT"):
            if len(tokens) < 2:
                raise BvhError(f"{source}: line {i}: {key} without a name")
            parent = next((j for j in reversed(stack) if j >= 0), -1)
            if key == "JOINT" and parent < 0:
                raise BvhError(f"{source}: line {i}: JOINT outside a ROOT")
            names.append(tokens[1])
            parents.append(parent)
            offsets.append(np.zeros(3))
            channels.append(())
            pending = len(names) - 1
        elif key == "End":
            pending = -2
        elif key == "{":
            if pending is None:
                raise BvhError(f"{source}: line {i}: unexpected '{{'")
            stack.append(pending)
            pending = None
        elif key == "}":
            if not stack:
                raise BvhError(f"{source}: line {i}: unbalanced '}}'")
            stack.pop()
        elif key == "OFFSET":
            if len(tokens) != 4 or not stack:
                raise BvhError(f"{source}: line {i}: OFFSET needs three numbers inside a joint")
            if stack[-1] >= 0:
                offsets[stack[-1]] = np.array([float(t) for t in tokens[1:]])
        elif key == "CHANNELS":
            if not stack or stack[-1] < 0:
                raise BvhError(f"{source}: line {i}: CHANNELS outside a joint")
            count = int(tokens[1])
            listed = tuple(tokens[2:])
            if len(listed) != count or any(c not in _AXIS_ROTATION and c not in _AXIS_POSITION for c in listed):
                raise BvhError(f"{source}: line {i}: bad channel list {' '.join(tokens[1:])}")
            channels[stack[-1]] = listed
        elif key == "MOTION":
            break
        else:
            raise BvhError(f"{source}: line {i}: unexpected {key!r} in the hierarchy")
    if not names:
        raise BvhError(f"{source}: no ROOT joint")
    if stack:
        raise BvhError(f"{source}: the hierarchy is not closed")
    frames, frame_time = None, None
    while i < len(lines) and (frames is None or frame_time is None):
        text_line = lines[i].strip()
        i += 1
        if text_line.startswith("Frames:"):
            frames = int(text_line.split(":")[1])
        elif text_line.startswith("Frame Time:"):
            frame_time = float(text_line.split(":")[1])
    if frames is None or frame_time is None or frame_time <= 0:
        raise BvhError(f"{source}: missing or bad 'Frames:' / 'Frame Time:' lines")
    width = sum(len(c) for c in channels)
    rows = [line for line in lines[i:] if line.strip()]
    if len(rows) < frames:
        raise BvhError(f"{source}: {frames} frames announced, {len(rows)} present")
    motion = np.array(" ".join(rows[:frames]).split(), dtype=float)
    if motion.size != frames * width:
        raise BvhError(f"{source}: expected {width} values per frame for {frames} frames, got {motion.size} values")
    return Bvh(names=tuple(names), parents=np.array(parents), offsets=np.array(offsets),
               channels=tuple(channels), motion=motion.reshape(frames, width), frame_time=frame_time)


def forward_kinematics(bvh, frames=None):
    """World rotations and positions of every joint.

    Parameters
    ----------
    bvh : Bvh
    frames : index array or slice or None   which frames (default all)

    Returns
    -------
    R : (f, J, 3, 3) float array   world rotation of each joint's frame
    P : (f, J, 3) float array      world position of each joint, file units
    """
    motion = bvh.motion if frames is None else bvh.motion[frames]
    f, J = len(motion), len(bvh.names)
    R = np.empty((f, J, 3, 3))
    P = np.empty((f, J, 3))
    column = 0
    for j in range(J):
        local_R = np.broadcast_to(np.eye(3), (f, 3, 3))
        local_t = np.broadcast_to(bvh.offsets[j], (f, 3)).copy()
        for name in bvh.channels[j]:
            values = motion[:, column]
            column += 1
            if name in _AXIS_POSITION:
                local_t[:, _AXIS_POSITION[name]] += values
            else:
                local_R = local_R @ _AXIS_ROTATION[name](np.radians(values))
        p = bvh.parents[j]
        if p < 0:
            R[:, j], P[:, j] = local_R, local_t
        else:
            R[:, j] = R[:, p] @ local_R
            P[:, j] = P[:, p] + np.einsum("fab,fb->fa", R[:, p], local_t)
    return R, P
