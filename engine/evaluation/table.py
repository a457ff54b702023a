"""Table I over a weight grid (Casas et al. 2012, section 4.2): every method's error against the
exact non-linear blend and its time per frame, and the ``BlendCache`` the other evaluations share
(each non-linear blend computed once, hybrids built in memory)."""

from __future__ import annotations

import contextlib
import functools
import itertools
import time

import numpy as np

from engine.blend import HybridBlender, build_hybrid, phase_of_sample, phase_samples

METHODS = ("linear", "hybrid_1", "hybrid_3", "hybrid", "nonlinear")
LABELS = {"linear": "Linear", "hybrid_1": "Hybrid, 1 reference", "hybrid_3": "Hybrid, 3 references",
          "hybrid": "Hybrid to epsilon", "nonlinear": "Non-linear"}
UNIFORM_DEPTH = {"hybrid_1": 1, "hybrid_3": 2}  # the paper's "1 / 3 references" rows (two sources)


def _key(weights):
    w = np.asarray(weights, dtype=np.float64)
    return tuple(np.round(w / w.sum(), 12))


def _noop(stage, done, total):
    pass


def weight_grid(n_sources, level=None):
    """Blend weights on a barycentric grid, without the sources themselves.

    Parameters
    ----------
    n_sources : int
    level : int or None   grid steps per edge (default 10 for two sources, else 4)

    Returns
    -------
    W : (k, N) float array   rows sum to 1; for two sources and level 10: 0.1, 0.2, ..., 0.9

    Notes
    -----
    Points on the simplex's edges and faces are kept (blends of some of the sources); only the
    N unit vectors are left out, where every method is exact.
    """
    level = int(level or (10 if n_sources == 2 else 4))
    n = int(n_sources)
    points = [head + (level - sum(head),) for head in itertools.product(range(level + 1), repeat=n - 1)
              if sum(head) <= level]
    points = [p for p in points if max(p) < level]
    return np.asarray(points, dtype=np.float64)[::-1] / level


SHEET_RESOLUTION = {1: 17, 2: 5}  # points per layout axis where blend_errors also measures the sheet


def _single_thread():
    """Context that limits BLAS/OpenMP pools to one thread, and whether it could."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext(), False
    return threadpool_limits(1), True


class BlendCache:
    """Exact non-linear blends of a space, each computed once, and hybrids built in memory.

    ``cache = BlendCache(space)``; ``cache.exact(w)`` is the (P, n, 3) non-linear blend at every
    phase sample; ``cache.blender(method)`` is a blender for any of ``METHODS``.

    Parameters
    ----------
    space : MotionSpace
    progress : callable(stage, done, total) or None   told about hybrid builds
    """

    def __init__(self, space, progress=None):
        self.space = space
        self.progress = progress or _noop
        self.phases = np.array([phase_of_sample(p, space.n_phases, space.cyclic) for p in range(space.n_phases)])
        self.sources = np.ascontiguousarray(space.sources, dtype=np.float32)
        self._exact = {}
        self._blenders = {}
        self.info = {}  # method -> {"references", "depth", "correction_bytes", "epsilon_mm"}

    def exact(self, weights):
        """(P, n, 3) float64 non-linear blend at every phase sample (kept for the whole run)."""
        key = _key(weights)
        if key not in self._exact:
            self._exact[key] = self._nonlinear(key)
        return self._exact[key]

    def _nonlinear(self, key):
        return np.asarray(self.space.blender("nonlinear").blend_all_phases(np.array(key)), dtype=np.float64)

    @property
    def blends_kept(self):
        """How many weights' non-linear blends the cache holds (those ``exact`` was asked for)."""
        return len(self._exact)

    def _exact_unkept(self, weights):
        """``exact(weights)`` from the cache when it is there, else computed and not kept."""
        key = _key(weights)
        return self._exact[key] if key in self._exact else self._nonlinear(key)

    def exact_at(self, weights, phase):
        """(n, 3) non-linear blend at any phase (from the cache at phase samples)."""
        p0, _, a = phase_samples(phase, self.space.n_phases, self.space.cyclic)
        if a == 0.0:
            return self.exact(weights)[p0]
        w = np.asarray(weights, dtype=np.float64)
        return np.asarray(self.space.blender("nonlinear").blend(w, phase), dtype=np.float64)

    def linear(self, weights):
        """(P, n, 3) float64 linear blend at every phase sample."""
        return self.space.blender("linear").blend_all_phases(weights)

    @functools.cached_property
    def sheet(self):
        """(M, N) weights on the layout's sheet for a space of 3 or more sources with a layout (where
        parameters lead, and where ``build`` bounds its hybrid), else None (two sources: the sheet
        is every blend)."""
        pmap = self.space.parameter_map
        if pmap is None or self.space.n_sources <= 2:
            return None
        from engine.parameters.sheet import sheet_weights

        return sheet_weights(pmap.layout, SHEET_RESOLUTION[pmap.layout.dims])

    def build_hybrid(self, *, epsilon=None, uniform_depth=None, test_weights=None):
        """A hybrid of this space rebuilt in memory (``engine.blend.build_hybrid``).

        Returns
        -------
        blender : HybridBlender
        tree : SimplexTree
        corrections : Corrections
        report : HybridReport
        """
        s = self.space
        if epsilon is None:
            epsilon = s.metadata["epsilon"]
        # the bisection's many test weights are not kept here: build_hybrid holds its own blends in a
        # bounded cache (this unbounded one held 22 GB of them on a 3-source space)
        tree, corrections, report = build_hybrid(self.linear, self._exact_unkept, s.n_sources, s.n_phases,
                                                 s.n_vertices, epsilon=epsilon, uniform_depth=uniform_depth,
                                                 test_weights=test_weights)
        return HybridBlender(self.sources, tree, corrections, s.cyclic), tree, corrections, report

    def blender(self, method):
        """The blender of ``method`` (one of ``METHODS``), built once."""
        if method not in METHODS:
            raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
        if method not in self._blenders:
            s = self.space
            if method in UNIFORM_DEPTH:
                self.progress(f"build {method}", 0, 1)
                blender, tree, corrections, report = self.build_hybrid(uniform_depth=UNIFORM_DEPTH[method])
                self.progress(f"build {method}", 1, 1)
                self.info[method] = {"references": report.references, "depth": report.max_depth,
                                     "correction_bytes": int(corrections.nbytes()), "epsilon_mm": None}
            else:
                mode = "hybrid" if method == "hybrid" else method
                blender = s.blender(mode)
                if method == "hybrid":
                    self.info[method] = {"references": len(s.tree.references) - s.n_sources,
                                         "depth": int(s.tree.depth.max()),
                                         "correction_bytes": int(s.corrections.nbytes()),
                                         "epsilon_mm": 1000.0 * s.metadata["epsilon"]}
                else:
                    self.info[method] = {"references": 0, "depth": 0, "correction_bytes": 0, "epsilon_mm": None}
            self._blenders[method] = blender
        return self._blenders[method]

    def blend(self, method, weights):
        """(P, n, 3) float64 blend of ``method`` at every phase sample, through ``blender.blend``."""
        if method == "nonlinear":
            return self.exact(weights)
        return _at_phases(self.blender(method), weights, self.phases)


def _at_phases(blender, weights, phases):
    """(len(phases), n, 3) float64 blends through ``blender.blend``."""
    w = np.asarray(weights, dtype=np.float64)
    return np.stack([np.asarray(blender.blend(w, ph), dtype=np.float64) for ph in phases])


def _grid_errors(cache, blender, weights_list):
    """(k, P, n) per-vertex errors of ``blender`` vs the non-linear blend, weights x phase samples."""
    return np.stack([np.linalg.norm(_at_phases(blender, w, cache.phases) - cache.exact(w), axis=2)
                     for w in weights_list])


def time_per_frame(blender, n_sources, n_vertices, *, calls=200, seed=0):
    """Median seconds of ``blender.blend(w, phase, out)`` at random weights and phases.

    Weights are uniform on the simplex, phases uniform in [0, 1) (between phase samples), run
    single-threaded when threadpoolctl is installed.

    Returns
    -------
    seconds : float
    single_threaded : bool
    """
    rng = np.random.default_rng(seed)
    W = rng.dirichlet(np.ones(n_sources), size=calls + 3)
    phases = rng.uniform(0.0, 1.0, size=calls + 3)
    out = np.empty((n_vertices, 3), dtype=np.float32)
    limit, single = _single_thread()
    times = np.empty(calls)
    with limit:
        for k in range(3):  # warm-up: caches, first factorisation touches
            blender.blend(W[k], phases[k], out=out)
        for k in range(calls):
            t0 = time.perf_counter()
            blender.blend(W[k + 3], phases[k + 3], out=out)
            times[k] = time.perf_counter() - t0
    return float(np.median(times)), single


def blend_errors(space, weights_list=None, phases=None, *, cache=None, timing_calls=200, nonlinear_timing_calls=40,
                 seed=0, progress=None):
    """Table I over a weight grid: error vs the non-linear blend and time per frame, per method.

    Parameters
    ----------
    space : MotionSpace
    weights_list : (k, N) float array or None   default ``weight_grid(N)``
    phases : sequence of float or None          default every phase sample
    cache : BlendCache or None                  share non-linear blends with the other evaluations
    timing_calls, nonlinear_timing_calls : int  calls timed per method (median reported)
    seed : int                                  random weights and phases of the timing
    progress : callable(stage, done, total) or None

    Returns
    -------
    result : dict
        ``methods[m]`` for m in ``METHODS``: max_error_mm, max_error_percent, mean_error_mm,
        mean_error_percent, worst_weights, worst_phase, references, depth, correction_bytes,
        epsilon_mm, time_per_frame_ms, frames_per_second; plus the space's sizes, the weights
        and phases used and whether timing was single-threaded.

    Notes
    -----
    Errors are per-vertex Euclidean distances to ``space.blender("nonlinear")`` at the same
    weights and phase (the paper's "maximum vertex displacement error", section 4.2), the
    maximum and mean taken over every vertex, weight vector and phase.
    """
    progress = progress or _noop
    cache = cache or BlendCache(space, progress)
    W = weight_grid(space.n_sources) if weights_list is None else np.asarray(weights_list, dtype=np.float64)
    if W.ndim != 2 or W.shape[1] != space.n_sources:
        raise ValueError(f"{space.name}: weights must be (k, {space.n_sources}), got shape {W.shape}")
    W = np.stack([space.check_weights(w) / w.sum() for w in W])
    phase_list = cache.phases if phases is None else np.asarray(phases, dtype=np.float64)
    for k, w in enumerate(W):
        cache.exact(w)
        progress("non-linear blends", k + 1, len(W))

    def at_phases(method, w):
        if phases is None:
            return cache.blend(method, w)
        if method == "nonlinear":
            return np.stack([cache.exact_at(w, ph) for ph in phase_list])
        return _at_phases(cache.blender(method), w, phase_list)

    methods = {}
    for i, method in enumerate(METHODS):
        blender = cache.blender(method)
        e = np.stack([np.linalg.norm(at_phases(method, w) - at_phases("nonlinear", w), axis=2) for w in W])
        k, p, _ = np.unravel_index(np.argmax(e), e.shape)  # (weights, phase, vertex) of the largest error
        worst, mean = float(e.max()), float(e.mean())
        calls = nonlinear_timing_calls if method == "nonlinear" else timing_calls
        seconds, single = time_per_frame(blender, space.n_sources, space.n_vertices, calls=calls, seed=seed)
        methods[method] = {
            "label": LABELS[method], **cache.info[method],
            "max_error_mm": 1000.0 * worst, "max_error_percent": 100.0 * worst / space.model_size,
            "mean_error_mm": 1000.0 * mean, "mean_error_percent": 100.0 * mean / space.model_size,
            "worst_weights": W[k].tolist(), "worst_phase": float(phase_list[p]),
            "time_per_frame_ms": 1000.0 * seconds, "frames_per_second": 1.0 / seconds,
        }
        progress("methods", i + 1, len(METHODS))
    sheet, S = None, cache.sheet
    if S is not None:
        # where the player goes: the layout's sheet, where the space's hybrid was built to its
        # epsilon (the grid above also holds blends no parameter reaches)
        sheet = {"weights": len(S)}
        for method in ("linear", "hybrid"):
            e = max(float(np.linalg.norm(cache.blend(method, w) - cache.exact(w), axis=2).max()) for w in S)
            sheet[method] = {"max_error_mm": 1000.0 * e, "max_error_percent": 100.0 * e / space.model_size}
        progress("layout's sheet", 1, 1)
    return {
        "sheet": sheet,
        "space": space.name, "n_sources": space.n_sources, "n_phases": space.n_phases,
        "n_vertices": space.n_vertices, "model_size_m": space.model_size,
        "epsilon_mm": 1000.0 * space.metadata["epsilon"], "source_bytes": int(cache.sources.nbytes),
        "weights": W.tolist(), "phases": [float(p) for p in phase_list],
        "timing": {"calls": timing_calls, "nonlinear_calls": nonlinear_timing_calls, "single_threaded": single},
        "methods": methods,
    }
