"""Named capture sets: ``demo`` (everything the demo motion spaces need) and ``tiny`` (tests) of the
procedural body, and ``studio`` / ``studio-tiny`` (``engine.synthetic.studio``: a real body and
real motion, reconstructed per frame like a multi-view studio)."""

from __future__ import annotations

from dataclasses import dataclass

from engine.synthetic.capture import SequenceSpec
from engine.synthetic.studio.presets import STUDIO_PRESETS


@dataclass(frozen=True)
class Preset:
    """A capture set: body resolution, frame rate, reconstruction noise and the sequences."""

    name: str
    vertices: int
    fps: float
    noise_mm: float
    sequences: tuple


def _gait(name, speed, turn_rate=0.0, cycles=2.0):
    return SequenceSpec(name, "gait", {"speed": speed, "turn_rate": turn_rate, "cycles": cycles})


def _jump(name, height, distance):
    return SequenceSpec(name, "jump", {"height": height, "distance": distance})


def _reach(name, height):
    return SequenceSpec(name, "reach", {"height": height, "side": "r"})


PRESETS = {
    "demo": Preset(
        name="demo", vertices=3000, fps=30.0, noise_mm=1.0,
        sequences=(
            _gait("walk_slow", 0.8), _gait("walk", 1.3), _gait("walk_fast", 1.8),
            _gait("jog", 2.8), _gait("run", 4.0),
            _gait("turn_left", 1.2, turn_rate=45.0), _gait("turn_right", 1.2, turn_rate=-45.0),
            _jump("jump_low_short", 0.30, 0.3), _jump("jump_low_long", 0.30, 1.2),
            _jump("jump_high_short", 0.55, 0.3), _jump("jump_high_long", 0.55, 1.2),
            _reach("reach_low", 0.7), _reach("reach_mid", 1.3), _reach("reach_high", 1.95),
        )),
    "tiny": Preset(
        name="tiny", vertices=1000, fps=15.0, noise_mm=1.0,
        sequences=(
            _gait("walk", 1.0, cycles=1.5), _gait("run", 3.5, cycles=1.5),
            _jump("jump", 0.35, 0.6), _reach("reach", 1.6),
        )),
    **STUDIO_PRESETS,
}


def get_preset(name):
    """The preset called ``name``; a ValueError lists the known ones otherwise."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(sorted(PRESETS))}") from None
