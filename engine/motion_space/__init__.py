"""Motion spaces: blendable sources plus precomputed data in one `.mspace` file per space.

`container` stores JSON metadata plus named numpy arrays (docs/file-formats.md, "Motion space
files"); nothing is ever pickled. `build_motion_space` writes a space, `MotionSpace.open` maps it
and hands out linear, hybrid and non-linear blenders.
"""

from .container import (
    FORMAT_VERSION,
    Container,
    MissingArrayError,
    MotionSpaceError,
    inspect_container,
    write_container,
)
from .derived import DerivedStore
from .build import PreparedSources, SourceClip, build_motion_space, prepare_sources, warp_cycle_onto
from .space import MODES, MotionSpace

__all__ = [
    "FORMAT_VERSION",
    "Container",
    "MissingArrayError",
    "MotionSpaceError",
    "inspect_container",
    "write_container",
    "DerivedStore",
    "SourceClip",
    "build_motion_space",
    "PreparedSources",
    "prepare_sources",
    "warp_cycle_onto",
    "MODES",
    "MotionSpace",
]
