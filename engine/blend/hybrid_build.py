"""Building a hybrid: references and corrections by bisection of the weight simplex.

References come from recursive bisection of the weight simplex (``SimplexTree``) until the hybrid
(:mod:`engine.blend.hybrid`) is within epsilon of the exact non-linear blend at the test points of
every cell, over all phase samples: a layout's sheet (where a player can go) or, without one, a
barycentric grid in every cell. The bisection is conforming: every leaf around a split edge is
split on it, so each reference is a vertex of every leaf that touches it. Stored entries the
bound does not need are then pruned (``prune_corrections``), and with ``check_weights`` the bound
is checked between the test points, whose failures become test points in turn.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

import numpy as np

from engine.blend.corrections import CorrectionBuilder, Corrections, vector_lengths
from engine.blend.simplex import SimplexTree


MAX_REFERENCES = 256  # new references at most: the spaces built so far need 18-201
CACHE_BYTES = 2e9     # non-linear blends kept for reuse by neighbouring cells
CHECK_ROUNDS = 3      # rounds of the check between the test points at most


@dataclass
class HybridReport:
    """What the bisection did (``check_*``: the check between the test points, if one ran)."""

    epsilon: float
    references: int
    leaves: int
    max_depth: int
    max_test_error: float
    nonlinear_evaluations: int
    stored_fraction: float  # stored entries / (new references x phases x vertices)
    leaf_errors: list = field(default_factory=list)
    check_points: int = 0            # check weights measured (those moved to the test points included)
    max_check_error: float = float("nan")  # the largest error at the check weights left, after the last round
    check_rounds: int = 0            # times the check weights were measured (refinements + 1 at most)
    check_added: int = 0             # check weights that failed and became test points


def build_hybrid(linear, nonlinear, n_sources, n_phases, n_vertices, *, epsilon, keep_threshold=None,
                 margin=0.9, level=None, max_depth=None, max_references=MAX_REFERENCES, uniform_depth=None,
                 test_weights=None, check_weights=None, check_rounds=CHECK_ROUNDS, prune=True,
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
    check_weights : (K, N) float array or None
        Weights between the test points where the bound (epsilon itself) must hold too, e.g. the
        sheet sampled twice as densely. The test points are where cells are measured while the
        tree is built; between them the error can rise above the bound, most where pruning left
        the test points just inside it (on the demo's fan, 5.89 mm at epsilon 5 mm). After the
        bisection and pruning, the hybrid as stored is measured at every check weight; those over
        epsilon become test points, the leaves holding them are tested again (and split where
        they fail), and the corrections are pruned again from the bisection's, keeping the new
        points within the bound. Up to ``check_rounds`` rounds; the report's ``max_check_error``
        is measured after the last. Only with ``test_weights``; skipped with ``uniform_depth``.
    check_rounds : int
        refinement rounds at most; after each, the check weights whose path down the tree or
        whose corrections changed are measured again (the report's ``check_rounds`` counts the
        measurements: at most one more)
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

    def normalised(weights):
        weights = np.asarray(weights, dtype=float)
        return weights / weights.sum(axis=1, keepdims=True)

    if test_weights is not None:
        test_weights = normalised(test_weights)
    if check_weights is not None:
        if test_weights is None:
            raise ValueError("check_weights needs test_weights: they are checked between a layout's test points")
        check_weights = normalised(check_weights)
    queue = [0]
    leaf_errors = []
    tested = 0

    def bisect():
        """Test the queued cells, splitting those that fail, until none is left."""
        nonlocal leaf_errors, tested
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

    def finished():
        """The corrections as stored, pruned, and the leaves' worst test errors after pruning (or None)."""
        corrections = store.finish()
        if not prune or uniform_depth is not None:
            return corrections, None
        # Where the bound is checked: the leaves' test points, and every reference (the bisection
        # takes them as exact; pruning must not spoil them, also off a layout's sheet).
        checked = [(node, w) for node, _ in leaf_errors for w in points_in(node)]
        checked += [(-1, w) for w in tree.references[n_sources:]]
        return prune_corrections(tree, corrections, [w for _, w in checked], linear, exact, margin * epsilon,
                                 leaf=[node for node, _ in checked],
                                 progress=None if progress is None else
                                 lambda message, done, total: progress(message, tested + done, tested + total))

    def stored_error(corrections, path, w):
        """The hybrid's distance from the exact blend at ``w`` (``path``: its path_weights), with
        the corrections as stored."""
        H = np.asarray(linear(w), dtype=np.float64)
        for r, phi in path:
            H += phi * corrections.dense(r)
        return float(vector_lengths(H - exact(w)).max())

    bisect()
    corrections, worst = finished()
    check = {"points": 0, "error": float("nan"), "rounds": 0, "added": 0}
    if check_weights is not None and uniform_depth is None:
        check["points"] = len(check_weights)
        paths, errors, before = [None] * len(check_weights), np.zeros(len(check_weights)), None
        for round_ in range(check_rounds + 1):
            # A weight is measured again only if its path down the tree or a correction on it changed
            changed = changed_references(before, corrections)
            todo = []
            for k, w in enumerate(check_weights):
                path = path_weights(tree, w)
                if path != paths[k] or any(r in changed for r, _ in path):
                    paths[k] = path
                    todo.append(k)
            for done, k in enumerate(todo):
                errors[k] = stored_error(corrections, paths[k], check_weights[k])
                if progress is not None:
                    progress(f"checking between the test points: {done + 1} of {len(todo)}", tested + done + 1,
                             tested + len(todo))
            tested += len(todo)
            before = corrections
            check["rounds"] += 1
            check["error"] = float(errors.max(initial=0.0))
            failing = np.flatnonzero(errors > epsilon)
            if not len(failing) or round_ == check_rounds:
                break
            # The failing weights become test points; the leaves holding them are tested again
            # (their entries in leaf_errors go: bisect() records them anew)
            added = check_weights[failing]
            test_weights = np.concatenate([test_weights, added])
            check_weights = np.delete(check_weights, failing, axis=0)
            gone = set(failing.tolist())
            paths = [path for k, path in enumerate(paths) if k not in gone]
            errors = np.delete(errors, failing)
            check["added"] += len(failing)
            leaves = sorted({int(tree.locate(w)[0]) for w in added})
            leaf_errors = [(leaf, error) for leaf, error in leaf_errors if leaf not in leaves]
            queue.extend(leaves)
            bisect()
            corrections, worst = finished()
    if worst is not None:
        leaf_errors = [(node, worst.get(node, 0.0)) for node, _ in leaf_errors]
    new = len(tree.references) - n_sources
    report = HybridReport(
        epsilon=epsilon, references=new, leaves=len(tree.leaves()), max_depth=int(tree.depth.max()),
        max_test_error=float(np.nanmax([e for _, e in leaf_errors])) if uniform_depth is None else float("nan"),
        nonlinear_evaluations=evaluations,
        stored_fraction=float(len(corrections.vertex)) / max(1, new * n_phases * n_vertices),
        leaf_errors=leaf_errors, check_points=check["points"], max_check_error=check["error"],
        check_rounds=check["rounds"], check_added=check["added"])
    return tree, corrections, report


def changed_references(before, after):
    """References whose stored entries differ between two Corrections of one build (all of them
    when ``before`` is None; references ``before`` lacks count as changed).

    Both come from the same CorrectionBuilder, which only appends, pruned from it: a reference's
    values and scales are those it was stored with, so which of its entries are kept, per phase,
    is all that can differ."""
    if before is None:
        return set(range(after.n_references))
    P, changed = after.n_phases, set()
    for r in range(after.n_references):
        if r >= before.n_references:
            changed.add(r)
            continue
        a, b = before.pointer[r * P:(r + 1) * P + 1], after.pointer[r * P:(r + 1) * P + 1]
        if not (np.array_equal(a - a[0], b - b[0])
                and np.array_equal(before.vertex[a[0]:a[-1]], after.vertex[b[0]:b[-1]])):
            changed.add(r)
    return changed


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
