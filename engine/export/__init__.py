"""Exports of played clips: binary glTF, USD, and OBJ / PLY sequences (docs/exports.md).

``frames = play_clip(space, Clip(params={"speed": 1.5}, duration=10, rate=60))`` plays a clip
with the real-time player; ``write_export(path, frames, "glb")`` writes it in one of ``FORMATS``.
"""

from .clip import MAX_FRAMES, Clip, ClipError, ClipFrames, check_clip, parse_track, play_clip
from .formats import FORMATS, write_export

__all__ = ["Clip", "ClipError", "ClipFrames", "FORMATS", "MAX_FRAMES", "check_clip", "parse_track", "play_clip", "write_export"]
