"""Synthetic performance capture with ground truth (the issue's stand-in for real 4D captures).

A procedural humanoid (``build_body``) performs parameterised motions (``motions.gait``,
``motions.jump``, ``motions.reach``); ``animate`` skins it and adds soft-tissue and garment
dynamics; ``generate_sequence_data`` also re-meshes every frame independently, as a multi-view
reconstruction would, and keeps the ground truth needed to score alignment and blending.
``engine.synthetic.studio`` is the harder studio: a real body and real motion capture, each
frame reconstructed from the volume with merged contacts, holes, fragments and noise.
"""

from engine.synthetic.body import Body, build_body
from engine.synthetic.capture import (
    SequenceSpec,
    animate,
    generate_sequence_data,
    make_sequence,
    unstructured_capture,
)
from engine.synthetic.motions import Motion, gait, jump, reach
from engine.synthetic.presets import PRESETS, Preset, get_preset
from engine.synthetic.skeleton import Skeleton

__all__ = [
    "Body", "build_body", "SequenceSpec", "animate", "generate_sequence_data", "make_sequence",
    "unstructured_capture", "Motion", "gait", "jump", "reach", "PRESETS", "Preset", "get_preset", "Skeleton",
]
