"""Limbs grafted from other aligned frames: a flagged frame's arms put where the capture's own
poses fit it best, then the frame aligned again from there (``AlignmentOptions.graft_limbs``,
``--graft-limbs``; off by default).

On a far step the patches leave a limb where the source had it, on the body's surface where
every patch fits (a dancer's arms from the hips to overhead, a punch thrown). Put in its place
whole (shoulder, elbow, hand and sleeve), an arm stays there through the fit: on the studio
dance's far steps, the arms pulled onto their true places and fitted again cut the steps' mean
error from 4.13% to 1.36% of the model size (docs/evaluation.md, "Arms put in place whole").
The place has to be found without the truth, and a limb posed as two rigid bones neither reaches
it nor scores better there (a loose sleeve is no bone). The capture itself holds better
candidates: every aligned frame's surface is one pose of each limb, whole and in the root's
structure.

So each of the root's extremities (:class:`engine.align.reach.Extremities`: hands, feet, the
head, a hem's corners) gets a limb, the surface within ``LENGTH`` of the model size of it
(geodesic), and an anchor, the ring of surface ``ANCHOR`` wider beyond it (a shoulder, a hip).
For a frame, every library pose of a limb is carried onto the frame by the rigid motion that
best fits its anchor to the frame's anchor, and scored by both ways of the fit
(:func:`limb_cost`): the limb's samples that find no compatible target (a capped distance, the
normals, the colour), and the target near the limb that neither it nor the rest of the body
covers. The best library pose that lowers the limb's cost by ``MARGIN`` of its own becomes the
limb's goal; the body follows in an as-rigid-as-possible solve that holds everything else where
it is, and the frame is aligned again from that pose. The repair keeps the result only where it
scores better (:mod:`engine.align.repair`).

It is only as good as its library. Given the true poses of the studio dance's sparse frames it
cut two far steps from 4.40% and 4.60% to 1.27% and 1.50% of the model size; given the frames as
aligned, whose arms share the root's errors, it grafted one limb in five frames tried on the dance
sampled one frame in 28 from frame 476 (5.66% -> 5.61%), and none in nine from frame 0
(docs/evaluation.md, "Limbs grafted from the capture's own poses").
"""

from __future__ import annotations

import weakref

import numpy as np
from scipy.sparse.csgraph import dijkstra

from engine.align.reach import _edge_graph, extremities_of
from engine.align.rigid import rotation_fit
from engine.nearest import PointTree
from engine.surface import model_size, vertex_normals

LENGTH = 0.4          # a limb's geodesic length from its extremity, as a share of the model size
ANCHOR = 0.1          # its anchor: the ring this much wider beyond it (share of the model size)
LIMB_SHARE = 0.25     # a limb holds at most this share of the vertices (else it is not a limb)
SAMPLES = 300         # limb samples scored
TARGET_SAMPLES = 3000 # about this many target vertices (every m-th) measured for coverage
CAP = 2.0             # distances are capped at this many search caps
COLOUR_GAP = 0.25     # an RGB distance this large counts as a miss
NORMAL_COS = 0.3      # a limb sample whose target's normal is further off counts as a miss
MARGIN = 0.1          # a library pose must lower the limb's cost by this share of it
LIBRARY = 48          # frames at most in the library (evenly spread over those given)
ARAP_STEPS = 10       # as-rigid-as-possible rounds that carry the body to the grafted limbs


class Limbs:
    """The root's limbs: for each extremity, its vertices, samples and anchor ring.

    Attributes
    ----------
    members, samples, anchors : lists of int arrays (root vertex indices)
    """

    def __init__(self, V, F, extremities):
        size = model_size(V)
        graph = _edge_graph(V, F)
        length, ring = LENGTH * size, ANCHOR * size
        self.members, self.samples, self.anchors = [], [], []
        for v in extremities.vertices:
            d = dijkstra(graph, indices=int(v), limit=length + ring)
            members = np.flatnonzero(d < length)
            anchor = np.flatnonzero((d >= length) & (d < length + ring))
            if len(members) > LIMB_SHARE * len(V) or len(anchor) < 10:
                continue
            self.members.append(members)
            self.samples.append(members[::max(1, len(members) // SAMPLES)])
            self.anchors.append(anchor)


_LIMBS = weakref.WeakKeyDictionary()  # aligner -> its Limbs, in this process


def limbs_of(aligner):
    """The aligner's root's :class:`Limbs`, made when first asked (kept per process, never pickled)."""
    if aligner not in _LIMBS:
        _LIMBS[aligner] = Limbs(aligner.V, aligner.F, extremities_of(aligner))
    return _LIMBS[aligner]


def batch_kabsch(P, Q):
    """Rigid motions (R, t) that best carry each of P (h, a, 3) onto Q (a, 3): x -> R x + t."""
    cp, cq = P.mean(axis=1), Q.mean(axis=0)
    H = np.einsum("hai,aj->hij", P - cp[:, None], Q - cq)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("hij,hjk->hik", U, Vt).transpose(0, 2, 1)))
    D = np.zeros_like(H)
    D[:, 0, 0], D[:, 1, 1], D[:, 2, 2] = 1.0, 1.0, d
    R = np.einsum("hji,hjk,hlk->hil", Vt, D, U)
    return R, cq - np.einsum("hij,hj->hi", R, cp)


def limb_cost(P, N, colours, target, cap, U, rest_gap, trees, R, t):
    """Cost of each candidate pose of a limb, in [0, 2]: the mean capped miss of its samples
    ``P`` (h, s, 3) with normals ``N`` (and ``colours`` (s, 3) or None) on ``target``, plus the
    mean capped gap of the nearby target samples ``U`` to the rest of the body (``rest_gap``) or
    to the candidate, whose samples are ``trees[h]``'s points carried by ``x -> R[h] x + t[h]``."""
    d, idx = target.tree.query(P.reshape(-1, 3), k=1)
    miss = np.einsum("pc,pc->p", N.reshape(-1, 3), target.normals[idx]) < NORMAL_COS
    if colours is not None and target.colors is not None:
        miss |= np.linalg.norm(np.tile(colours, (len(P), 1)) - target.colors[idx], axis=1) > COLOUR_GAP
    forward = np.where(miss, 1.0, np.minimum(d / cap, 1.0) ** 2).reshape(P.shape[:2]).mean(axis=1)
    cover = np.empty(len(P))
    for h in range(len(P)):
        gap = np.minimum(rest_gap, trees[h].query((U - t[h]) @ R[h], k=1)[0])
        cover[h] = np.mean(np.minimum(gap / cap, 1.0) ** 2)
    return forward + cover


class LimbLibrary:
    """Aligned frames' surfaces as candidate limb poses (see the module's docstring).

    Parameters
    ----------
    aligner : PairwiseAligner     surfaces : (k, n, 3) aligned vertices of the frames
    """

    def __init__(self, aligner, surfaces):
        surfaces = np.asarray(surfaces, dtype=np.float64)
        if len(surfaces) > LIBRARY:
            surfaces = surfaces[np.unique(np.linspace(0, len(surfaces) - 1, LIBRARY).astype(np.int64))]
        self.aligner, self.surfaces = aligner, surfaces
        self.limbs = limbs_of(aligner)
        normals = np.stack([vertex_normals(S, aligner.F) for S in surfaces]) if len(surfaces) else surfaces
        self.sample_normals = [normals[:, s] for s in self.limbs.samples]
        self.trees = [[PointTree(S[s]) for S in surfaces] for s in self.limbs.samples]

    def graft(self, S, target):
        """Goals for the frame aligned as ``S`` (n, 3) on ``target``: every limb whose best library
        pose fits clearly better carried there. Returns (goal (n, 3), how many limbs were grafted)."""
        o = self.aligner.options
        cap = CAP * o.search_cap
        colours = self.aligner.colors if o.colour_weight > 0 else None
        goal, grafted = S.copy(), 0
        if not len(self.surfaces):
            return goal, 0
        U_all = target.V[::max(1, len(target.V) // TARGET_SAMPLES)]
        gap_k, idx_k = PointTree(S).query(U_all, k=16)
        N = vertex_normals(S, self.aligner.F)
        for members, samples, anchor, normals, trees in zip(self.limbs.members, self.limbs.samples, self.limbs.anchors,
                                                            self.sample_normals, self.trees):
            in_limb = np.zeros(len(S), dtype=bool)
            in_limb[members] = True
            centre = S[anchor].mean(axis=0)
            near = np.linalg.norm(U_all - centre, axis=1) <= np.linalg.norm(S[members] - centre, axis=1).max() + cap
            if not near.any():
                continue
            U = U_all[near]
            outside = ~in_limb[idx_k[near]]
            rest_gap = np.where(outside.any(axis=1), gap_k[near][np.arange(len(U)), outside.argmax(axis=1)], np.inf)
            R, t = batch_kabsch(self.surfaces[:, anchor], S[anchor])
            P = np.einsum("hij,hsj->hsi", R, self.surfaces[:, samples]) + t[:, None]
            Nn = np.einsum("hij,hsj->hsi", R, normals)
            cols = None if colours is None else colours[samples]
            cost = limb_cost(P, Nn, cols, target, cap, U, rest_gap, trees, R, t)
            own = limb_cost(S[samples][None], N[samples][None], cols, target, cap, U, rest_gap,
                            [PointTree(S[samples])], np.eye(3)[None], np.zeros((1, 3)))[0]
            h = int(np.argmin(cost))
            if cost[h] < (1.0 - MARGIN) * own:
                goal[members] = self.surfaces[h, members] @ R[h].T + t[h]
                grafted += 1
        return goal, grafted

    def pose(self, X, S, target):
        """The tet pose carried to the grafted limbs from pose ``X`` (surface ``S``), or None when
        no limb was grafted."""
        goal, grafted = self.graft(S, target)
        return carry(self.aligner, X, goal) if grafted else None


def carry(aligner, X, goal):
    """The root's solid carried from pose ``X`` (k, 3) towards per-vertex surface goals (n, 3) by
    the aligner's own as-rigid-as-possible solve at its final stiffness, every goal at full
    confidence: ``ARAP_STEPS`` deformations, the rotations first fitted to ``X``."""
    R = rotation_fit(aligner._gradients(X), aligner._eye, iterations=8)
    solver = aligner._solvers[aligner.options.final_stiffness]
    for _ in range(ARAP_STEPS):
        X, R = aligner._deform(X, R, solver, goal, np.ones(len(goal)))
    return X


__all__ = ["LimbLibrary", "Limbs", "batch_kabsch", "carry", "limb_cost", "limbs_of"]
