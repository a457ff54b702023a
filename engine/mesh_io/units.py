"""Length units and up axis of captured meshes: detection and conversion to metres, +Y up.

Capture files come in metres, centimetres or millimetres, with +Y or +Z up. The engine works in
metres with +Y up (DESIGN.md conventions), so readers of captures convert on the way in:

``V = to_metres_y_up(V_file, "mm", "z")``      file coordinates -> metres, +Y up
``V_file = from_metres_y_up(V, "mm", "z")``    and back
``convention = resolve_convention(frames, units="auto", up="auto")``   what the files are in

Z up becomes Y up by the rotation of -90 degrees about X, ``(x, y, z) -> (x, z, -y)``: a proper
rotation (faces keep their orientation), and a Z-up scene's front (-Y, as in Blender) faces +Z.

Detection (``auto``) assumes a human-sized subject, whose model size (the largest extent of the
bounding box) is 0.5-2.5 m: 0.5-2.5 in metres, 50-250 in centimetres, 500-2,500 in millimetres.
The ranges are a factor of 20 apart, so a person's size names the unit. The up axis is
the one along which the subject keeps coming back to a floor, when the frames show one (an
animal that walks, longer than it is tall, as much as a person), else the longer of the body's
Y and Z extents: a standing or moving person is several times taller than deep.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UNITS_PER_METRE = {"m": 1.0, "cm": 100.0, "mm": 1000.0}
UP_AXES = ("y", "z")
HUMAN_SIZE_M = (0.5, 2.5)
UP_RATIO_CONFIDENT = 1.25
FLOOR_TOLERANCE = 0.02    # a frame is on the floor when its lowest point is this share of the model size above it
FLOOR_TOUCHES = 0.6       # the up axis: on the floor in at least this share of the frames ...
FLOOR_MISSES = 0.3        # ... and the other axis's lowest level in at most this share
FLOOR_MIN_FRAMES = 8


def _units(units):
    if units not in UNITS_PER_METRE:
        raise ValueError(f"units must be one of {', '.join(UNITS_PER_METRE)}, got {units!r}")
    return units


def _up(up):
    """'y' or 'z' from 'y', 'Y', '+Y', 'z', 'Z', '+Z'."""
    axis = str(up).strip().lower().lstrip("+")
    if axis not in UP_AXES:
        raise ValueError(f"up must be one of y, z (or +Y, +Z), got {up!r}")
    return axis


def to_metres_y_up(V, units="m", up="y"):
    """Positions in ``units`` with ``up`` up -> metres with +Y up.

    Parameters
    ----------
    V : (..., 3) float array   positions in the file's coordinates (one mesh or a sequence)
    units : {"m", "cm", "mm"}
    up : {"y", "z"} (or "+Y", "+Z")

    Returns
    -------
    V : (..., 3) float64 array   a new array; ``(x, y, z) -> (x, z, -y) / per_metre`` for Z up
    """
    V = np.asarray(V, dtype=np.float64)
    out = V / UNITS_PER_METRE[_units(units)]
    if _up(up) == "z":
        out = np.stack([out[..., 0], out[..., 2], -out[..., 1]], axis=-1)
    return out


def from_metres_y_up(V, units="m", up="y"):
    """The inverse of :func:`to_metres_y_up`: metres, +Y up -> ``units`` with ``up`` up.

    Parameters
    ----------
    V : (..., 3) float array   positions in metres, +Y up
    units : {"m", "cm", "mm"}
    up : {"y", "z"} (or "+Y", "+Z")

    Returns
    -------
    V : (..., 3) float64 array   ``(x, y, z) -> (x, -z, y) * per_metre`` for Z up
    """
    V = np.asarray(V, dtype=np.float64)
    out = V * UNITS_PER_METRE[_units(units)]
    if _up(up) == "z":
        out = np.stack([out[..., 0], -out[..., 2], out[..., 1]], axis=-1)
    return out


def detect_units(size):
    """The unit in which a human-sized model measures ``size`` across.

    Parameters
    ----------
    size : float   model size (largest bounding-box extent) in the file's units

    Returns
    -------
    units : str    "m", "cm" or "mm"
    fits : bool    True when ``size`` lies in that unit's human range (0.5-2.5 m); otherwise
                   ``units`` is the unit whose range is nearest on a log scale (a guess)
    """
    size = float(size)
    if not np.isfinite(size) or size <= 0:
        raise ValueError(f"model size must be positive and finite, got {size}")
    gaps = {}
    for units, per_metre in UNITS_PER_METRE.items():
        lo, hi = HUMAN_SIZE_M[0] * per_metre, HUMAN_SIZE_M[1] * per_metre
        if lo <= size <= hi:
            return units, True
        gaps[units] = max(np.log(lo / size), np.log(size / hi))
    return min(gaps, key=gaps.get), False


def detect_up(extents):
    """Up axis from per-frame bounding-box extents: the longer of Y and Z.

    Parameters
    ----------
    extents : (frames, 3) float array   each frame's bounding-box extent along x, y, z

    Returns
    -------
    up : str          "y" or "z"
    ratio : float     median over frames of (Y extent / Z extent), taken on a log scale, so
                      the same frames turned Z up give exactly its inverse (also for an even
                      number of frames)
    confident : bool  the ratio is at least 1.25 (or at most 1 / 1.25)
    """
    extents = np.atleast_2d(np.asarray(extents, dtype=np.float64))
    ratio = float(np.exp(np.median(np.log(np.maximum(extents[:, 1], 1e-300) / np.maximum(extents[:, 2], 1e-300)))))
    up = "y" if ratio >= 1.0 else "z"
    return up, ratio, bool(max(ratio, 1.0 / max(ratio, 1e-300)) >= UP_RATIO_CONFIDENT)


def detect_floor(lows, size):
    """Up axis from a floor: the axis along which the lowest point keeps coming back to one level.

    A subject stands, walks or lies on a floor, so along the up axis its lowest point is at the
    floor's level in most frames (a jump lifts it for some), while along a horizontal axis the
    lowest point is whatever part reaches furthest that way, and it moves as the subject travels
    or turns. It tells an animal or a person lying down, longer than tall, from one standing on
    end; a subject that stays in place tells nothing (both axes look alike) and the extents
    decide.

    Parameters
    ----------
    lows : (frames, 2) float array   each frame's smallest Y and Z
    size : float                     model size, in the same units

    Returns
    -------
    up : str or None      "y" or "z" when the frames show a floor along one and not the other,
                          else None (fewer than 8 frames, or no clear floor)
    touches : (2,) float  share of the frames whose lowest Y / Z lies within 2% of the model size
                          of that axis's floor level (its 5th percentile over the frames)
    """
    lows = np.atleast_2d(np.asarray(lows, dtype=np.float64))
    if len(lows) < FLOOR_MIN_FRAMES or not np.isfinite(size) or size <= 0:
        return None, np.full(2, np.nan)
    floor = np.percentile(lows, 5, axis=0)
    touches = np.mean(lows <= floor + FLOOR_TOLERANCE * size, axis=0)
    return _floor_axis(touches), touches


def _floor_axis(touches):
    """"y", "z" or None from the shares of frames on a floor along Y and Z."""
    for axis, (on, other) in zip(UP_AXES, (touches, touches[::-1])):
        if on >= FLOOR_TOUCHES and other <= FLOOR_MISSES:
            return axis
    return None


@dataclass(frozen=True)
class Convention:
    """Units and up axis of a set of capture files, and how they were decided.

    Attributes
    ----------
    units : str          "m", "cm" or "mm"
    up : str             "y" or "z"
    units_from : str     "given" (asked for), "detected" (from the model size) or "metadata"
                         (the dataset's manifest or meta.json said so)
    up_from : str        the same for the up axis
    size : float         median over frames of the model size, in ``units``
    up_ratio : float     median over frames of (Y extent / Z extent)
    floor : tuple        (share of frames on a floor along Y, along Z) (:func:`detect_floor`), or
                         () when there were too few frames to tell
    warnings : tuple of str   doubts worth telling the user (ambiguous size or axis, metadata
                              contradicted by the geometry)
    """

    units: str = "m"
    up: str = "y"
    units_from: str = "given"
    up_from: str = "given"
    size: float = float("nan")
    up_ratio: float = float("nan")
    floor: tuple = ()
    warnings: tuple = ()

    @property
    def per_metre(self):
        """File units per metre (1, 100 or 1000)."""
        return UNITS_PER_METRE[self.units]

    @property
    def up_label(self):
        """"+Y" or "+Z"."""
        return "+" + self.up.upper()

    def describe(self):
        """One line saying what the files are in and why, e.g. for the command line."""
        units = f"units {self.units} ({self.units_from}"
        if np.isfinite(self.size):
            units += f": the model is {self.size:.4g} {self.units} across"
        up = f"up {self.up_label} ({self.up_from}"
        if self.up_from == "detected" and self.floor and _floor_axis(self.floor) == self.up:
            on, other = self.floor if self.up == "y" else self.floor[::-1]
            up += f": on a floor in {on:.0%} of the frames, against {other:.0%} along the other axis"
        elif np.isfinite(self.up_ratio) and self.up_ratio > 0:
            # the extent along the up axis over the other's: below 1 when a given axis is the shorter
            ratio = self.up_ratio if self.up == "y" else 1 / self.up_ratio
            up += f": height / depth {ratio:.2g}" if 1e-3 < ratio < 1e3 else ": the model is flat along one axis"
        return f"{units}), {up})"

    def to_metadata(self):
        """JSON record: units, up ("+Y"/"+Z"), units_from, up_from."""
        return {"units": self.units, "up": self.up_label, "units_from": self.units_from, "up_from": self.up_from}


def resolve_convention(frames, units="auto", up="auto", *, declared_units=None, declared_up=None):
    """Decide the units and up axis of capture frames: as given, else detected, else declared.

    Parameters
    ----------
    frames : iterable of (n, 3) float arrays   vertex positions of the frames, file coordinates
    units : {"auto", "m", "cm", "mm"}          "auto" detects
    up : {"auto", "y", "z"}                    "auto" detects
    declared_units, declared_up : str or None  what the dataset's metadata says (manifest
                                               ``body.units`` / ``body.up``), or None

    Returns
    -------
    Convention

    Notes
    -----
    With "auto", a confident detection (a human-sized model size, a body clearly taller than
    deep) wins over the metadata, which is used only when the geometry is ambiguous; every
    disagreement and every guess is reported in ``warnings``. A given unit or axis is always
    used, with a warning when the geometry contradicts it.
    """
    frames_list = list(frames)
    extents = np.array([np.ptp(np.asarray(V, dtype=np.float64), axis=0) for V in frames_list], dtype=np.float64)
    if extents.size == 0:
        raise ValueError("no frames to decide units and up axis from")
    size = float(np.median(extents.max(axis=1)))
    declared_units = None if declared_units in (None, "") else _units(str(declared_units).strip().lower())
    declared_up = None if declared_up in (None, "") else _up(declared_up)
    warnings = []

    detected_units, fits = detect_units(size)
    if units != "auto":
        chosen_units, units_from = _units(units), "given"
        if fits and detected_units != chosen_units:
            warnings.append(f"the model is {size:.4g} {chosen_units} across, not human-sized; "
                            f"it looks like {detected_units}")
    elif fits:
        chosen_units, units_from = detected_units, "detected"
        if declared_units is not None and declared_units != detected_units:
            warnings.append(f"the metadata says {declared_units}, but the model is {size:.4g} units across: "
                            f"using {detected_units} (pass --units {declared_units} to keep the metadata's)")
    elif declared_units is not None:
        chosen_units, units_from = declared_units, "metadata"
    else:
        chosen_units, units_from = detected_units, "detected"
        warnings.append(f"the model is {size:.4g} units across, not human-sized in m, cm or mm; guessed "
                        f"{detected_units} (pass --units to say)")

    detected_up, ratio, confident = detect_up(extents)
    lows = np.array([np.asarray(V, dtype=np.float64)[:, 1:].min(axis=0) for V in frames_list], dtype=np.float64)
    floor_up, touches = detect_floor(lows, size)
    extents_up = detected_up
    if floor_up is not None:
        detected_up, confident = floor_up, True
    floor = tuple(round(float(t), 3) for t in touches) if np.all(np.isfinite(touches)) else ()
    if up != "auto":
        chosen_up, up_from = _up(up), "given"
        if confident and detected_up != chosen_up:
            warnings.append(f"{_up_evidence(detected_up, chosen_up, ratio, touches, floor_up)}; "
                            f"is +{detected_up.upper()} up?")
    elif confident:
        chosen_up, up_from = detected_up, "detected"
        if floor_up is not None and extents_up != floor_up and max(ratio, 1 / ratio) >= UP_RATIO_CONFIDENT:
            warnings.append(f"the body is longer along {extents_up.upper()} than {floor_up.upper()}, but "
                            f"{_up_evidence(floor_up, extents_up, ratio, touches, floor_up)}: using "
                            f"+{floor_up.upper()} (pass --up {extents_up} if not)")
        if declared_up is not None and declared_up != detected_up:
            warnings.append(f"the metadata says +{declared_up.upper()} up, but "
                            f"{_up_evidence(detected_up, declared_up, ratio, touches, floor_up)}: using "
                            f"+{detected_up.upper()} (pass --up {declared_up} to keep the metadata's)")
    elif declared_up is not None:
        chosen_up, up_from = declared_up, "metadata"
    else:
        chosen_up, up_from = detected_up, "detected"
        warnings.append(f"the body's Y and Z extents are alike (ratio {ratio:.2f}) and the frames show no "
                        f"floor; guessed +{detected_up.upper()} up (pass --up to say)")
    longest = np.median(extents, axis=0)
    if floor_up is None and longest[0] > UP_RATIO_CONFIDENT * max(longest[1], longest[2]):
        warnings.append("the body is longest along X; only +Y or +Z up are supported")
    return Convention(units=chosen_units, up=chosen_up, units_from=units_from, up_from=up_from, size=size,
                      up_ratio=ratio, floor=floor, warnings=tuple(warnings))


def _up_evidence(axis, other, ratio, touches, floor_up):
    """Why the geometry says +``axis`` up rather than +``other``, in words."""
    if floor_up == axis:
        on, off = touches if axis == "y" else touches[::-1]
        return (f"the subject stands on a floor along {axis.upper()} ({on:.0%} of the frames, "
                f"{off:.0%} along {other.upper()})")
    return f"the body is longer along {axis.upper()} than {other.upper()} (ratio {max(ratio, 1 / ratio):.2g})"


__all__ = ["Convention", "HUMAN_SIZE_M", "UNITS_PER_METRE", "UP_AXES", "detect_floor", "detect_units",
           "detect_up", "from_metres_y_up", "resolve_convention", "to_metres_y_up"]
