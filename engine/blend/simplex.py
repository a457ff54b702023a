"""Recursive longest-edge bisection of the blend-weight simplex, with point location.

The root cell is the simplex of the N sources' unit weight vectors. Splitting a cell at the
midpoint m of its longest edge (a, b) gives two children: one with b replaced by m (the points
nearer a) and one with a replaced by m. A weight vector is located by walking down the tree with
its barycentric coordinates, which stay exact under each split:
child with a: (lambda_a - lambda_b, 2 lambda_b at m); child with b: (lambda_b - lambda_a, 2 lambda_a).
"""

from __future__ import annotations

import numpy as np


class SimplexTree:
    """Binary tree of simplices over reference weight vectors.

    Attributes
    ----------
    references : (R, N) float array   reference weight vectors; the first N are the unit vectors
    cells : (C, N) int array          reference ids of each node's vertices
    children : (C, 2) int array       child node ids, -1 for leaves
    split : (C, 2) int array          positions (in the node's vertex list) of the split edge
    depth : (C,) int array
    """

    def __init__(self, n_sources):
        if n_sources < 2:
            raise ValueError(f"blending needs at least 2 sources, got {n_sources}")
        self.n = int(n_sources)
        self._references = [np.eye(self.n)[i] for i in range(self.n)]
        self._ref_index = {tuple(np.round(r, 12)): i for i, r in enumerate(self._references)}
        self._cells = [list(range(self.n))]
        self._children = [[-1, -1]]
        self._split = [[-1, -1]]
        self._depth = [0]

    @classmethod
    def from_arrays(cls, references, cells, children, split):
        tree = cls(references.shape[1])
        tree._references = [np.asarray(r, dtype=float) for r in references]
        tree._ref_index = {tuple(np.round(r, 12)): i for i, r in enumerate(tree._references)}
        tree._cells = [list(map(int, c)) for c in cells]
        tree._children = [list(map(int, c)) for c in children]
        tree._split = [list(map(int, s)) for s in split]
        depth = [0] * len(cells)
        for node, (a, b) in enumerate(tree._children):
            if a >= 0:
                depth[a] = depth[b] = depth[node] + 1
        tree._depth = depth
        return tree

    @property
    def references(self):
        return np.array(self._references)

    @property
    def cells(self):
        return np.array(self._cells, dtype=np.int64)

    @property
    def children(self):
        return np.array(self._children, dtype=np.int64)

    @property
    def split(self):
        return np.array(self._split, dtype=np.int64)

    @property
    def depth(self):
        return np.array(self._depth, dtype=np.int64)

    def split_references(self):
        """(C,) reference id introduced by each node's split (-1 for leaves).

        The midpoint m of the split edge (a, b) sits at position b of the first child's cell.
        """
        out = np.full(len(self._cells), -1, dtype=np.int64)
        for node, (first, _) in enumerate(self._children):
            if first >= 0:
                out[node] = self._cells[first][self._split[node][1]]
        return out

    def leaves(self):
        return [i for i, c in enumerate(self._children) if c[0] < 0]

    def vertices(self, node):
        """(N, N) weight vectors of a node's vertices."""
        return np.array([self._references[r] for r in self._cells[node]])

    def longest_edge(self, node, points=None):
        """Positions (i, j) in the node's vertex list of its longest edge.

        points : (M, N) float array or None
            Weight vectors inside the node (where the hybrid is tested). When given, only edges
            some point straddles count: both ends have a barycentric coordinate above 1e-9 for
            one of the points (splitting any other edge leaves every point's interpolation as it
            was: a chain along the simplex's edges is then split only along the chain, never
            across the triangle it does not visit). The longest of all edges when none does.
        """
        W = self.vertices(node)
        allowed = None
        if points is not None and len(points):
            g = np.linalg.lstsq(W.T, np.asarray(points, dtype=float).T, rcond=None)[0].T  # (M, N)
            straddle = np.minimum(g[:, :, None], g[:, None, :]).max(axis=0) > 1e-9     # (N, N)
            if straddle[np.triu_indices(self.n, 1)].any():
                allowed = straddle
        best, pair = -1.0, (0, 1)
        for i in range(self.n):
            for j in range(i + 1, self.n):
                if allowed is not None and not allowed[i, j]:
                    continue
                length = np.linalg.norm(W[i] - W[j])
                if length > best + 1e-12:
                    best, pair = length, (i, j)
        return pair

    def bisect(self, node, edge=None):
        """Split ``node`` at the midpoint of one of its edges.

        Parameters
        ----------
        node : int          a leaf
        edge : (int, int)   positions (in the node's vertex list) of the edge to split;
                            default its longest edge

        Returns
        -------
        reference : int    id of the midpoint's reference vector (new, or shared with a neighbour)
        is_new : bool      whether the reference was created by this split
        """
        if self._children[node][0] >= 0:
            raise ValueError(f"node {node} is already split")
        a, b = self.longest_edge(node) if edge is None else edge
        cell = self._cells[node]
        mid = 0.5 * (self._references[cell[a]] + self._references[cell[b]])
        key = tuple(np.round(mid, 12))
        is_new = key not in self._ref_index
        if is_new:
            self._ref_index[key] = len(self._references)
            self._references.append(mid)
        m = self._ref_index[key]
        child_a = list(cell)
        child_a[b] = m
        child_b = list(cell)
        child_b[a] = m
        self._children[node] = [len(self._cells), len(self._cells) + 1]
        self._split[node] = [a, b]
        for child in (child_a, child_b):
            self._cells.append(child)
            self._children.append([-1, -1])
            self._split.append([-1, -1])
            self._depth.append(self._depth[node] + 1)
        return m, is_new

    def bisect_conforming(self, node, edge=None):
        """Split ``node`` on ``edge`` (positions in its vertex list; default its longest edge)
        and every other leaf with that edge on the same edge.

        Returns
        -------
        reference : int     the midpoint's reference id
        is_new : bool       whether the reference was created by this split
        nodes : list of int the split nodes, ``node`` first

        Notes
        -----
        Splitting every simplex around an edge keeps the tree's leaves a conforming mesh: no leaf
        has a reference in the middle of one of its edges (a hanging reference). Otherwise a leaf
        beside the split interpolates along the shared edge without the reference on it, so the
        hybrid is discontinuous there and not even exact at the reference itself. The neighbours'
        splits add no reference and store nothing: the midpoint's residual is defined by the edge.
        """
        a, b = self.longest_edge(node) if edge is None else edge
        ends = self._cells[node][a], self._cells[node][b]
        reference, is_new = self.bisect(node, (a, b))
        nodes = [node]
        for leaf in self.leaves():
            cell = self._cells[leaf]
            if ends[0] in cell and ends[1] in cell:
                self.bisect(leaf, (cell.index(ends[0]), cell.index(ends[1])))
                nodes.append(leaf)
        return reference, is_new, nodes

    def hanging_references(self):
        """[(leaf, reference)] of references at the midpoint of a leaf's edge (none in a tree
        grown by ``bisect_conforming``)."""
        out = []
        for leaf in self.leaves():
            cell = self._cells[leaf]
            for i in range(self.n):
                for j in range(i + 1, self.n):
                    mid = 0.5 * (self._references[cell[i]] + self._references[cell[j]])
                    r = self._ref_index.get(tuple(np.round(mid, 12)))
                    if r is not None:
                        out.append((leaf, r))
        return out

    def locate(self, weights):
        """Leaf containing ``weights`` and the barycentric coordinates there.

        Parameters
        ----------
        weights : (N,) float array   non-negative; normalised to sum 1 here

        Returns
        -------
        leaf : int
        bary : (N,) float array   coordinates w.r.t. ``cells[leaf]`` (non-negative, sum 1)
        """
        lam = np.asarray(weights, dtype=float)
        lam = lam / lam.sum()
        node = 0
        children, split = self._children, self._split
        while children[node][0] >= 0:
            a, b = split[node]
            la, lb = lam[a], lam[b]
            lam = lam.copy()
            if la >= lb:
                lam[a], lam[b] = la - lb, 2.0 * lb
                node = children[node][0]
            else:
                lam[b], lam[a] = lb - la, 2.0 * la
                node = children[node][1]
        return node, lam

    def test_points(self, node, level=4):
        """Weight vectors on a barycentric grid of ``level`` inside a node, excluding its vertices."""
        W = self.vertices(node)
        points = []
        for combo in _compositions(level, self.n):
            if max(combo) == level:
                continue  # a vertex: the hybrid is exact there
            points.append(np.asarray(combo, dtype=float) @ W / level)
        return np.array(points)


def _compositions(total, parts):
    """All tuples of ``parts`` non-negative integers summing to ``total``."""
    if parts == 1:
        yield (total,)
        return
    for first in range(total + 1):
        for rest in _compositions(total - first, parts - 1):
            yield (first,) + rest
