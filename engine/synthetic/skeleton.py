"""The synthetic humanoid's skeleton: joints, hierarchy, rest positions (Y up, facing +Z, metres).

The character's left is +X. Each joint drives the body segment distal to it (the hip drives the
thigh, the knee the shin, the ankle the foot). Rest pose: an A-pose with the arms 45 degrees
below horizontal, legs straight, feet flat on the ground (y = 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

JOINTS = (
    "pelvis", "spine", "chest", "neck", "head",
    "shoulder_l", "elbow_l", "wrist_l", "shoulder_r", "elbow_r", "wrist_r",
    "hip_l", "knee_l", "ankle_l", "hip_r", "knee_r", "ankle_r",
)
PARENTS = {
    "pelvis": None, "spine": "pelvis", "chest": "spine", "neck": "chest", "head": "neck",
    "shoulder_l": "chest", "elbow_l": "shoulder_l", "wrist_l": "elbow_l",
    "shoulder_r": "chest", "elbow_r": "shoulder_r", "wrist_r": "elbow_r",
    "hip_l": "pelvis", "knee_l": "hip_l", "ankle_l": "knee_l",
    "hip_r": "pelvis", "knee_r": "hip_r", "ankle_r": "knee_r",
}
JOINT_INDEX = {name: i for i, name in enumerate(JOINTS)}

# Segment lengths of the 1.75 m reference body (metres).
UPPER_ARM, FOREARM, HAND = 0.29, 0.25, 0.17
THIGH, SHIN = 0.43, 0.43  # Winter's anthropometry: 0.245 H each
ARM_DROP = np.radians(45.0)  # rest A-pose: arms 45 degrees below horizontal
REFERENCE_HEIGHT = 1.75


def _rest_positions():
    p = {
        "pelvis": (0.0, 0.99, 0.0),
        "spine": (0.0, 1.11, -0.01),
        "chest": (0.0, 1.27, -0.01),
        "neck": (0.0, 1.48, -0.015),
        "head": (0.0, 1.58, 0.0),
        "hip_l": (0.10, 0.94, 0.0),
    }
    p["knee_l"] = (0.10, 0.94 - THIGH, 0.01)
    p["ankle_l"] = (0.10, 0.94 - THIGH - SHIN, -0.005)
    arm = np.array([np.cos(ARM_DROP), -np.sin(ARM_DROP), 0.0])
    shoulder = np.array([0.185, 1.43, -0.02])
    p["shoulder_l"] = tuple(shoulder)
    p["elbow_l"] = tuple(shoulder + UPPER_ARM * arm)
    p["wrist_l"] = tuple(shoulder + (UPPER_ARM + FOREARM) * arm)
    for name in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"):
        x, y, z = p[f"{name}_l"]
        p[f"{name}_r"] = (-x, y, z)
    return np.array([p[name] for name in JOINTS], dtype=float)


@dataclass(frozen=True)
class Skeleton:
    """Joint names, parent indices and rest positions of a body scaled to ``height``.

    Attributes
    ----------
    names : tuple of str          joint names, JOINTS order
    parents : (J,) int array      parent index, -1 for the root (pelvis)
    rest : (J, 3) float array     rest joint positions
    scale : float                 height / 1.75
    """

    names: tuple
    parents: np.ndarray
    rest: np.ndarray
    scale: float

    @classmethod
    def humanoid(cls, height=REFERENCE_HEIGHT):
        scale = height / REFERENCE_HEIGHT
        parents = np.array([-1 if PARENTS[n] is None else JOINT_INDEX[PARENTS[n]] for n in JOINTS])
        return cls(names=JOINTS, parents=parents, rest=_rest_positions() * scale, scale=scale)

    def index(self, name):
        return JOINT_INDEX[name]

    def position(self, name):
        return self.rest[JOINT_INDEX[name]]

    @property
    def leg_length(self):
        return (THIGH + SHIN) * self.scale

    def to_dict(self):
        """JSON-friendly description (names, parents, rest positions)."""
        return {
            "joints": list(self.names),
            "parents": [int(p) for p in self.parents],
            "rest_positions": np.round(self.rest, 6).tolist(),
            "up": "+Y", "forward": "+Z", "left": "+X", "units": "m",
        }
