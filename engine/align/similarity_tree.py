"""The shape similarity tree (Casas et al. 2012, section 3.1, eq. 1).

``tree = similarity_tree(D)`` prunes the complete graph of frames to the edges no more
dissimilar than the automatic threshold (every frame keeps its best match), reconnects any
components the pruning split by their cheapest edges, and takes the minimum spanning tree; the
root is the most central frame unless one is given. Alignment then runs from the root along
the branches (``tree.order`` lists every frame after its parent).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, connected_components, dijkstra, minimum_spanning_tree


@dataclass(frozen=True)
class SimilarityTree:
    """A spanning tree over N frames, rooted.

    Attributes
    ----------
    root : int
    parent : (N,) int array        parent of every frame, -1 for the root
    order : (N,) int array         breadth-first order from the root (parents before children)
    depth : (N,) int array         edges from the root
    cost : (N,) float array        sum of edge dissimilarities from the root
    edges : (N - 1, 2) int array   (parent, child) pairs in ``order``
    weights : (N - 1,) float array dissimilarity of each edge
    threshold : float              the pruning threshold used
    components : int               connected components after pruning (1: nothing to reconnect)
    """

    root: int
    parent: np.ndarray
    order: np.ndarray
    depth: np.ndarray
    cost: np.ndarray
    edges: np.ndarray
    weights: np.ndarray
    threshold: float
    components: int

    @property
    def n_frames(self):
        return len(self.parent)

    def children(self):
        """List of child index arrays, one per frame."""
        children = [[] for _ in range(len(self.parent))]
        for node in self.order[1:]:
            children[self.parent[node]].append(int(node))
        return [np.array(c, dtype=np.int64) for c in children]


def _check_matrix(D):
    D = np.asarray(D, dtype=np.float64)
    if D.ndim != 2 or D.shape[0] != D.shape[1] or len(D) == 0:
        raise ValueError(f"D must be a non-empty square matrix, got shape {D.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError("D has non-finite entries")
    if np.any(D < 0):
        raise ValueError("D has negative dissimilarities")
    return D


def pruning_threshold(D):
    """Automatic pruning threshold: the largest of the rows' best (smallest off-diagonal) entries.

    Parameters
    ----------
    D : (N, N) float array   symmetric dissimilarities, N >= 2

    Returns
    -------
    threshold : float

    Notes
    -----
    The paper (section 3.1) states it for a similarity: "the minimum of the maximum similarity
    for each row". With a dissimilarity the same rule is the maximum over rows of each row's
    minimum, so that every frame keeps at least its best match.
    """
    D = _check_matrix(D)
    if len(D) < 2:
        raise ValueError("a threshold needs at least 2 frames")
    off = D + np.diag(np.full(len(D), np.inf))
    return float(off.min(axis=1).max())


def pruned_graph(D, threshold):
    """Edges (i < j) with ``D[i, j] <= threshold`` as a sparse upper-triangular matrix.

    Zero dissimilarities are stored as a tiny positive value (sparse graphs treat 0 as no edge).
    """
    D = _check_matrix(D)
    i, j = np.nonzero(np.triu(D <= threshold, k=1))
    w = np.maximum(D[i, j], np.finfo(float).tiny)
    return sp.csr_matrix((w, (i, j)), shape=D.shape)


def reconnect_components(D, graph):
    """Add the cheapest edges joining the connected components of ``graph``.

    Parameters
    ----------
    D : (N, N) float array               full dissimilarities
    graph : (N, N) sparse matrix         the pruned graph (upper triangular)

    Returns
    -------
    graph : (N, N) csr_matrix   ``graph`` plus the edges of a minimum spanning tree over the
                                components, each the cheapest edge between its two components
    components : int            how many components ``graph`` had

    Notes
    -----
    Kruskal's algorithm takes every edge under the threshold before any above it, so the
    minimum spanning tree of the complete graph is the pruned graph's forest joined by a
    minimum spanning tree of the components under their cheapest connecting edges: the result
    equals the unpruned tree whatever the threshold.
    """
    D = _check_matrix(D)
    n_components, label = connected_components(graph, directed=False)
    if n_components == 1:
        return sp.csr_matrix(graph), 1
    # Cheapest edge between every pair of components.
    order = np.argsort(label, kind="stable")
    bounds = np.searchsorted(label[order], np.arange(n_components + 1))
    best = np.full((n_components, n_components), np.inf)
    where = np.zeros((n_components, n_components, 2), dtype=np.int64)
    for a in range(n_components):
        rows = order[bounds[a]:bounds[a + 1]]
        block = D[rows]
        for b in range(a + 1, n_components):
            cols = order[bounds[b]:bounds[b + 1]]
            sub = block[:, cols]
            k = int(np.argmin(sub))
            r, c = divmod(k, len(cols))
            best[a, b] = best[b, a] = sub[r, c]
            where[a, b] = where[b, a] = (rows[r], cols[c])
    component_tree = minimum_spanning_tree(sp.csr_matrix(np.triu(np.maximum(best, np.finfo(float).tiny), 1)))
    a, b = component_tree.nonzero()
    i, j = where[a, b, 0], where[a, b, 1]
    lo, hi = np.minimum(i, j), np.maximum(i, j)
    extra = sp.csr_matrix((np.maximum(D[lo, hi], np.finfo(float).tiny), (lo, hi)), shape=D.shape)
    return (sp.csr_matrix(graph) + extra).tocsr(), n_components


def tree_centrality(parent_graph_edges, weights, n):
    """Every node's sum of path lengths to all nodes of a weighted tree (lower is more central).

    Parameters
    ----------
    parent_graph_edges : (n - 1, 2) int array   undirected tree edges
    weights : (n - 1,) float array              edge lengths
    n : int

    Returns
    -------
    total : (n,) float array
    """
    if n == 1:
        return np.zeros(1)
    edges = np.asarray(parent_graph_edges, dtype=np.int64)
    adjacency = _adjacency(edges, weights, n)
    order, parent = breadth_first_order(adjacency, 0, directed=False, return_predecessors=True)
    length = np.zeros(n)  # length of the edge to the parent (rooted at 0)
    child_nodes = order[1:]
    length[child_nodes] = np.asarray(adjacency[parent[child_nodes], child_nodes]).ravel()
    # Sum of distances by rerooting: S(child) = S(parent) + w * (n - 2 size(child)).
    size = np.ones(n)
    down = np.zeros(n)  # sum of distances to the nodes of the subtree
    for node in order[:0:-1]:
        size[parent[node]] += size[node]
        down[parent[node]] += down[node] + length[node] * size[node]
    total = np.zeros(n)
    total[order[0]] = down[order[0]]
    for node in child_nodes:
        total[node] = total[parent[node]] + length[node] * (n - 2.0 * size[node])
    return total


def _adjacency(edges, weights, n):
    return sp.csr_matrix((np.concatenate([weights, weights]),
                          (np.concatenate([edges[:, 0], edges[:, 1]]),
                           np.concatenate([edges[:, 1], edges[:, 0]]))), shape=(n, n))


def tree_root(parent_graph_edges, weights, n, *, criterion="median"):
    """The most central node of a weighted tree.

    Parameters
    ----------
    parent_graph_edges : (n - 1, 2) int array   undirected tree edges
    weights : (n - 1,) float array              edge lengths
    n : int
    criterion : {"median", "center"}
        "median" minimises the sum of path lengths to all nodes (the average alignment path,
        :func:`tree_centrality`), "center" the longest path (the worst one).

    Returns
    -------
    root : int
    """
    if n == 1:
        return 0
    if criterion not in ("median", "center"):
        raise ValueError(f"criterion must be 'median' or 'center', got {criterion!r}")
    if criterion == "median":
        return int(np.argmin(tree_centrality(parent_graph_edges, weights, n)))
    edges = np.asarray(parent_graph_edges, dtype=np.int64)
    adjacency = _adjacency(edges, weights, n)
    # Eccentricity: the farthest node from any node is an end of a longest path (tree diameter).
    first = _farthest(adjacency, 0)[0]
    second, dist_first = _farthest(adjacency, first)
    _, dist_second = _farthest(adjacency, second)
    return int(np.argmin(np.maximum(dist_first, dist_second)))


def _farthest(adjacency, source):
    from scipy.sparse.csgraph import dijkstra

    dist = dijkstra(adjacency, directed=False, indices=source)
    return int(np.argmax(dist)), dist


TREE_KINDS = ("paths", "mst", "steps")
DEFAULT_TREE = "mst"


def similarity_tree(D, *, root=None, threshold=None, criterion="median", kind=DEFAULT_TREE, power=3.0,
                    choose_root=None, lengths=None):
    """Spanning tree of the pruned, reconnected similarity graph, rooted.

    Parameters
    ----------
    D : (N, N) float array   symmetric dissimilarities (e.g. temporally filtered)
    root : int or None       the root frame; default the most central of the minimum spanning
                             tree (``criterion``)
    threshold : float or None   pruning threshold, default :func:`pruning_threshold`
    criterion : {"median", "center"}   see :func:`tree_root`
    kind : {"mst", "paths", "steps"}
        "mst": the minimum spanning tree (the paper's eq. 1). "paths": every frame's cheapest
        path from the root over the same graph, an edge costing ``(D / threshold) ** power``.
        "steps": every frame's path of the least expected error
        (:func:`engine.align.step_tree.step_tree`; ``lengths`` tells neighbours in time).
    power : float            for ``kind="paths"``
    choose_root : callable(centrality) -> int, or None
        picks the root when ``root`` is None, from every frame's sum of path lengths in the
        minimum spanning tree (:func:`tree_centrality`), instead of ``criterion``
        (e.g. :func:`engine.align.root_choice.choose_root`: central, with its limbs apart)
    lengths : (S,) int array or None   frames per sequence, for ``kind="steps"`` (None: no two
                             frames are neighbours in time)

    Returns
    -------
    SimilarityTree

    Notes
    -----
    Casas et al. 2012, eq. (1): the tree minimising the total dissimilarity of its edges. On one
    long performance that tree is nearly the temporal chain, and alignment errors accumulate
    along it (hundreds of frames deep). With ``kind="paths"`` a frame is reached by the path
    whose steps are small in total with big steps penalised steeply (cubed), so paths take
    shortcuts through similar poses: on the studio dance (617 frames at 25 fps) the mean depth
    drops from 62 to 21 and the deepest frame from 131 to 58, while the mean edge
    dissimilarity grows by only 9% (0.103 to 0.112). It is not the default: on the tiny preset's
    four sequences it aligned worse than the minimum spanning tree (mean error 1.74% against
    0.79% of the model size; docs/evaluation.md).
    """
    D = _check_matrix(D)
    n = len(D)
    if kind not in TREE_KINDS:
        raise ValueError(f"kind must be one of {TREE_KINDS}, got {kind!r}")
    if root is not None and not 0 <= int(root) < n:
        raise ValueError(f"root {root} is not a frame index in 0..{n - 1}")
    if n == 1:
        return SimilarityTree(root=0, parent=np.array([-1]), order=np.array([0]), depth=np.array([0]),
                              cost=np.array([0.0]), edges=np.zeros((0, 2), dtype=np.int64),
                              weights=np.zeros(0), threshold=0.0, components=1)
    if threshold is None:
        threshold = pruning_threshold(D)
    graph, components = reconnect_components(D, pruned_graph(D, threshold))
    mst = minimum_spanning_tree(graph).tocoo()
    edges = np.stack([mst.row, mst.col], axis=1).astype(np.int64)
    if len(edges) != n - 1:
        raise RuntimeError(f"spanning tree has {len(edges)} edges for {n} frames")
    weights = D[edges[:, 0], edges[:, 1]]
    if root is None and choose_root is not None:
        root = int(choose_root(tree_centrality(edges, weights, n)))
        if not 0 <= root < n:
            raise ValueError(f"choose_root gave {root}, not a frame index in 0..{n - 1}")
    elif root is None:
        root = tree_root(edges, weights, n, criterion=criterion)
    if kind == "steps":
        from engine.align.step_tree import step_tree

        edges, _ = step_tree(D, int(root), lengths, spanning=edges)  # (the spanning tree's edges, made above)
        weights = D[edges[:, 0], edges[:, 1]]
    elif kind == "paths":
        costs = graph.copy()
        costs.data = np.maximum((costs.data / max(float(threshold), 1e-300)) ** float(power), np.finfo(float).tiny)
        _, predecessor = dijkstra(costs, directed=False, indices=int(root), return_predecessors=True)
        nodes = np.flatnonzero(predecessor >= 0)
        edges = np.stack([predecessor[nodes], nodes], axis=1).astype(np.int64)
        weights = D[edges[:, 0], edges[:, 1]]
    return rooted_tree(edges, weights, int(root), n, threshold=float(threshold), components=components)


def rooted_tree(edges, weights, root, n, *, threshold=float("nan"), components=1):
    """Orient undirected tree edges away from ``root``: parents, order, depth and path cost."""
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    weights = np.asarray(weights, dtype=np.float64)
    adjacency = sp.csr_matrix((np.concatenate([weights, weights]) + np.finfo(float).tiny,
                               (np.concatenate([edges[:, 0], edges[:, 1]]),
                                np.concatenate([edges[:, 1], edges[:, 0]]))), shape=(n, n))
    order, parent = breadth_first_order(adjacency, root, directed=False, return_predecessors=True)
    if len(order) != n:
        raise ValueError(f"the edges do not connect all {n} frames")
    parent = parent.astype(np.int64)
    parent[root] = -1
    lookup = {(int(a), int(b)): float(w) for (a, b), w in zip(edges, weights)}
    depth = np.zeros(n, dtype=np.int64)
    cost = np.zeros(n)
    tree_weights = []
    for node in order[1:]:
        p = parent[node]
        w = lookup.get((int(p), int(node)), lookup.get((int(node), int(p))))
        depth[node] = depth[p] + 1
        cost[node] = cost[p] + w
        tree_weights.append(w)
    tree_edges = np.stack([parent[order[1:]], order[1:]], axis=1) if n > 1 else np.zeros((0, 2), np.int64)
    return SimilarityTree(root=int(root), parent=parent, order=order.astype(np.int64), depth=depth, cost=cost,
                          edges=tree_edges.astype(np.int64), weights=np.array(tree_weights),
                          threshold=float(threshold), components=int(components))


def chain_tree(lengths, root):
    """Frame-to-frame tracking as a tree: consecutive frames linked, sequences end to end.

    Parameters
    ----------
    lengths : (S,) int array   frames per sequence (concatenated in order)
    root : int                 the frame tracking starts from (forwards and backwards)

    Returns
    -------
    SimilarityTree   a path through all frames in their order (the sequential baseline)
    """
    n = int(np.sum(lengths))
    edges = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    return rooted_tree(edges, np.ones(n - 1), int(root), n)


__all__ = ["SimilarityTree", "chain_tree", "pruned_graph", "pruning_threshold", "reconnect_components",
           "rooted_tree", "similarity_tree", "tree_centrality", "tree_root"]
