"""Named capture sets: ``demo`` (everything the demo motion spaces and motion graph need: gaits,
jumps, reaches, standing idles, walks that stop and start, and one true continuous performance
walk -> stop -> jump -> start -> walk for evaluation) and ``tiny`` (the same in miniature; tests) of the
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


def _stand(name, breath=0.008, sway=0.0, period=2.0):
    return SequenceSpec(name, "stand", {"period": period, "breath": breath, "sway": sway, "cycles": 1.0})


def _walk_change(name, kind, speed, walk=1.0):
    return SequenceSpec(name, f"gait_{kind}", {"speed": speed, "walk": walk})


def _performance(name, speed, height, distance, walk=1.0):
    return SequenceSpec(name, "performance", {"speed": speed, "height": height, "distance": distance, "walk": walk})


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
            _stand("stand", breath=0.008), _stand("stand_shift", breath=0.006, sway=0.02, period=2.4),
            _walk_change("walk_stop", "stop", 1.3), _walk_change("walk_start", "start", 1.3),
            _walk_change("walk_stop_slow", "stop", 1.0), _walk_change("walk_start_slow", "start", 1.0),
            _performance("performance", 1.3, 0.45, 0.8, walk=1.5),
        )),
    "tiny": Preset(
        name="tiny", vertices=1000, fps=15.0, noise_mm=1.0,
        sequences=(
            _gait("walk", 1.0, cycles=1.5), _gait("run", 3.5, cycles=1.5),
            _jump("jump", 0.35, 0.6), _reach("reach", 1.6),
            _stand("stand", breath=0.008), _stand("stand_shift", breath=0.006, sway=0.02, period=2.4),
            _walk_change("walk_stop", "stop", 1.0, walk=0.6), _walk_change("walk_start", "start", 1.0, walk=0.6),
            _performance("performance", 1.0, 0.35, 0.6, walk=1.0),
        )),
    **STUDIO_PRESETS,
}


def get_preset(name):
    """The preset called ``name``; a ValueError lists the known ones otherwise."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(sorted(PRESETS))}") from None
