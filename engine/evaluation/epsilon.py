"""Figures 4-6 of the paper, as numbers: the hybrid rebuilt for several error thresholds epsilon
(error, references, correction memory, corrected surface area) and at uniform subdivision depths."""

from __future__ import annotations

import time

import numpy as np

from engine.evaluation.table import BlendCache, _grid_errors, _noop, weight_grid
from engine.surface import lumped_mass

EPSILONS_MM = (1, 2, 3, 5, 8, 12, 20)


def vertex_areas(V, F):
    """(n,) area per vertex: a third of the area of each incident triangle."""
    return lumped_mass(np.asarray(V, dtype=float), np.asarray(F, dtype=np.int64)).diagonal()


def corrected_vertices(tree, corrections, weights, p, n_vertices):
    """Vertices a hybrid blend corrects at ``weights`` and phase sample ``p``.

    Returns
    -------
    mask : (n,) bool array

    Notes
    -----
    Walks the simplex tree like ``HybridBlender.blend``: a split node contributes its stored
    residual entries wherever its hat function phi = 2 min(lambda_i, lambda_j) is positive.
    """
    lam = np.asarray(weights, dtype=np.float64)
    lam = lam / lam.sum()
    children, split, refs = tree.children, tree.split, tree.split_references()
    mask = np.zeros(n_vertices, dtype=bool)
    node = 0
    while children[node, 0] >= 0:
        i, j = split[node]
        li, lj = lam[i], lam[j]
        if min(li, lj) > 0.0:
            vertex, _, _ = corrections.entries(refs[node], p)
            mask[vertex] = True
        if li >= lj:
            lam[i], lam[j] = li - lj, 2.0 * lj
            node = children[node, 0]
        else:
            lam[j], lam[i] = lj - li, 2.0 * li
            node = children[node, 1]
    return mask


def _rest(space):
    names = getattr(space.container, "names", ())
    return np.asarray(space.container["rest"]) if "rest" in names else np.asarray(space.sources[0, 0])


def epsilon_sweep(space, epsilons_mm=EPSILONS_MM, *, weights_list=None, test_weights=None, cache=None,
                  progress=None):
    """The hybrid rebuilt for each error threshold epsilon (figs. 4-6).

    Parameters
    ----------
    space : MotionSpace
    epsilons_mm : sequence of float
    weights_list : (k, N) float array or None   where the error is measured (default ``weight_grid``)
    test_weights : (N,) float array or None     the pose interpolation of the corrected-area
                                                measure (fig. 5; default equal weights)
    cache : BlendCache or None
    progress : callable(stage, done, total) or None

    Returns
    -------
    rows : list of dict, one per epsilon:
        epsilon_mm, max_error_mm, max_error_percent, mean_error_mm, references, depth, leaves,
        correction_bytes, correction_mb (10^6 bytes), correction_percent (of the sources' bytes),
        corrected_area_percent, build_s

    Notes
    -----
    The corrected area is the area-weighted share of the surface where the hybrid adds a
    non-zero correction at ``test_weights``, averaged over the phase samples; a vertex's area is
    a third of the area of its triangles in the rest mesh.
    """
    progress = progress or _noop
    cache = cache or BlendCache(space, progress)
    sheet = cache.sheet   # a layout of 3 or more sources: rebuilt and measured on its sheet, as `build` builds it
    if weights_list is not None:
        W = np.asarray(weights_list, dtype=np.float64)
    else:
        W = weight_grid(space.n_sources) if sheet is None else sheet
    if test_weights is None:
        if sheet is None:
            test = np.full(space.n_sources, 1.0 / space.n_sources)
        else:   # a quarter along each layout axis: between sources (the sheet's middle may be a source)
            layout = space.parameter_map.layout
            test = np.asarray(layout.weights([0.25] * layout.dims), dtype=np.float64)
    else:
        test = space.check_weights(test_weights)
    area = vertex_areas(_rest(space), space.faces)
    rows = []
    progress("epsilon sweep", 0, len(epsilons_mm))   # shown from the start: a build may take minutes
    for i, eps in enumerate(epsilons_mm):
        if eps <= 0:
            raise ValueError(f"epsilon must be positive, got {eps} mm")
        t0 = time.perf_counter()
        blender, tree, corrections, report = cache.build_hybrid(epsilon=eps / 1000.0, test_weights=sheet)
        build_s = time.perf_counter() - t0
        e = _grid_errors(cache, blender, W)
        share = [area[corrected_vertices(tree, corrections, test, p, space.n_vertices)].sum() / area.sum()
                 for p in range(space.n_phases)]
        nbytes = int(corrections.nbytes())
        rows.append({
            "epsilon_mm": float(eps), "max_error_mm": 1000.0 * float(e.max()),
            "max_error_percent": 100.0 * float(e.max()) / space.model_size,
            "mean_error_mm": 1000.0 * float(e.mean()), "references": report.references, "depth": report.max_depth,
            "leaves": report.leaves, "correction_bytes": nbytes, "correction_mb": nbytes / 1e6,
            "correction_percent": 100.0 * nbytes / cache.sources.nbytes,
            "corrected_area_percent": 100.0 * float(np.mean(share)), "test_weights": test.tolist(),
            "build_s": build_s, "on": "simplex" if sheet is None else "sheet", "weights": len(W),
        })
        progress("epsilon sweep", i + 1, len(epsilons_mm))
    return rows


def uniform_subdivision(space, depths=(1, 2, 3), *, weights_list=None, cache=None):
    """Hybrids with every cell split to a fixed depth, nothing dropped (fig. 6a's subdivisions).

    Returns
    -------
    rows : list of dict   depth, references, max_error_mm and mean_error_mm over ``weights_list``
                          (default ``weight_grid``) x all phase samples, correction_bytes
    """
    cache = cache or BlendCache(space)
    W = weight_grid(space.n_sources) if weights_list is None else np.asarray(weights_list, dtype=np.float64)
    rows = []
    for depth in depths:
        blender, _, corrections, report = cache.build_hybrid(uniform_depth=int(depth))
        e = _grid_errors(cache, blender, W)
        rows.append({"depth": int(depth), "references": report.references,
                     "max_error_mm": 1000.0 * float(e.max()), "mean_error_mm": 1000.0 * float(e.mean()),
                     "correction_bytes": int(corrections.nbytes())})
    return rows
