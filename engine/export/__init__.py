"""Exports of played clips: binary glTF, USD, and OBJ / PLY sequences (docs/exports.md).

``frames = play_clip(space, Clip(params={"speed": 1.5}, duration=10, rate=60))`` plays a clip
with the real-time player; ``write_export(path, frames, "glb")`` writes it in one of ``FORMATS``.
``frames, digest = play_performance(graph, recording)`` replays a recorded motion-graph
performance into the same kind of frames.
"""

from .clip import MAX_FRAMES, Clip, ClipError, ClipFrames, check_clip, parse_track, play_clip
from .formats import FORMATS, write_export
from .performance import check_performance, play_performance, scripted_recording

__all__ = ["Clip", "ClipError", "ClipFrames", "FORMATS", "MAX_FRAMES", "check_clip", "parse_track", "play_clip", "write_export",
           "check_performance", "play_performance", "scripted_recording"]
