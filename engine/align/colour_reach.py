"""Matches that reach past the closest point to where the target shows the source's colour.

A closest-point match can only slide a patch along the surface it already touches. When a step
swings a limb far (guard to arms down, a punch thrown), the patches of the forearm fit the
belly they were left against and the target's forearm, a hand's width away, is covered by the
skirt: every closest point is close, every fit is good, and the hand stays where it was. The
colours say otherwise: the skin of the hand lands on the shirt, the dark inside of a bell
sleeve on the skirt's checks. The local colour cue (:func:`engine.align.matching.colour_flow`)
looks only among the few nearest target vertices, too near to cross that gap.

So on the coarsest levels (``AlignmentOptions.colour_reach_levels``) each match whose
*smoothed* colour (the mean over a vertex's ``SMOOTHING`` nearest vertices, so that noise and
shading average out; repeated on denser surfaces so that it spans the same few centimetres,
:func:`smoothing_passes`) disagrees with the source's by more than ``GAP`` also
looks for the target vertex nearest in position and smoothed colour together: a 6-D nearest
neighbour, colour scaled by ``AlignmentOptions.colour_reach`` times the root's model size, so
that at 0.18 a colour 0.1 apart weighs as 3 cm at 1.7 m. That vertex replaces the closest point
when its joint squared distance is under ``BETTER`` times the closest point's, as a point-to-point
pull, if that vertex's own smoothed colour agrees (within ``AGREE``). Root vertices on a
pattern (their neighbours' colours spread over ``SPREAD``: checks, stripes) do not reach: their
smoothed colour is found again a stripe away. The patches' rigid steps and the solid's
stiffness keep the pulls coherent; the finer levels and the per-vertex rounds then fit the
surface closely as before.

The target's colours are first brought to the source's exposure with one gain per frame (the
ratio of the sums at the current matches, held within ``GAIN_RANGE``). On the studio's
martial-arts take sampled one frame in 9 it cut the mean error from 1.69% to 1.45% of the
model size (the sleeves' from 3.33% and 6.28% to 1.98% and 5.10%); dense slices were even
(docs/alignment.md, step 6; docs/evaluation.md, "Matches that reach for the colour").
"""

from __future__ import annotations

import numpy as np

from engine.align.appearance import GAIN_RANGE
from engine.nearest import PointTree
from engine.surface import surface_area

SMOOTHING = 24   # vertices averaged into a vertex's smoothed colour (about 3-4 cm on a 10k-vertex body)
GAP = 0.15       # smoothed RGB distance at the closest point above which a match looks further
AGREE = 0.15     # ... and its smoothed colour is within this distance of the source's
BETTER = 0.5     # a colour match is taken when its joint squared distance is below this share of the closest point's
SPREAD = 0.2     # a root vertex whose neighbours' colours spread more than this is patterned: it does not reach
WEIGHT = 0.5     # the least robust weight of a match so taken
DENSITY = 8000   # vertices per model size squared of surface where one pass of SMOOTHING spans 3-4 cm (the studio's 10k)


def smoothing_passes(V, F, size):
    """How many times :func:`smoothed_colours` averages over the nearest ``SMOOTHING`` vertices
    so that the smoothing spans about the same share of the body whatever the surface's
    density: one at up to 1.5 times ``DENSITY`` vertices per ``size`` squared of surface (the
    studio's 10k-vertex frames, where 24 neighbours reach about 4 cm), five on a 50k-vertex
    capture of the same body. Each pass widens the averaging as a diffusion does: p passes of
    k neighbours at p times the density spread as far as one pass at the density.

    Parameters
    ----------
    V, F : the surface       size : float   the root's model size (the same for source and target)
    """
    area = surface_area(V, F)
    if not area > 0:
        return 1
    return max(1, int(round(len(V) * float(size) ** 2 / area / DENSITY)))


def smoothed_colours(V, colors, k=SMOOTHING, spread=False, passes=1):
    """(n, 3) mean colour of each vertex's ``k`` nearest vertices (itself included), that mean
    taken ``passes`` times over; with ``spread`` also (n,) the RMS distance of the colours so
    averaged from their mean (a pattern's stripes or checks: large; a plain cloth or skin:
    small)."""
    V = np.asarray(V, dtype=np.float64)
    colors = np.asarray(colors, dtype=np.float64)
    n, k = len(V), min(int(k), len(V))
    index = PointTree(V).query(V, k=k)[1].reshape(n, k)
    near = colors[index]
    mean = near.mean(axis=1)
    passes = max(1, int(passes))
    if passes == 1:   # summed as before passes existed: 10k-vertex alignments keep their bits
        if not spread:
            return mean
        return mean, np.sqrt(np.mean(np.sum((near - mean[:, None]) ** 2, axis=2), axis=1))
    import scipy.sparse as sp

    average = sp.csr_matrix((np.full(n * k, 1.0 / k), index.ravel(), np.arange(0, n * k + 1, k)), shape=(n, n))
    both = np.hstack([mean, np.mean(np.sum(near ** 2, axis=2), axis=1)[:, None]])   # colour, squared norm
    for _ in range(passes - 1):
        both = average @ both
    mean = both[:, :3]
    if not spread:
        return mean
    return mean, np.sqrt(np.maximum(both[:, 3] - np.sum(mean ** 2, axis=1), 0.0))


def reach_colours(V, colors, passes=1):
    """The root's colours as :func:`reach_for_colour` reads them: smoothed, and NaN where the
    surface is patterned (spread over ``SPREAD``), whose smoothed colour repeats every stripe."""
    mean, spread = smoothed_colours(V, colors, spread=True, passes=passes)
    mean[spread > SPREAD] = np.nan
    return mean


def target_colour_tree(target, scale, size=None):
    """The target's vertices in 6-D (position, ``scale`` x smoothed colour) as a PointTree, made
    once per target and scale (kept on the target, with its smoothed colours: smoothed as often
    as :func:`smoothing_passes` says for the root's model size ``size``, once without it)."""
    cache = target.__dict__.setdefault("_colour_reach", {})
    if "smoothed" not in cache:
        passes = 1 if size is None else smoothing_passes(target.V, target.F, size)
        cache["smoothed"] = smoothed_colours(target.V, target.colors, passes=passes)
    key = round(float(scale), 12)
    if key not in cache:
        cache[key] = PointTree(np.hstack([target.V, scale * cache["smoothed"]]))
    return cache["smoothed"], cache[key]


def reach_for_colour(x, y, m, w, tangential, target, source, scale, size=None):
    """Replace matches whose colour disagrees with the nearest target vertex in position and colour.

    Parameters
    ----------
    x : (p, 3) source points          y, m : (p, 3) their closest target points and normals
    w, tangential : (p,)              robust and tangential weights (changed in place)
    target : TargetSurface with colours
    source : (p, 3) the source points' smoothed colours (the root's)
    scale : float                     metres per unit of RGB distance
    size : float or None              the root's model size (sets the target's smoothing passes)

    Returns
    -------
    y, m : new arrays (the replaced rows changed)      replaced : (p,) bool
    """
    smoothed, tree = target_colour_tree(target, scale, size)
    replaced = np.zeros(len(x), dtype=bool)
    plain = np.isfinite(source[:, 0])
    if not plain.any():
        return y, m, replaced
    near = target.tree.query(y, k=1)[1]
    there = smoothed[near]
    gain = np.clip(there[plain].sum(axis=0) / np.maximum(source[plain].sum(axis=0), 1e-9), *GAIN_RANGE)
    source = np.clip(source * gain, 0.0, 1.0)
    gap = np.linalg.norm(there - source, axis=1)
    look = np.flatnonzero(plain & (gap > GAP))
    if len(look) == 0:
        return y, m, replaced
    joint, vertex = tree.query(np.hstack([x[look], scale * source[look]]), k=1)
    closest = np.sum((x[look] - y[look]) ** 2, axis=1) + (scale * gap[look]) ** 2
    agrees = np.linalg.norm(smoothed[vertex] - source[look], axis=1) <= AGREE
    better = agrees & (joint ** 2 < BETTER * closest)
    take, vertex = look[better], vertex[better]
    replaced[take] = True
    y, m = y.copy(), m.copy()
    y[take], m[take] = target.V[vertex], target.normals[vertex]
    w[take] = np.maximum(w[take], WEIGHT)
    tangential[take] = 1.0
    return y, m, replaced


__all__ = ["AGREE", "BETTER", "DENSITY", "GAP", "SMOOTHING", "SPREAD", "WEIGHT", "reach_colours", "reach_for_colour",
           "smoothed_colours", "smoothing_passes", "target_colour_tree"]
