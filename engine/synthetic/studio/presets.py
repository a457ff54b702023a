"""The studio capture sets: ``studio`` (the full set) and ``studio-tiny`` (tests)."""

from __future__ import annotations

from dataclasses import dataclass

from engine.synthetic.studio.poses import CONTACT_KEYS, reach_keys
from engine.synthetic.studio.reconstruct import StudioCamera
from engine.synthetic.studio.sequences import StudioSequenceSpec


@dataclass(frozen=True)
class StudioPreset:
    """A studio capture set: frame rate, body and garment resolution, camera, sequences."""

    name: str
    fps: float
    body_vertices: int
    garment_detail: float
    camera: StudioCamera
    sequences: tuple

    @property
    def vertices(self):
        """Target vertex count of a reconstructed frame."""
        return self.camera.vertices

    @property
    def noise_mm(self):
        return 1000.0 * self.camera.noise


def _take(name, kind, *takes, units="m", up="+Y"):
    return StudioSequenceSpec(name, kind, takes=tuple(takes), units=units, up=up)


def _reach(name, height, units="m", up="+Y"):
    return StudioSequenceSpec(name, "reach", keys=tuple(reach_keys(height)), units=units, up=up,
                              params={"height": height, "side": "r"})


STUDIO = StudioPreset(
    name="studio", fps=25.0, body_vertices=13_380, garment_detail=1.0, camera=StudioCamera(),
    sequences=(
        _take("walk", "gait", ("002_01", 0.0, None)),
        _take("walk_7", "gait", ("007_01", 0.0, None)),
        _take("walk_slow_7", "gait", ("007_04", 0.0, None), units="mm", up="+Z"),
        _take("walk_brisk_7", "gait", ("007_12", 0.0, None), up="+Z"),
        _take("run", "gait", ("002_03", 0.0, None), units="mm"),
        _take("jump", "jump", ("002_04", 0.0, None), up="+Z"),
        _take("strikes", "performance", ("002_05", 0.0, None), units="mm"),
        _take("dance", "performance", ("005_02", 0.0, None), ("005_06", 0.0, None), ("005_17", 0.0, None)),
        StudioSequenceSpec("contacts", "contact", keys=tuple(CONTACT_KEYS)),
        _reach("reach_low", 0.75), _reach("reach_mid", 1.3), _reach("reach_high", 1.75, units="mm", up="+Z"),
    ))

STUDIO_TINY = StudioPreset(
    name="studio-tiny", fps=12.5, body_vertices=3000, garment_detail=0.5,
    camera=StudioCamera(spacing=0.012, merge=0.026, vertices=2500),
    sequences=(
        _take("walk", "gait", ("002_01", 0.0, 0.8)),
        _take("strikes", "performance", ("002_05", 2.0, 2.8), units="mm", up="+Z"),
        StudioSequenceSpec("contacts", "contact",
                           keys=((0.0, "stand", {}), (0.5, "hands_on_hips", {}), (0.8, "hands_on_hips", {}))),
    ))

STUDIO_PRESETS = {p.name: p for p in (STUDIO, STUDIO_TINY)}
