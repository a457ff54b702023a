"""A tree of the cheapest expected error: every frame reached from the root by the path whose
steps are expected to add the least error in total.

Along the paper's minimum spanning tree a frame's error is close to the sum of what each step of
its path added, and what a step adds grows faster than its dissimilarity: on the whole studio
preset (1,823 frames, session 29's alignment without the repair) the path sums of the model below
follow the frames' true errors at a correlation of 0.84. A step between frames next to each other
in time adds about 0.01% of the model size at a small dissimilarity and 0.2% at a large one; a
step between frames far apart in time adds as little when they are alike (0.01%) and far more
when they are not (0.7%: the body is reached from another way round or another pose). The
spanning tree minimises the sum of the dissimilarities over all edges, not over each frame's
path, so its paths are long chains (mean depth 67, deepest 213 on the studio), and it takes the
cheapest way across between clusters of poses whatever that costs the frames beyond.

:func:`step_tree` instead gives every frame its cheapest path from the root (Dijkstra) under
:func:`step_cost`: a fixed cost per step (``STEP_HOP``: a step never comes free, so a path does
not wander through many near-copies) plus the dissimilarity in units of ``STEP_UNIT``, squared for neighbours in time and to the fourth power
for other pairs (``STEP_NEAR``, ``STEP_FAR``). The constants are fitted to the error each step
added on the studio; docs/evaluation.md ("A tree of the cheapest expected error") has the fit
and the runs. Measured, it aligns worse than the spanning tree (the studio dance, one frame in
two: 4.25% against 2.98% mean): fitted on the spanning tree's own steps, the model does not see
that a jump between frames apart in time can land a fast frame the wrong way round. So it is an
option (``kind="steps"``), not the default.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra, minimum_spanning_tree

STEP_HOP = 0.005        # what any step adds (% of the model size)
STEP_NEAR = 0.04        # ... plus this times (D / unit)^2 between frames next to each other in time
STEP_FAR = 0.03         # ... or this times (D / unit)^4 between other frames
STEP_UNIT = 0.113       # the unit of dissimilarity (the shape histograms' distance, filtered in time)
STEP_WINDOW = 2         # frames of one sequence at most this many apart are neighbours in time
STEP_NEIGHBOURS = 32    # the most similar frames of each frame its path may step to (and from)


def temporal_neighbours(lengths, n, window=STEP_WINDOW):
    """Pairs (i, j), i < j, of frames of the same sequence at most ``window`` frames apart.

    Parameters
    ----------
    lengths : (S,) int array or None   frames per sequence (concatenated in order); None: no
                                       frame is a neighbour in time of another (a subset of a
                                       capture, frames far apart)
    n : int                            frames in all
    """
    if lengths is None:
        return np.zeros((0, 2), dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    if int(lengths.sum()) != n:
        raise ValueError(f"the sequences have {int(lengths.sum())} frames, there are {n}")
    sequence = np.repeat(np.arange(len(lengths)), lengths)
    pairs = []
    for gap in range(1, int(window) + 1):
        i = np.arange(n - gap)
        same = sequence[i] == sequence[i + gap]
        pairs.append(np.stack([i[same], i[same] + gap], axis=1))
    return np.concatenate(pairs).astype(np.int64) if pairs else np.zeros((0, 2), dtype=np.int64)


def step_cost(d, near, unit=STEP_UNIT):
    """Expected error a step of dissimilarity ``d`` adds (``near``: between neighbours in time)."""
    x = np.asarray(d, dtype=np.float64) / float(unit)
    return STEP_HOP + np.where(near, STEP_NEAR * x ** 2, STEP_FAR * x ** 4)


def step_graph(D, lengths=None, neighbours=STEP_NEIGHBOURS, spanning=None):
    """The steps a path may take, each with its :func:`step_cost`: every frame to its
    ``neighbours`` most similar frames, to its neighbours in time, and the edges of the minimum
    spanning tree (so every frame is reachable; ``spanning``, (N - 1, 2) edges, when the caller
    has it: :func:`engine.align.similarity_tree.similarity_tree` has). Symmetric sparse (N, N)."""
    D = np.asarray(D, dtype=np.float64)
    n = len(D)
    k = min(int(neighbours), n - 1)
    off = D + np.diag(np.full(n, np.inf))
    nearest = np.argpartition(off, k - 1, axis=1)[:, :k] if k > 0 else np.zeros((n, 0), dtype=np.int64)
    timed = temporal_neighbours(lengths, n)
    if spanning is None:
        mst = minimum_spanning_tree(sp.csr_matrix(np.triu(np.maximum(D, np.finfo(float).tiny), 1))).tocoo()
        spanning = np.stack([mst.row, mst.col], axis=1)
    spanning = np.asarray(spanning, dtype=np.int64).reshape(-1, 2)
    i = np.concatenate([np.repeat(np.arange(n), k), timed[:, 0], spanning[:, 0]])
    j = np.concatenate([nearest.ravel(), timed[:, 1], spanning[:, 1]])
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    keep = lo != hi
    pair = np.unique(np.stack([lo[keep], hi[keep]], axis=1), axis=0)
    near = np.isin(pair[:, 0] * n + pair[:, 1], timed[:, 0] * n + timed[:, 1])
    cost = step_cost(D[pair[:, 0], pair[:, 1]], near)
    graph = sp.coo_matrix((np.concatenate([cost, cost]), (np.concatenate([pair[:, 0], pair[:, 1]]),
                                                          np.concatenate([pair[:, 1], pair[:, 0]]))), shape=(n, n))
    return graph.tocsr()


def step_tree(D, root, lengths=None, spanning=None):
    """Edges (parent, child) of every frame's cheapest path from ``root`` over :func:`step_graph`
    (``spanning``: the minimum spanning tree's edges, if known), and each frame's expected error
    (the sum of its path's step costs).

    Returns
    -------
    edges : (N - 1, 2) int array
    expected : (N,) float array   0 at the root
    """
    D = np.asarray(D, dtype=np.float64)
    n = len(D)
    expected, predecessor = dijkstra(step_graph(D, lengths, spanning=spanning), directed=False, indices=int(root),
                                     return_predecessors=True)
    nodes = np.flatnonzero(predecessor >= 0)
    if len(nodes) != n - 1:
        raise RuntimeError(f"the steps reach {len(nodes) + 1} of {n} frames")
    return np.stack([predecessor[nodes], nodes], axis=1).astype(np.int64), expected


__all__ = ["STEP_FAR", "STEP_HOP", "STEP_NEAR", "STEP_NEIGHBOURS", "STEP_UNIT", "STEP_WINDOW", "step_cost",
           "step_graph", "step_tree", "temporal_neighbours"]
