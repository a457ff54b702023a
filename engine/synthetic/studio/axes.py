"""Units and up axes of the files a studio sequence is written in.

Studios disagree: some write millimetres, some Z up. The generator works in metres with Y up;
a sequence may be written in other units and axes, its files (consistent and unstructured
frames) and its ground truth (``truth.npz``) alike, and its metadata records how:
``p_file = from_metres_y_up @ p`` (Z up: ``(x, y, z) -> (x, -z, y)``, a proper rotation, so
faces keep their orientation and the character's front, +Z, becomes -Y). The template and the
manifest's body stay in metres, Y up.
"""

from __future__ import annotations

import numpy as np

UNITS = {"m": 1.0, "mm": 1000.0}
UP = {
    "+Y": (np.eye(3), {"up": "+Y", "forward": "+Z", "left": "+X"}),
    "+Z": (np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]), {"up": "+Z", "forward": "-Y", "left": "+X"}),
}


def from_metres_y_up(units="m", up="+Y"):
    """(3, 3) matrix taking metres, Y up to the file's coordinates."""
    if units not in UNITS:
        raise ValueError(f"unknown units {units!r}; choose one of {', '.join(UNITS)}")
    if up not in UP:
        raise ValueError(f"unknown up axis {up!r}; choose one of {', '.join(UP)}")
    return UNITS[units] * UP[up][0]


def to_file(V, units="m", up="+Y"):
    """Points (..., 3) in metres, Y up expressed in the file's units and axes."""
    return np.asarray(V) @ from_metres_y_up(units, up).T


def to_metres_y_up(V, units="m", up="+Y"):
    """Inverse of ``to_file``: file coordinates back to metres, Y up."""
    return np.asarray(V) @ np.linalg.inv(from_metres_y_up(units, up)).T


def truth_to_file(truth, units="m", up="+Y"):
    """Ground-truth arrays expressed like the files: positions scaled and turned, rotations turned.

    ``heading`` stays the angle about the up axis; ``times`` are unchanged.
    """
    R = UP[up][0]
    out = dict(truth)
    for key in ("template_positions", "joint_positions", "root_position"):
        if key in out:
            out[key] = to_file(out[key], units, up).astype(np.asarray(truth[key]).dtype)
    if "joint_rotations" in out:
        out["joint_rotations"] = R @ np.asarray(truth["joint_rotations"]) @ R.T
    return out


def axes_record(units="m", up="+Y"):
    """What a sequence's meta.json says about the coordinates of its files and truth."""
    return {"units": units, **UP[up][1], "from_metres_y_up": from_metres_y_up(units, up).tolist()}
