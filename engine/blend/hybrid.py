"""Hybrid blending: linear blending plus precomputed non-linear corrections (paper eq. 3).

M(t, w) = M_L(t, w) + sum_j g_j(w) D_NL(t, w_j), where the w_j are the reference weights at the
vertices of the simplex cell containing w, g_j are w's barycentric coordinates there and
D_NL(t, w_j) = M_NL(t, w_j) - M_L(t, w_j). References come from recursive bisection of the weight
simplex (``SimplexTree``) until the hybrid is within epsilon of the exact non-linear blend at
test points of every cell, over all phase samples. The bisection is conforming: every leaf around
a split edge is split on it, so each reference is a vertex of every leaf that touches it.

Storage is hierarchical and sparse. When a cell is split at the midpoint m of its edge (a, b),
only the part of D_NL(m) that interpolating the edge does not predict is stored:
delta_m = D_NL(m) - (D(a) + D(b)) / 2, per phase sample, only where |delta_m| exceeds a
threshold, quantised to 8 bits per component with one scale per reference and phase; then
entries the bound does not need are pruned (``prune_corrections``). For a weight vector w the
correction is then the sum over the
split nodes on w's path down the tree of phi_m(w) delta_m with phi_m = 2 min(lambda_a, lambda_b)
(the hat function of m), which equals the nodal interpolation of eq. 3 in w's leaf.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg.blas import saxpy

from engine.blend.corrections import CorrectionBuilder, Corrections, vector_lengths
from engine.blend.linear import blend_rows
from engine.blend.phase import phase_samples
from engine.blend.simplex import SimplexTree


def hybrid_layout(corrections, n_vertices, dense_above=None, dense_budget=64 << 20):
    """The arrays HybridBlender adds corrections from, beside the corrections themselves.

    corrections : Corrections;  n_vertices : int
    dense_above : int or None   rows listing more vertices than this are also kept dense
                                (default n / 60); dense_budget : int, bytes of dense rows at most
    Returns
    layout : dict   ``flat_index`` (3 E,) intp: the flat (x, y, z) indices of every entry;
                    ``dense_keys`` (K,) int64 (reference, phase) rows kept dense, the largest
                    first, and ``dense_rows`` (K, 3 n) float32 their scaled corrections
    """
    above = n_vertices // 60 if dense_above is None else dense_above
    v = np.asarray(corrections.vertex).astype(np.intp)
    flat_index = (3 * v[:, None] + np.arange(3)).ravel()
    pointer = np.asarray(corrections.pointer, dtype=np.int64)
    counts = np.diff(pointer)
    order = np.argsort(-counts, kind="stable")[:dense_budget // (12 * n_vertices)]
    keys = order[counts[order] > above]
    value = np.asarray(corrections.value).reshape(-1)
    rows = np.zeros((len(keys), 3 * n_vertices), dtype=np.float32)
    for row, k in zip(rows, keys):
        s, e = pointer[k], pointer[k + 1]
        row[flat_index[3 * s:3 * e]] = value[3 * s:3 * e] * np.float32(corrections.scale[k])
    return {"flat_index": flat_index, "dense_keys": keys.astype(np.int64), "dense_rows": rows}


class HybridBlender:
    """Real-time hybrid blends of N sources on a phase grid.

    ``blender = HybridBlender(sources, tree, corrections, cyclic)``;
    ``blender.blend(weights, phase, out)`` is the hot path, close to linear-blend cost.

    Parameters
    ----------
    sources : (P, N, n, 3) float32 array   sources on the phase grid (phase-major layout)
    tree : SimplexTree
    corrections : Corrections
    cyclic : bool
    dense_above : int or None   (reference, phase) corrections listing more vertices than this
                                are also kept dense: adding a dense row is one contiguous BLAS
                                pass (saxpy), cheaper than scattering that many entries
                                (default n / 60)
    dense_budget : int          bytes of dense rows at most (the largest corrections first)
    """

    def __init__(self, sources, tree, corrections, cyclic, *, dense_above=None, dense_budget=64 << 20,
                 layout=None):
        self.sources = sources
        self.n_phases, self.n_sources, self.n_vertices = sources.shape[:3]
        self._flat = np.ascontiguousarray(sources, dtype=np.float32).reshape(self.n_phases, self.n_sources, -1)
        self.cyclic = bool(cyclic)
        self.tree = tree
        self.corrections = corrections
        # The tree walk in plain Python lists (fast scalar access on the hot path).
        self._children = tree.children.tolist()
        self._split = tree.split.tolist()
        self._split_ref = tree.split_references().tolist()
        self._pointer = corrections.pointer.tolist()
        self._value = corrections.value.reshape(-1)
        self._scale = corrections.scale.tolist()
        self._buffer = np.empty(self.n_vertices * 3, dtype=np.float32)
        # Flat (x, y, z) indices of every correction entry (a row scatters into a flat buffer)
        # and the dense rows. ``layout``: hybrid_layout's arrays made beforehand, e.g. mapped
        # from a file several processes share (engine/motion_space/derived.py); only read.
        if layout is None:
            layout = hybrid_layout(corrections, self.n_vertices, dense_above, dense_budget)
        self._flat_index = layout["flat_index"]
        self._dense = dict(zip(layout["dense_keys"].tolist(), layout["dense_rows"]))

    def _add(self, flat, r, p, coefficient):
        k = r * self.n_phases + p
        row = self._dense.get(k)
        if row is not None:
            saxpy(row, flat, a=coefficient)  # in place: one pass over the row
            return
        s, e = self._pointer[k], self._pointer[k + 1]
        if e > s:
            # a (reference, phase) entry lists each vertex once, so plain fancy-index adding is
            # exact (and much faster than np.add.at)
            flat[self._flat_index[3 * s:3 * e]] += self._value[3 * s:3 * e] * np.float32(coefficient * self._scale[k])

    def blend(self, weights, phase, out=None):
        """Blended vertices (n, 3) float32 at ``weights`` (N,) and ``phase`` in [0, 1]."""
        w = np.asarray(weights, dtype=np.float64)
        lam = w / w.sum()
        p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
        flat = self._buffer if out is None else out.reshape(-1)
        if flat.dtype != np.float32 or not flat.flags.c_contiguous:
            raise ValueError("out must be a C-contiguous float32 (n, 3) array")
        blend_rows(self._flat, lam, p0, p1, a, flat)
        node, children, split = 0, self._children, self._split
        lam = lam.tolist()
        while children[node][0] >= 0:
            i, j = split[node]
            li, lj = lam[i], lam[j]
            phi = 2.0 * min(li, lj)
            if phi > 0.0:
                r = self._split_ref[node]
                if a != 1.0:
                    self._add(flat, r, p0, phi * (1.0 - a))
                if a != 0.0:
                    self._add(flat, r, p1, phi * a)
            if li >= lj:
                lam[i], lam[j] = li - lj, 2.0 * lj
                node = children[node][0]
            else:
                lam[j], lam[i] = lj - li, 2.0 * li
                node = children[node][1]
        V = flat.reshape(-1, 3)
        return V if out is not None else V.copy()


MAX_REFERENCES = 256  # new references at most: the spaces built so far need 18-201
CACHE_BYTES = 2e9     # non-linear blends kept for reuse by neighbouring cells


@dataclass
class HybridReport:
    """What the bisection did."""

    epsilon: float
    references: int
    leaves: int
    max_depth: int
    max_test_error: float
    nonlinear_evaluations: int
    stored_fraction: float  # stored entries / (new references x phases x vertices)
    leaf_errors: list = field(default_factory=list)


def build_hybrid(linear, nonlinear, n_sources, n_phases, n_vertices, *, epsilon, keep_threshold=None,
                 margin=0.9, level=None, max_depth=None, max_references=MAX_REFERENCES, uniform_depth=None,
                 test_weights=None, prune=True,
                 progress=None):
    """Reference weights and hierarchical sparse corrections by bisection of the weight simplex.

    Parameters
    ----------
    linear : callable(w) -> (P, n, 3)       linear blend at every phase sample
    nonlinear : callable(w) -> (P, n, 3)    exact non-linear blend at every phase sample
    n_sources, n_phases, n_vertices : int
    epsilon : float        error bound (m)
    keep_threshold : float residuals smaller than this are dropped (default 0.8 epsilon)
    margin : float         cells are split until their test errors are below margin * epsilon
    level : int            barycentric grid level of the test points (default 4; 3 for N > 3)
    max_depth : int        bisection depth limit (default 8 + (N - 2): longest-edge bisection of
                           an (N-1)-simplex needs about N - 1 levels to halve a cell's diameter;
                           cells at the limit are kept even if they fail, and the report says so)
    max_references : int   no cell is split once this many references have been added (cells are
                           split breadth first, so the coarser ones come first); the rest are kept
                           as they are, as at the depth limit. Sources that blend badly (unrelated
                           motions over the whole simplex) otherwise bisect to the depth limit
                           everywhere: hours for five sources
    uniform_depth : int or None
        Split every cell to this depth with nothing dropped, regardless of error (the paper's
        "hybrid with 1 / 3 references" rows are depths 1 and 2 for two sources).
    test_weights : (M, N) float array or None
        Where the bound must hold: the weights a player can reach (a parameter layout's sheet).
        Each cell is tested at those of them inside it and only split if one fails, on the
        longest edge they straddle (``SimplexTree.longest_edge(node, points)``: references stay
        on the sheet, e.g. on a chain's own edges of the simplex); cells with none are never
        split. Default: a barycentric grid of ``level`` in every cell (the whole simplex; the
        longest edge).
    prune : bool
        After the bisection, drop stored entries whose removal keeps every test point and every
        reference within margin * epsilon, or no further off than it was
        (``prune_corrections``). Same tree, fewer entries.
    progress : callable(message, done, total) or None
        called after every cell tested (split or kept as a leaf) and, while pruning, after every
        test point checked: the exact blends they need are the stage's cost, so a bar on it moves
        through all of it (it moved only on splits and stood still for minutes once the
        references' cap stopped them). ``done`` counts the cells tested and points checked,
        ``total`` adds the cells still queued, then the points still to check: it grows as the
        bisection finds more to do

    Returns
    -------
    tree : SimplexTree
    corrections : Corrections
    report : HybridReport

    Notes
    -----
    Test errors are measured with the corrections exactly as stored (thresholded, quantised,
    pruned), so the bound holds for what the runtime computes. Non-linear blends are cached by weight,
    up to ``CACHE_BYTES`` (the least recently used dropped: a five-source bisection of unrelated
    takes held 24 GB of them).
    Cells are split conformingly (``SimplexTree.bisect_conforming``): a leaf beside a split edge is
    split on it too and its halves tested, so no leaf interpolates across a reference on its edge
    and the hybrid is continuous in the weights and within the bound at every reference.
    """
    tree = SimplexTree(n_sources)
    max_depth = 8 + (n_sources - 2) if max_depth is None else max_depth
    keep = 0.8 * epsilon if keep_threshold is None else keep_threshold
    if uniform_depth is not None:
        keep = 0.0
    level = level or (4 if n_sources <= 3 else 3)
    cache = collections.OrderedDict()  # weight -> its non-linear blend, the least recently used dropped
    room = max(64, int(CACHE_BYTES // (8 * 3 * n_phases * n_vertices)))
    evaluations = 0  # non-linear blends computed (a dropped one may be computed again)

    def exact(w):
        nonlocal evaluations
        key = tuple(np.round(w, 12))
        if key in cache:
            cache.move_to_end(key)
            return cache[key]
        evaluations += 1
        cache[key] = value = np.asarray(nonlinear(w), dtype=np.float64)
        if len(cache) > room:
            cache.popitem(last=False)
        return value

    store = CorrectionBuilder(n_phases, n_vertices)
    nodal = {}  # reference -> (P, n, 3) represented D (sources: None = zero)
    for r in range(n_sources):
        store.add_empty()
        nodal[r] = None

    def nodal_of(r):
        return 0.0 if nodal[r] is None else nodal[r]

    def add_reference(r, a, b):
        w = tree.references[r]
        D = exact(w) - np.asarray(linear(w), dtype=np.float64)
        predicted = 0.5 * (nodal_of(a) + nodal_of(b))
        stored = store.add(D - predicted, keep)
        nodal[r] = (predicted + stored).astype(np.float32)

    def hybrid_error(node, w):
        W = tree.vertices(node)
        g = np.linalg.lstsq(W.T, w, rcond=None)[0]
        H = np.asarray(linear(w), dtype=np.float64)
        for k, r in enumerate(tree.cells[node]):
            if g[k] > 0 and nodal[r] is not None:
                H += g[k] * nodal[r]
        return float(vector_lengths(H - exact(w)).max())

    def points_in(node):
        if test_weights is None:
            return tree.test_points(node, level)
        W = tree.vertices(node)
        g = np.linalg.lstsq(W.T, test_weights.T, rcond=None)[0].T
        inside = np.all(g >= -1e-9, axis=1) & np.all(np.abs(g @ W - test_weights) < 1e-9, axis=1)
        return test_weights[inside]

    if test_weights is not None:
        test_weights = np.asarray(test_weights, dtype=float)
        test_weights = test_weights / test_weights.sum(axis=1, keepdims=True)
    queue = [0]
    leaf_errors = []
    tested = 0
    while queue:
        node = queue.pop(0)
        depth = int(tree.depth[node])
        points = None  # uniform subdivision: the longest edge
        if uniform_depth is not None:
            split, worst = depth < uniform_depth, float("nan")
        else:
            points = points_in(node)
            worst = max((hybrid_error(node, w) for w in points), default=0.0)
            split = (worst > margin * epsilon and depth < max_depth
                     and len(tree.references) - n_sources < max_references)
        if split:
            cell = tree.cells[node]
            # With a layout's sheet: the longest edge its points straddle (references stay on the
            # sheet); on the whole simplex: the longest edge
            a, b = tree.longest_edge(node, None if test_weights is None else points)
            r, is_new, split_nodes = tree.bisect_conforming(node, (a, b))
            if is_new:
                add_reference(r, cell[a], cell[b])
            for other in split_nodes[1:]:  # leaves beside the split edge: their halves are tested instead
                if other in queue:
                    queue.remove(other)
                leaf_errors = [(leaf, error) for leaf, error in leaf_errors if leaf != other]
            children = tree.children
            for split_node in split_nodes:
                queue.extend(children[split_node].tolist())
            tested += 1
            if progress is not None:
                progress(f"split cell {node} (depth {depth}, test error {worst * 1000:.1f} mm): "
                         f"{len(tree.references) - n_sources} references", tested, tested + len(queue))
        else:
            leaf_errors.append((int(node), worst))
            tested += 1
            if progress is not None:
                progress(f"cell {node} kept (depth {depth}, test error {worst * 1000:.1f} mm)", tested,
                         tested + len(queue))
    corrections = store.finish()
    if prune and uniform_depth is None:
        # Where the bound is checked: the leaves' test points, and every reference (the bisection
        # takes them as exact; pruning must not spoil them, also off a layout's sheet).
        checked = [(node, w) for node, _ in leaf_errors for w in points_in(node)]
        checked += [(-1, w) for w in tree.references[n_sources:]]
        corrections, worst = prune_corrections(tree, corrections, [w for _, w in checked], linear, exact,
                                               margin * epsilon, leaf=[node for node, _ in checked],
                                               progress=None if progress is None else
                                               lambda message, done, total: progress(message, tested + done,
                                                                                     tested + total))
        leaf_errors = [(node, worst.get(node, 0.0)) for node, _ in leaf_errors]
    new = len(tree.references) - n_sources
    report = HybridReport(
        epsilon=epsilon, references=new, leaves=len(tree.leaves()), max_depth=int(tree.depth.max()),
        max_test_error=float(np.nanmax([e for _, e in leaf_errors])) if uniform_depth is None else float("nan"),
        nonlinear_evaluations=evaluations,
        stored_fraction=float(len(corrections.vertex)) / max(1, new * n_phases * n_vertices),
        leaf_errors=leaf_errors)
    return tree, corrections, report


def path_weights(tree, weights):
    """[(reference, phi)] of the split nodes on ``weights``' path down the tree (phi > 0):
    the hat-function weight each stored residual gets in the hybrid blend."""
    lam = list(np.asarray(weights, dtype=float) / np.sum(weights))
    node, children, split, split_ref = 0, tree.children, tree.split, tree.split_references()
    out = []
    while children[node][0] >= 0:
        i, j = split[node]
        li, lj = lam[i], lam[j]
        if min(li, lj) > 0.0:
            out.append((int(split_ref[node]), 2.0 * min(li, lj)))
        if li >= lj:
            lam[i], lam[j], node = li - lj, 2.0 * lj, children[node][0]
        else:
            lam[j], lam[i], node = lj - li, 2.0 * li, children[node][1]
    return out


def prune_corrections(tree, corrections, test_weights, linear, exact, bound, leaf=None, progress=None):
    """Drop stored entries the bound does not need.

    An entry (reference r, phase p, vertex v) is dropped when, without it, the hybrid is still
    within ``bound`` of the exact blend (or no further from it than before, where it already was
    further) at phase p, vertex v and every test weight r's hat function reaches. Entries are
    visited reference by reference, the deepest first; every decision sees the ones before.

    Parameters
    ----------
    tree : SimplexTree
    corrections : Corrections
    test_weights : (T, N) float array   where the bound must hold (references and test points)
    linear, exact : callable(w) -> (P, n, 3)
    bound : float
    leaf : (T,) int list or None        the leaf each test weight reports to (-1: none; default
                                        the leaf containing it)
    progress : callable(message, done, total) or None   called after each test weight's error is
                                        measured (``done`` of ``total`` test weights)

    Returns
    -------
    corrections : Corrections   the kept entries, values and scales unchanged
    worst : dict                leaf -> largest error left at its test weights

    Notes
    -----
    Dropping entry (r, p, v) changes the hybrid at weight w by exactly -phi_r(w) times the
    stored value (``path_weights``), so the errors are updated without re-blending.
    """
    P, n = corrections.n_phases, corrections.n_vertices
    R = corrections.n_references
    phi = np.zeros((len(test_weights), R))
    for t, w in enumerate(test_weights):
        for r, weight in path_weights(tree, w):
            phi[t, r] += weight
    if leaf is None:
        leaf = [tree.locate(w)[0] for w in test_weights]
    error = np.empty((len(test_weights), P, n, 3), dtype=np.float32)  # hybrid - exact
    for t, w in enumerate(test_weights):
        error[t] = np.asarray(linear(w), dtype=np.float64) - exact(w)
        for r in np.flatnonzero(phi[t]):
            error[t] += phi[t, r] * corrections.dense(r)
        if progress is not None:
            progress(f"pruning: test point {t + 1} of {len(test_weights)} measured", t + 1, len(test_weights))
    limit = np.maximum(np.float32(bound), vector_lengths(error).max(axis=(1, 2)))
    keep = np.ones(len(corrections.vertex), dtype=bool)
    for r in range(R - 1, -1, -1):
        support = np.flatnonzero(phi[:, r])
        if not len(support):
            continue
        for p in range(P):
            k = r * P + p
            s, e = corrections.pointer[k], corrections.pointer[k + 1]
            if e == s:
                continue
            vertex = corrections.vertex[s:e].astype(np.intp)
            value = corrections.value[s:e].astype(np.float32) * corrections.scale[k]
            before = error[support, p][:, vertex]                                  # (S, c, 3)
            after = before - phi[support, r, None, None].astype(np.float32) * value
            fine = np.all(vector_lengths(after) <= limit[support, None], axis=0)
            keep[s:e] = ~fine
            error[np.ix_(support, [p], vertex[fine])] = after[:, None, fine]
    kept_before = np.concatenate([[0], np.cumsum(keep)])
    pruned = Corrections(n_phases=P, n_vertices=n, pointer=kept_before[corrections.pointer].astype(np.int64),
                         vertex=corrections.vertex[keep], value=corrections.value[keep],
                         scale=corrections.scale)
    norms = vector_lengths(error).max(axis=(1, 2))
    worst = {}
    for t, node in enumerate(leaf):
        if node >= 0:
            worst[node] = max(worst.get(node, 0.0), float(norms[t]))
    return pruned, worst
