"""Limbs pulled out, as-rigid-as-possible, to what nothing covers.

A punch thrown between the source and the target leaves the source's arm folded by the body,
where it fits the body's surface well, while the target's arm stands out with no source surface
near it. The patches cannot see that (they fit), and a limb turned as one rigid piece about a
joint does not cover a straight arm with a folded one (:mod:`engine.align.coverage`). Here the
limb is bent as the solid lets it: one of the root's *extremities* (the ends of its geodesic
reach: hands, feet, the head, a hem's corners) is pulled to the far end of an uncovered region,
the surface more than a limb's length away from it holds where it is, and everything between is
free in an as-rigid-as-possible solve on the root's tet mesh. The elbow and the shoulder bend
as the solid does, not as a patch graph guesses. A pull is kept when the bent surface covers
much of the region and what it leaves uncovered is less.

Used when ``AlignmentOptions.reach_limbs`` is on (the default; ``--no-reach-limbs`` turns it off). On the
studio's martial-arts take, one frame in 9, it cut the mean error from 1.93% to 1.62% of the
model size (the right bell sleeve's from 12.5% to 6.3%) at the same CPU, and the tiny preset's
sparse performance's from 1.43% to 0.77%; a dense slice was unchanged; on the sparse dance it
was even from the same roots (docs/alignment.md, "Limbs pulled onto what nothing covers").
"""

from __future__ import annotations

import weakref

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from engine.align.coverage import REGION_SHARE, UNCOVERED, point_regions
from engine.align.matching import sample_cost
from engine.align.rigid import rotation_fit, stack_rotations
from engine.deform import DeformationSolver
from engine.nearest import PointTree
from engine.surface import model_size, vertex_normals
from engine.tetmesh import tet_components

EXTREMITY_SPACING = 0.2   # extremities lie at least this share of the model size apart (geodesic)
EXTREMITY_REACH = 0.3     # and this share of it from the surface's centre
HANDLE = 0.05             # the surface within this share of the model size of an extremity is pulled
HOLD = 0.4                # the surface farther than this share of it from the extremity holds
KEEP_COVER = 0.4          # a pull must cover this share of its region ...
KEEP_FIT = 0.9            # ... the surface it moved fit the target at least this well (mean capped cost)
ARAP_STEPS = 10           # as-rigid-as-possible steps (rotations, then one solve) of a pull
CANDIDATES = 6            # the extremities nearest a region's far end are tried
LOST_WEIGHT = 2.0         # a target sample a pull uncovers costs this many it covers
SAMPLES = 2000            # about this many target vertices (every m-th) are measured
HOLD_WEIGHT = 100.0       # handle and hold constraints, times the mean Laplacian diagonal: nearly hard


def _edge_graph(V, F):
    """The surface's edges weighted by their lengths (n, n) csr_matrix."""
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    length = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)
    n = len(V)
    return sp.csr_matrix((np.concatenate([length, length]),
                          (np.concatenate([edges[:, 0], edges[:, 1]]), np.concatenate([edges[:, 1], edges[:, 0]]))),
                         shape=(n, n))


class Extremities:
    """The root surface's extremities and, for each, what a pull moves and what holds.

    Parameters
    ----------
    V, F : the root surface            size : float, its model size (m)

    Attributes
    ----------
    vertices : (e,) int array          an extremity's vertex, farthest first
    handles, holds : lists of (h,) int arrays   the surface pulled with it, the surface that holds
    """

    def __init__(self, V, F, size):
        graph = _edge_graph(V, F)
        centre = int(np.argmin(np.linalg.norm(V - V.mean(axis=0), axis=1)))
        from_centre = dijkstra(graph, indices=centre)
        reachable = np.isfinite(from_centre)
        blocked = ~reachable | (from_centre < EXTREMITY_REACH * size)
        vertices, self.handles, self.holds = [], [], []
        # farthest first (ties to the lower index); each one taken blocks its neighbourhood
        for v in np.argsort(-np.where(reachable, from_centre, 0.0), kind="stable"):
            if blocked[v]:
                continue
            near = dijkstra(graph, indices=int(v), limit=HOLD * size)
            blocked |= near < EXTREMITY_SPACING * size
            vertices.append(int(v))
            self.handles.append(np.flatnonzero(near < HANDLE * size))
            self.holds.append(np.flatnonzero(~(near < HOLD * size)))
        self.vertices = np.array(vertices, dtype=np.int64)
        self._solvers = {}
        self._parts = None   # the solid's part of each surface vertex, made with the first solver

    def solver(self, k, aligner):
        """The tet solve with extremity ``k``'s handle and hold constrained (factored when first asked).

        A part of the solid that neither reaches (a tet island under a fingertip or a thin hem,
        joined to the rest only through the surface) is held too: nothing would pin it, and the
        solve would be singular. Its surface vertices follow the handle and hold rows."""
        if k not in self._solvers:
            rows = np.concatenate([self.handles[k], self.holds[k]])
            if self._parts is None:
                self._parts = _surface_parts(aligner)
            rows = np.concatenate([rows, np.flatnonzero(~np.isin(self._parts, self._parts[rows]))])
            weight = np.sqrt(HOLD_WEIGHT * aligner._laplacian_scale)
            self._solvers[k] = (rows, DeformationSolver(aligner.V_tet, aligner.T, constraints=aligner.B[rows],
                                                        constraint_weight=weight))
        return self._solvers[k]


def _surface_parts(aligner):
    """The connected part of the aligner's tet mesh that embeds each surface vertex (n,) int."""
    _, part = tet_components(aligner.T, len(aligner.V_tet))
    return part[np.asarray(aligner.B.argmax(axis=1)).ravel()]


_EXTREMITIES = weakref.WeakKeyDictionary()  # aligner -> its Extremities, in this process


def extremities_of(aligner):
    """The aligner's root's :class:`Extremities`, made when first asked (kept per process, never pickled)."""
    if aligner not in _EXTREMITIES:
        _EXTREMITIES[aligner] = Extremities(aligner.V, aligner.F, model_size(aligner.V))
    return _EXTREMITIES[aligner]


def reach_uncovered(aligner, X, R, target):
    """Pull extremities onto the target's uncovered regions (see the module's docstring).

    Parameters
    ----------
    aligner : PairwiseAligner    X : (k, 3) tet vertices    R : (t, 3, 3) their rotations
    target : TargetSurface

    Returns
    -------
    X, R, pulled : the tet vertices and rotations after the pulls kept, and how many were kept
    """
    o = aligner.options
    extremities = extremities_of(aligner)
    far = UNCOVERED * o.search_cap
    S = aligner.surface(X)
    samples = target.V[::max(1, len(target.V) // SAMPLES)]
    gap = PointTree(S).query(samples, k=1)[0]
    uncovered = np.flatnonzero(gap > far)
    regions = [r for r in point_regions(samples[uncovered], far) if len(r) >= REGION_SHARE * len(samples)]
    pulled = 0
    for region in regions[:2]:
        U = samples[uncovered[region]]
        tip = U[np.argmax(gap[uncovered[region]])]
        covered = gap <= far
        best, best_score = None, 0.0
        nearest = np.argsort(np.linalg.norm(S[extremities.vertices] - tip, axis=1), kind="stable")[:CANDIDATES]
        for k in nearest:
            v = extremities.vertices[k]
            rows, solver = extremities.solver(k, aligner)
            goal = S[rows].copy()
            goal[:len(extremities.handles[k])] += tip - S[v]
            Xk, Rk = X, R
            for _ in range(ARAP_STEPS):
                Rk = rotation_fit(aligner._gradients(Xk), Rk, iterations=3)
                Xk = solver.solve(stack_rotations(Rk), goal)
            Sk = aligner.surface(Xk)
            moved = np.flatnonzero(np.linalg.norm(Sk - S, axis=1) > 0.5 * far)
            if len(moved) == 0:
                continue
            fit = float(sample_cost(Sk[moved], vertex_normals(Sk, aligner.F)[moved], target, o).mean())
            now = PointTree(Sk).query(samples, k=1)[0] <= far
            gain = float(np.sum(now[uncovered[region]])) - LOST_WEIGHT * float(np.sum(covered & ~now))
            # enough of the region covered, net of what the pull uncovers; then the best fitting
            score = gain * (1.0 - fit)
            if gain >= KEEP_COVER * len(U) and fit <= KEEP_FIT and score > best_score:
                best, best_score = (Xk, Rk), score
        if best is not None:
            X, R = best
            S = aligner.surface(X)
            gap = PointTree(S).query(samples, k=1)[0]
            pulled += 1
    return X, R, pulled


__all__ = ["Extremities", "reach_uncovered"]
