"""Procedural motions with physical parameters: gaits (walk, jog, run, turns), jumps, reaches.

Each generator returns a ``Motion``: joint transforms per frame plus the root trajectory, the
requested parameters and key events. Everything is a function of time, so a cyclic motion is
exactly periodic in its root frame: frame k + N equals frame k moved by one cycle's root motion.

Conventions: Y up, the character starts at the origin facing +Z, its left is +X; headings are
radians about +Y (positive = turning left); angles in user-facing parameters are degrees.

The generators live in ``gaits``, ``jumps`` and ``reaches``; what they share (``Motion``, the
stance constants, torso, arm and standing poses) in ``motion_base``. This module gathers them.
"""

from engine.synthetic.gaits import GaitParameters, gait
from engine.synthetic.jumps import jump
from engine.synthetic.motion_base import GRAVITY, STANCE_WIDTH, STAND_PELVIS, Motion
from engine.synthetic.reaches import reach

__all__ = ["GRAVITY", "STANCE_WIDTH", "STAND_PELVIS", "GaitParameters", "Motion", "gait", "jump", "reach"]
