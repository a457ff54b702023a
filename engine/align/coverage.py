"""Limbs swung onto the parts of the target that nothing covers.

A patch is matched to the nearest surface that fits. When a limb moved far between the source
and the target (an arm thrown into a punch, a leg into a kick), its patches find the body's
surface beside them and fit it well, so nothing tells them they are wrong, while the target's
arm stands out with no source surface near it: after the coarsest level's rounds about a tenth
of the studio strikes' target was more than 10 cm from the aligned source in such a frame.
Neither the patches' own fit nor the articulated search for badly fitting patches
(:func:`engine.align.patches.search_patches`) sees that. :func:`cover_uncovered` does: it
finds the target's uncovered regions, and tries swinging a limb onto each (a patch and the
patches on its side of its joint with a neighbour, rotated about that joint so that it points
at the region, then refined by ICP as one rigid piece). A swing is kept when it covers much of the
region, fits it well, and uncovers little that the limb covered before.

Used when ``AlignmentOptions.swing_limbs`` is on (``--swing-limbs``; off by default): on bodies
in tight clothes it cuts a sparse take's error by a fifth to a quarter, on the studio's loose
skirt and bell sleeves it is mixed and costs up to twice the CPU (docs/alignment.md, "Limbs
swung onto what nothing covers").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, shortest_path

from engine.align.matching import sample_cost
from engine.align.patches import border_points, patch_members, refine_hypotheses
from engine.align.rigid import rodrigues
from engine.nearest import PointTree

UNCOVERED = 2.0       # a target sample farther than this many search caps from the source is uncovered
REGION_SHARE = 0.02   # an uncovered region must hold this share of the target samples
LIMB_SHARE = 0.3      # a limb is at most this share of the root's vertices
REGIONS = 3           # the largest uncovered regions tried per round
KEEP_COVER = 0.4      # a swing must cover this share of its region ...
KEEP_FIT = 0.3        # ... with a mean fit cost at most this (1: every sample unmatched)
STAY_MARGIN = 0.15    # a patch of the limb whose fit cost the swing raises by more stays where it is


def _limbs(pairs, count, sizes, centres, reach):
    """Every (patch, neighbour) joint's limb: the patch and the patches on its side of the joint.

    On its side are the patches within ``reach`` of the joint (the centre of the two patches'
    border, here the midpoint of their centres) that are fewer steps from ``p`` than from ``q``
    in the patch graph. (Taking the patches beyond the joint in the graph's topology does not
    work on a body: loose garments and merged contacts join almost every patch to the rest by
    another way round.) A limb holds at most ``LIMB_SHARE`` of the vertices; else it is ``p``
    alone.

    Returns a list of (p, q, pair, patches) for both directions of every adjacent pair
    (``pair``: its row in ``pairs``).
    """
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(count, count))
    hops = shortest_path(graph, directed=False, unweighted=True)
    out = []
    total = float(sizes.sum())
    for pair, (p, q) in zip(np.tile(np.arange(len(pairs)), 2), np.concatenate([pairs, pairs[:, ::-1]])):
        c = 0.5 * (centres[p] + centres[q])
        limb = np.flatnonzero((hops[p] < hops[q]) & (np.linalg.norm(centres - c, axis=1) <= reach))
        if p not in limb or sizes[limb].sum() > LIMB_SHARE * total:
            limb = np.array([p])
        out.append((int(p), int(q), int(pair), limb))
    return out


def point_regions(points, radius):
    """Connected regions of ``points`` (neighbours within ``radius``): a list of index arrays."""
    if len(points) == 0:
        return []
    k = min(8, len(points))
    d, idx = PointTree(points).query(points, k=k)
    d, idx = d.reshape(len(points), k), idx.reshape(len(points), k)
    rows = np.repeat(np.arange(len(points)), k)
    near = d.ravel() <= radius
    graph = sp.coo_matrix((np.ones(int(near.sum())), (rows[near], idx.ravel()[near])),
                          shape=(len(points), len(points)))
    n, label = connected_components(graph, directed=False)
    regions = [np.flatnonzero(label == r) for r in range(n)]
    return sorted(regions, key=len, reverse=True)


def _turn(a, b):
    """The smallest rotation taking direction ``a`` to direction ``b`` (3, 3)."""
    a, b = a / max(np.linalg.norm(a), 1e-12), b / max(np.linalg.norm(b), 1e-12)
    axis = np.cross(a, b)
    angle = np.arctan2(np.linalg.norm(axis), float(a @ b))
    return rodrigues((axis / max(np.linalg.norm(axis), 1e-12) * angle)[None])[0]


def limbs_of(V, adjacency, labels, count):
    """:func:`_limbs` of a level's patches on the root's vertices ``V`` (``patch_adjacency``,
    the labels and their count), with a reach of a third of the model size (an arm or a leg)."""
    sizes = np.bincount(labels, minlength=count).astype(float)
    centres = np.stack([np.bincount(labels, weights=V[:, a], minlength=count) for a in range(3)], axis=1)
    centres /= np.maximum(sizes, 1.0)[:, None]
    reach = np.max(np.ptp(V, axis=0)) / 3.0
    return _limbs(adjacency[0], count, sizes, centres, reach)


def cover_uncovered(x, n, target, labels, count, sampled, adjacency, limbs, options, samples=2000):
    """Swing limbs onto the target's uncovered regions (see the module's docstring).

    Parameters
    ----------
    x, n : (n, 3) float arrays       source surface positions and normals after this round's ICP
    target : TargetSurface
    labels, count : the patch of every vertex at this level, and the number of patches
    sampled : (indices, patch)       :func:`engine.align.patches.patch_samples` of this level
    adjacency : (pairs, border)      :func:`engine.align.patches.patch_adjacency` of this level
    limbs : list of (p, q, pair, patches)   :func:`limbs_of` this level
    options : AlignmentOptions
    samples : int                    about this many target vertices (every m-th) are measured

    Returns
    -------
    x, n : (n, 3) float arrays   with the swung limbs moved
    """
    o = options
    far = UNCOVERED * o.search_cap
    target_samples = target.V[::max(1, len(target.V) // samples)]
    k = 16
    d, idx = PointTree(x).query(target_samples, k=k)
    d, idx = d.reshape(len(target_samples), k), idx.reshape(len(target_samples), k)
    uncovered = np.flatnonzero(d[:, 0] > far)
    regions = [r for r in point_regions(target_samples[uncovered], far) if len(r) >= REGION_SHARE * len(target_samples)]
    if not regions or not limbs:
        return x, n
    members = patch_members(sampled, count)
    _, joint, _ = border_points(x, adjacency)
    near = d <= far
    covered_by = np.where(near, labels[idx], -1)  # each sample's near source patches (-1: too far)
    samples_of = np.concatenate(members)
    fit_now = np.bincount(np.repeat(np.arange(count), [len(m) for m in members]),
                          weights=sample_cost(x[samples_of], n[samples_of], target, o), minlength=count)
    fit_now /= np.maximum([len(m) for m in members], 1)  # each patch's fit cost where it is
    x, n = x.copy(), n.copy()
    for region in regions[:REGIONS]:
        U = target_samples[uncovered[region]]
        centre = U.mean(axis=0)
        hyp, R0, t0, pts, nrm, owner = [], [], [], [], [], []
        for p, q, pair, limb in limbs:
            c = joint[pair]
            own = np.concatenate([members[m] for m in limb])
            if len(own) < 3:
                continue
            reach = np.linalg.norm(x[own] - c, axis=1)
            if np.linalg.norm(centre - c) > reach.max() + far:
                continue
            R = _turn(x[own].mean(axis=0) - c, centre - c)
            hyp.append(limb)
            R0.append(R)
            t0.append(c - R @ c)
            pts.append(x[own] @ R.T + t0[-1])
            nrm.append(n[own] @ R.T)
            owner.append(np.full(len(own), len(hyp) - 1))
        if not hyp:
            continue
        H = len(hyp)
        owner = np.concatenate(owner)
        R_h, t_h, _ = refine_hypotheses(np.concatenate(pts), np.concatenate(nrm), owner, H, np.array(R0),
                                        np.array(t0), target, o)
        best, best_gain = None, 0.0
        for h, limb in enumerate(hyp):
            # a patch of the limb that fitted where it was and does not where the swing takes it
            # (a skirt panel beside the hanging arm) stays
            stays = []
            for m in limb:
                after = sample_cost(x[members[m]] @ R_h[h].T + t_h[h], n[members[m]] @ R_h[h].T, target, o).mean()
                stays.append(after > max(fit_now[m] + STAY_MARGIN, KEEP_FIT))
            limb = hyp[h] = limb[~np.array(stays, dtype=bool)]
            if len(limb) == 0:
                continue
            own = np.concatenate([members[m] for m in limb])
            moved = x[own] @ R_h[h].T + t_h[h]
            if sample_cost(moved, n[own] @ R_h[h].T, target, o).mean() > KEEP_FIT:
                continue
            gained = np.mean(PointTree(moved).query(U, k=1)[0] <= far)
            if gained < KEEP_COVER:
                continue
            # samples the limb alone covered now, which it leaves
            in_limb = np.isin(covered_by, limb) & near
            alone = np.any(in_limb, axis=1) & ~np.any(near & ~in_limb, axis=1)
            lost = 0.0
            if alone.any():
                lost = np.mean(PointTree(moved).query(target_samples[alone], k=1)[0] > far) * alone.sum()
            gain = gained * len(U) - lost
            if gain > best_gain and gain >= KEEP_COVER * len(U):
                best, best_gain = h, gain
        if best is None:
            continue
        vertices = np.flatnonzero(np.isin(labels, hyp[best]))
        x[vertices] = x[vertices] @ R_h[best].T + t_h[best]
        n[vertices] = n[vertices] @ R_h[best].T
    return x, n


__all__ = ["cover_uncovered", "limbs_of", "point_regions"]
