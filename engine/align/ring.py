"""Rigid starts from a ring of placements: the body laid along the target's long axis, turned about it.

The pairwise aligner's rigid start (:meth:`engine.align.pairwise.PairwiseAligner._rigid_starts`)
turns the source about the vertical only: by the shape histograms' hint, or not at all. That
holds for a body that stays upright and turns a little between two frames. It fails where the
step is large: a dancer who goes down onto the floor (the body pitched 60-70 degrees onto its
hands), or frames far apart in time whose facing the hint gets wrong. From such a start the
non-rigid search stays in the wrong basin (docs/evaluation.md, "Where the sparse takes still
fail").

The ring lays the source's long axis (the principal axis of its vertices) along the target's,
both ways round, at ``RING_TURNS`` turns about that axis, refines each placement by the same
point-to-plane ICP as the upright start, and scores it the way the upright start's placement is
scored: by how well the root's colours agree with the target's where the samples land (with
colours on both), else by the fit. When the best placement of the ring scores clearly better
than the upright one (below ``options.ring_margin`` of its score) and faces another way (more
than ``RING_APART`` degrees), the aligner aligns from it too, and keeps the better result
(:meth:`engine.align.pairwise.PairwiseAligner._orientation_score`). The ring's 16 refinements cost
about a quarter of a pairwise alignment at 10k vertices, so it runs only where the upright
placement fits poorly (``RING_FROM``); between neighbouring frames it fits well, and where it
does not, the ring's best is usually the upright placement itself.
"""

from __future__ import annotations

import numpy as np

from engine.align.appearance import colour_distance
from engine.align.matching import nearest_compatible
from engine.align.rigid import point_to_plane_step, rodrigues

RING_TURNS = 8      # placements about the long axis, each way round
RING_APART = 20.0   # degrees: a ring placement this close to the upright one adds nothing
RING_FROM = 0.01    # the ring runs when the upright placement's fit (placement_fit) is above this share of
                    # the model size: neighbouring frames 0.2-0.4%, the dance's spin 1.1%, frames on the floor 2-3%


def refine_placement(P, N, R, t, target, options):
    """Point-to-plane ICP of sample points P (normals N) on the target from the placement (R, t).

    ``options.rigid_iterations`` steps on the nearest compatible target vertices, outliers beyond
    ``options.outlier_factor`` times the median distance (at least two target edges) left out.
    Returns the refined (R, t)."""
    o = options
    for _ in range(o.rigid_iterations):
        placed = P @ R.T + t
        q, m, d, ok = nearest_compatible(placed, N @ R.T, target, o)
        limit = max(o.outlier_factor * np.median(d[ok]) if ok.any() else np.inf, 2 * target.edge_length)
        w = (ok & (d < limit)).astype(float)
        if w.sum() < 6:
            break
        dR, dt = point_to_plane_step(placed, q, m, w)
        R, t = dR @ R, dR @ t + dt
    return R, t


def placement_fit(placed, target):
    """How far placed sample points lie from the target: the mean distance, each capped at the
    90th percentile (a limb that moved does not decide the placement of the rest)."""
    d = target.closest(placed)[1]
    return float(np.mean(np.minimum(d, np.percentile(d, 90))))


def placement_score(placed, colours, target):
    """A placement's score, lower is better: the median RGB distance between the samples' root
    colours and the target's where they land, with colours on both; else :func:`placement_fit`."""
    if colours is None or target.colors is None:
        return placement_fit(placed, target)
    return colour_distance(placed, colours, target)


def long_axis(P):
    """The unit direction of largest spread of points P (n, 3) (its sign is arbitrary)."""
    centred = P - P.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    return vectors[:, -1]


def turn_onto(a, b):
    """The rotation (3, 3) by the smallest angle that takes unit vector ``a`` onto unit vector ``b``."""
    axis = np.cross(a, b)
    sine, cosine = float(np.linalg.norm(axis)), float(a @ b)
    if sine > 1e-9:
        return rodrigues((axis / sine * np.arctan2(sine, cosine))[None])[0]
    if cosine > 0:
        return np.eye(3)
    other = np.eye(3)[int(np.argmin(np.abs(a)))]   # a half turn about any axis across a
    across = np.cross(a, other)
    return rodrigues((np.pi * across / np.linalg.norm(across))[None])[0]


def ring_start(P, N, centre, target, options, colours, upright):
    """The ring's best rigid placement when it beats the upright one clearly, else None.

    Parameters
    ----------
    P, N : (s, 3) float arrays     sample points of the source surface and their normals
    centre : (3,) float array      the source's centre (placed on the target's)
    target : TargetSurface
    options : AlignmentOptions     ``rigid_iterations``, ``outlier_factor``, ``ring_margin``
    colours : (s, 3) float array or None   the samples' root colours
    upright : (R, t)               the upright start's refined placement

    Returns
    -------
    (R, t) or None
    """
    upright_score = placement_score(P @ upright[0].T + upright[1], colours, target)
    source_axis, target_axis = long_axis(P), long_axis(target.V)
    best = None
    for way in (1.0, -1.0):
        laid = turn_onto(source_axis, way * target_axis)
        for k in range(RING_TURNS):
            R = rodrigues((target_axis * (2.0 * np.pi * k / RING_TURNS))[None])[0] @ laid
            R, t = refine_placement(P, N, R, target.centre - R @ centre, target, options)
            score = placement_score(P @ R.T + t, colours, target)
            if best is None or score < best[0]:
                best = (score, R, t)
    if best is None or not best[0] < options.ring_margin * upright_score:
        return None
    cosine = (np.trace(best[1] @ upright[0].T) - 1.0) / 2.0
    if np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))) <= RING_APART:
        return None
    return best[1], best[2]


__all__ = ["RING_APART", "RING_FROM", "RING_TURNS", "long_axis", "placement_fit", "placement_score", "refine_placement",
           "ring_start", "turn_onto"]
