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

A studio photographs each frame under lights that stay where they are while the performer turns,
and exposes every frame a little differently: the same cloth is brighter facing the key light and
darker turned away (engine.synthetic.studio.lighting). With ``regions`` (a label per root vertex,
e.g. the aligner's coarse patches) the frame's colours are first divided by one brightness gain
per region, the ratio of the frame's colours there to the root's, so that light
and exposure do not read as disagreement; a patch that slid or turned still lands on another
part's pattern, which no single gain undoes.
"""

from __future__ import annotations

import numpy as np


GAIN_RANGE = (0.5, 2.0)   # a region's brightness gain is held within this range


def colour_gaps(V, colors, target, regions=None):
    """(n,) RGB distances between ``colors`` (the root's, (n, 3) in [0, 1]) and the target's
    colours where the aligned vertices ``V`` (n, 3) land (``target``: a TargetSurface with
    colours); with ``regions`` ((n,) int labels) the target's colours are first divided by each
    region's brightness gain (:func:`region_gains`)."""
    _, _, face = target.closest(V)
    there = target.colors[target.F[face]].mean(axis=1)
    if regions is not None:
        there = there / region_gains(there, colors, regions)[regions][:, None]
    return np.linalg.norm(there - colors, axis=1)


def region_gains(there, colors, regions):
    """(regions,) brightness gain from ``colors`` to ``there`` in each region: the ratio of their
    sums over its vertices and channels (blur, as in the root against its own faces, leaves it
    at 1), within ``GAIN_RANGE``; 1 for a region without colour."""
    count = int(regions.max()) + 1
    seen = np.bincount(regions, weights=there.sum(axis=1), minlength=count)
    own = np.bincount(regions, weights=colors.sum(axis=1), minlength=count)
    gains = np.divide(seen, own, out=np.ones(count), where=own > 1e-9)
    return np.clip(gains, *GAIN_RANGE)


def colour_distance(V, colors, target, regions=None):
    """Median of :func:`colour_gaps` (NaN when either side has no colours)."""
    if colors is None or target.colors is None:
        return float("nan")
    return float(np.median(colour_gaps(V, colors, target, regions)))


def colour_disagreement(V, colors, target, regions=None):
    """Mean of :func:`colour_gaps` (NaN when either side has no colours): a slid patch counts
    with its area, where the median would not see it until it covered half the body."""
    if colors is None or target.colors is None:
        return float("nan")
    return float(np.mean(colour_gaps(V, colors, target, regions)))


def colour_measures(V, colors, target, regions=None):
    """(:func:`colour_distance`, :func:`colour_disagreement`) from one look-up of where ``V`` lands."""
    if colors is None or target.colors is None:
        return float("nan"), float("nan")
    gaps = colour_gaps(V, colors, target, regions)
    return float(np.median(gaps)), float(np.mean(gaps))


def colour_floor(V, F, colors, regions=None):
    """:func:`colour_disagreement` of the root mesh against its own surface (NaN without colours):
    the texture's own variation within a face, the least an aligned frame can show."""
    if colors is None:
        return float("nan")
    from engine.align.matching import TargetSurface

    return colour_disagreement(V, colors, TargetSurface(V, F, colors), regions)


__all__ = ["GAIN_RANGE", "colour_disagreement", "colour_distance", "colour_floor", "colour_gaps", "colour_measures",
           "region_gains"]
