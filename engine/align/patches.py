"""Surface patches of the root mesh for coarse-to-fine matching (Casas et al. 2012, 3.2).

Nested partitions by farthest-point sampling (about 30 patches, doubling per level), the
patches' adjacency and sample vertices, and the articulated search that lets a badly fitting
patch try rotations about its joint with a neighbour.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from engine.align.matching import nearest_compatible, sample_cost
from engine.align.rigid import patch_rigid_steps, rodrigues


def farthest_point_patches(V, F, counts, *, seed=0):
    """Nested surface partitions by farthest-point sampling over mesh-edge (geodesic) distance.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array
    counts : sequence of int    patch counts, increasing
    seed : int                  chooses the first sample

    Returns
    -------
    labels : list of (n,) int arrays   the patch of every vertex, one array per count
    """
    V = np.asarray(V, dtype=np.float64)
    n = len(V)
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    length = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1) + 1e-12
    graph = sp.csr_matrix((length, (edges[:, 0], edges[:, 1])), shape=(n, n))
    graph = graph.maximum(graph.T).tocsr()
    rng = np.random.default_rng(seed)
    most = min(int(max(counts)), n)
    seeds = [int(rng.integers(n))]
    nearest = dijkstra(graph, indices=seeds[0])
    nearest[~np.isfinite(nearest)] = np.inf
    # Unreachable parts (several components) are reached by restarting there.
    while len(seeds) < most:
        gap = np.where(np.isfinite(nearest), nearest, np.inf)
        candidate = int(np.argmax(gap))
        seeds.append(candidate)
        nearest = np.minimum(nearest, dijkstra(graph, indices=candidate))
    labels = []
    for count in counts:
        count = min(int(count), n)
        _, _, source = dijkstra(graph, indices=seeds[:count], min_only=True, return_predecessors=True)
        label_of = {s: i for i, s in enumerate(seeds[:count])}
        labels.append(np.array([label_of.get(int(s), 0) for s in source], dtype=np.int64))
    return labels


def patch_adjacency(F, labels, count):
    """Adjacent patch pairs and their border vertices.

    Returns
    -------
    pairs : (e, 2) int array          patch pairs (a < b) that share mesh edges
    border : (b, 3) int array         (vertex, its patch, pair index): vertices on a shared border
    """
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    la, lb = labels[edges[:, 0]], labels[edges[:, 1]]
    cut = la != lb
    a, b = np.minimum(la[cut], lb[cut]), np.maximum(la[cut], lb[cut])
    code = a * count + b
    unique, pair_of = np.unique(code, return_inverse=True)
    pairs = np.stack([unique // count, unique % count], axis=1)
    verts = np.concatenate([edges[cut, 0], edges[cut, 1]])
    pair_index = np.concatenate([pair_of, pair_of])
    border = np.unique(np.stack([verts, labels[verts], pair_index], axis=1), axis=0)
    return pairs.astype(np.int64), border.astype(np.int64)


def patch_samples(labels, count, per_patch, rng):
    """Up to ``per_patch`` random vertices of every patch: (indices, their patch)."""
    chosen = []
    for p in range(count):
        members = np.flatnonzero(labels == p)
        if len(members) > per_patch:
            members = np.sort(rng.choice(members, size=per_patch, replace=False))
        chosen.append(members)
    idx = np.concatenate(chosen)
    return idx, labels[idx]


def search_patches(x, n, target, labels, count, sampled, adjacency, rotations, options):
    """Articulated hypotheses for every patch; the best fitting one (after ICP) wins.

    Hypotheses: the current pose and rotations about the joint with the
    best-fitting neighbour (the centre of their shared border) by the search angles about
    the three axes. Each is refined by point-to-plane ICP on a few samples and scored by
    its capped fit cost plus how far it tears the joint open.

    Parameters
    ----------
    x, n : (n, 3) float arrays   surface positions and normals after this round's patch ICP
    target : TargetSurface
    labels : (n,) int array      the patch of every vertex at this level, ``count`` patches
    sampled : (indices, patch)   :func:`patch_samples` of this level
    adjacency : (pairs, border)  :func:`patch_adjacency` of this level
    rotations : (r, 3, 3) float array   rotations tried about a joint (:func:`rotation_set`)
    options : AlignmentOptions

    Returns
    -------
    x, n : (n, 3) float arrays   with the patches whose best hypothesis won moved
    """
    o = options
    samples, sample_patch = sampled
    pairs, border = adjacency
    cost = np.bincount(sample_patch, weights=sample_cost(x[samples], n[samples], target, o),
                       minlength=count) / np.maximum(np.bincount(sample_patch, minlength=count), 1)
    bad = np.flatnonzero(cost > 0.05)
    if len(bad) == 0 or len(pairs) == 0:
        return x, n
    # joints: the centre of each shared border, at the current positions
    joint = np.stack([np.bincount(border[:, 2], weights=x[border[:, 0], a], minlength=len(pairs))
                      for a in range(3)], axis=1) / np.maximum(np.bincount(border[:, 2], minlength=len(pairs)), 1)[:, None]
    hyp_patch, hyp_R, hyp_c = [], [], []
    for p in bad:
        touching = np.flatnonzero((pairs[:, 0] == p) | (pairs[:, 1] == p))
        if len(touching) == 0:
            continue
        other = np.where(pairs[touching, 0] == p, pairs[touching, 1], pairs[touching, 0])
        anchor = touching[np.argmin(cost[other])]
        hyp_patch.append(np.full(len(rotations) + 1, p))
        hyp_R.append(np.concatenate([np.eye(3)[None], rotations]))
        hyp_c.append(np.repeat(joint[anchor][None], len(rotations) + 1, axis=0))
    if not hyp_patch:
        return x, n
    hyp_patch = np.concatenate(hyp_patch)
    hyp_R = np.concatenate(hyp_R)
    hyp_c = np.concatenate(hyp_c)
    H = len(hyp_patch)
    members = patch_members(sampled, count)  # sample points of each hypothesis
    idx = np.concatenate([members[p] for p in hyp_patch])
    owner = np.repeat(np.arange(H), [len(members[p]) for p in hyp_patch])
    P = np.einsum("pij,pj->pi", hyp_R[owner], x[idx] - hyp_c[owner]) + hyp_c[owner]
    N = np.einsum("pij,pj->pi", hyp_R[owner], n[idx])
    R_total, t_total, score = refine_hypotheses(P, N, owner, H, hyp_R.copy(),
                                                hyp_c - np.einsum("hij,hj->hi", hyp_R, hyp_c), target, o)
    tear = np.linalg.norm(np.einsum("hij,hj->hi", R_total, hyp_c) + t_total - hyp_c, axis=1)
    score += (tear / o.search_cap) ** 2 * 0.25
    x, n = x.copy(), n.copy()
    for p in np.unique(hyp_patch):
        mine = np.flatnonzero(hyp_patch == p)
        best = mine[np.argmin(score[mine])]
        if best == mine[0] or score[best] > cost[p] - 0.02:
            continue  # the current pose (refined) is as good
        vertices = np.flatnonzero(labels == p)
        x[vertices] = x[vertices] @ R_total[best].T + t_total[best]
        n[vertices] = n[vertices] @ R_total[best].T
    return x, n


def border_points(x, graph):
    """(pairs, border point, spread) of adjacent patches: the mean of their shared border
    vertices at positions ``x`` and those vertices' rms distance from it (at least 1 mm)."""
    pairs, border = graph
    e = len(pairs)
    vertex, pair = border[:, 0], border[:, 2]
    counts = np.maximum(np.bincount(pair, minlength=e), 1).astype(float)
    points = np.stack([np.bincount(pair, weights=x[vertex, a], minlength=e) for a in range(3)], axis=1)
    points /= counts[:, None]
    d2 = np.sum((x[vertex] - points[pair]) ** 2, axis=1)
    spread = np.sqrt(np.maximum(np.bincount(pair, weights=d2, minlength=e) / counts, 1e-6))
    return pairs, points, spread


def refine_hypotheses(P, N, owner, H, R_total, t_total, target, o):
    """Three point-to-plane ICP steps of ``H`` rigid hypotheses at once, each moving the sample
    points ``P``, ``N`` it ``owner``s; their steps composed onto ``R_total``, ``t_total``.

    Returns (R_total, t_total, score): the refined transforms and each hypothesis's mean fit
    cost (:func:`engine.align.matching.sample_cost`) at its refined pose.
    """
    for _ in range(3):
        q, m, d, ok = nearest_compatible(P, N, target, o)
        w = (ok & (d < 2 * o.search_cap)).astype(float)
        omega, shift, centres = patch_rigid_steps(P, q, m, w, np.full(len(P), o.tangential_damping), owner, H)
        Rs = rodrigues(omega)
        P = np.einsum("pij,pj->pi", Rs[owner], P - centres[owner]) + centres[owner] + shift[owner]
        N = np.einsum("pij,pj->pi", Rs[owner], N)
        # compose: x -> Rs (R x + t - c) + c + s
        t_total = np.einsum("hij,hj->hi", Rs, t_total - centres) + centres + shift
        R_total = Rs @ R_total
    score = np.bincount(owner, weights=sample_cost(P, N, target, o), minlength=H)
    return R_total, t_total, score / np.maximum(np.bincount(owner, minlength=H), 1)


def patch_members(sampled, count):
    """Each patch's sample vertices (a list of index arrays), from :func:`patch_samples`."""
    samples, sample_patch = sampled
    order = np.argsort(sample_patch, kind="stable")
    starts = np.searchsorted(sample_patch[order], np.arange(count + 1))
    return [samples[order[starts[p]:starts[p + 1]]] for p in range(count)]


__all__ = ["border_points", "farthest_point_patches", "patch_adjacency", "patch_members", "patch_samples",
           "refine_hypotheses", "search_patches"]
