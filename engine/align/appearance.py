"""How well an aligned frame's appearance agrees with the root's: the colours where it landed.

Every aligned frame carries the root's vertex colours to where its vertices landed on the frame's
surface. Where the correspondence holds, the frame's own colours there are the root's (up to the
reconstruction's colour noise and resampling); where a patch slid or a body turned, they are
another part's. The disagreement is anchored to the root, not to the parent, so it sees what a
frame inherited along its tree path as well as what its own step added, which the fit and the
solid's distortion cannot (docs/evaluation.md, "A confidence that reads the colours").

- :func:`colour_gaps`: per vertex, the RGB distance between the root's colour and the frame's
  colour where the vertex landed (the closest face's corner colours averaged).
- :func:`colour_distance` (median) decides between orientations and among repair results.
- :func:`colour_disagreement` (mean) is what a frame's confidence reads, against
  :func:`colour_floor`: the same measure for the root against its own surface, which is what a
  perfect alignment shows with this texture at this mesh resolution.
"""

from __future__ import annotations

import numpy as np


def colour_gaps(V, colors, target):
    """(n,) RGB distances between ``colors`` (the root's, (n, 3) in [0, 1]) and the target's
    colours where the aligned vertices ``V`` (n, 3) land (``target``: a TargetSurface with colours)."""
    _, _, face = target.closest(V)
    there = target.colors[target.F[face]].mean(axis=1)
    return np.linalg.norm(there - colors, axis=1)


def colour_distance(V, colors, target):
    """Median of :func:`colour_gaps` (NaN when either side has no colours)."""
    if colors is None or target.colors is None:
        return float("nan")
    return float(np.median(colour_gaps(V, colors, target)))


def colour_disagreement(V, colors, target):
    """Mean of :func:`colour_gaps` (NaN when either side has no colours): a slid patch counts
    with its area, where the median would not see it until it covered half the body."""
    if colors is None or target.colors is None:
        return float("nan")
    return float(np.mean(colour_gaps(V, colors, target)))


def colour_measures(V, colors, target):
    """(:func:`colour_distance`, :func:`colour_disagreement`) from one look-up of where ``V`` lands."""
    if colors is None or target.colors is None:
        return float("nan"), float("nan")
    gaps = colour_gaps(V, colors, target)
    return float(np.median(gaps)), float(np.mean(gaps))


def colour_floor(V, F, colors):
    """:func:`colour_disagreement` of the root mesh against its own surface (NaN without colours):
    the texture's own variation within a face, the least an aligned frame can show."""
    if colors is None:
        return float("nan")
    from engine.align.matching import TargetSurface

    return colour_disagreement(V, colors, TargetSurface(V, F, colors))


__all__ = ["colour_disagreement", "colour_distance", "colour_floor", "colour_gaps", "colour_measures"]
