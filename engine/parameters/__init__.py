"""High-level parameters of a motion space: measured on blends, inverted to blend weights.

Paper section 4.3: w = h^-1(p) from a discrete sampling of the weight space and the parameters
measured on each blend. Here the weights come from a *layout*, a low-dimensional sheet through
the weight simplex with coordinates u in [0, 1]^d (d = 1 or 2):

- ``chain``: sources ordered along one parameter (slow walk, walk, jog, run); u moves along
  the chain, blending neighbours;
- ``grid``: four corner sources of a 2-D parameter (jump height x distance); bilinear;
- ``fan``: speed x direction (the paper's fig. 8): a speed chain of straight gaits blended with
  a left and a right turn; u = (speed along the chain, direction from right (0) to left (1)).

The parameters of the blend at each u on a grid are measured on the blended motion itself
(``measure_parameters``); ``ParameterMap.solve(p)`` inverts by Gauss-Newton on the interpolated
map starting from the nearest sample, and clamps an unreachable request to the nearest reachable
parameters, saying so.
"""

from __future__ import annotations

from .layout import MEASURES, Layout
from .root_track import RootTrack
from .measure import accuracy_report, measure_parameters
from .parameter_map import ParameterMap, Solution

__all__ = ["MEASURES", "Layout", "RootTrack", "measure_parameters", "accuracy_report", "ParameterMap", "Solution"]
