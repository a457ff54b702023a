"""Accuracy and cost of mesh blending (Casas et al. 2012, section 4.2: Table I, figs. 3-6).

Every error is a per-vertex Euclidean distance in metres (reported in mm and in % of the space's
model size) against a reference:

- ``blend_errors``: linear, hybrid with 1 and 3 references, the space's own hybrid (to its
  epsilon) and non-linear blending against the exact non-linear blend, over a grid of weight
  vectors x all phase samples, plus the time per frame of each (Table I over a grid);
- ``heatmap_figure``: one pose coloured by that error, method by method (fig. 3);
- ``epsilon_sweep`` / ``sweep_figure``: the hybrid rebuilt for several epsilons: error, references,
  correction memory and corrected surface area (figs. 4-6);
- ``ground_truth_comparison``: beyond the paper, blends of synthetic gaits against the generator's
  own motion at the in-between parameters (``gait_truth``).

The non-linear blends at a weight vector are computed once per weight and shared through a
``BlendCache``, which also holds the hybrids built in memory. Nothing here reads or writes files;
figures are returned as RGB arrays.
"""

from __future__ import annotations

import contextlib
import itertools
import time

import numpy as np

from engine.blend import HybridBlender, build_hybrid, phase_of_sample, phase_samples
from engine.motion_space import SourceClip, warp_cycle_onto
from engine.render import error_colors, render_meshes
from engine.surface import enclosed_volume, lumped_mass
from engine.synthetic import animate, gait

METHODS = ("linear", "hybrid_1", "hybrid_3", "hybrid", "nonlinear")
LABELS = {"linear": "Linear", "hybrid_1": "Hybrid, 1 reference", "hybrid_3": "Hybrid, 3 references",
          "hybrid": "Hybrid to epsilon", "nonlinear": "Non-linear"}
UNIFORM_DEPTH = {"hybrid_1": 1, "hybrid_3": 2}  # the paper's "1 / 3 references" rows (two sources)
EPSILONS_MM = (1, 2, 3, 5, 8, 12, 20)


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
        """(P, n, 3) float64 non-linear blend at every phase sample."""
        key = _key(weights)
        if key not in self._exact:
            self._exact[key] = np.asarray(
                self.space.blender("nonlinear").blend_all_phases(np.array(key)), dtype=np.float64)
        return self._exact[key]

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

    def build_hybrid(self, *, epsilon=None, uniform_depth=None):
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
        tree, corrections, report = build_hybrid(self.linear, self.exact, s.n_sources, s.n_phases, s.n_vertices,
                                                 epsilon=epsilon, uniform_depth=uniform_depth)
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
    return {
        "space": space.name, "n_sources": space.n_sources, "n_phases": space.n_phases,
        "n_vertices": space.n_vertices, "model_size_m": space.model_size,
        "epsilon_mm": 1000.0 * space.metadata["epsilon"], "source_bytes": int(cache.sources.nbytes),
        "weights": W.tolist(), "phases": [float(p) for p in phase_list],
        "timing": {"calls": timing_calls, "nonlinear_calls": nonlinear_timing_calls, "single_threaded": single},
        "methods": methods,
    }


# ------------------------------------------------------------------------------------------------
# Figure 3: error heatmaps of one pose
# ------------------------------------------------------------------------------------------------

def pose_errors(space, weights, phase, *, cache=None):
    """Every method's blend at one pose and its per-vertex error vs the non-linear blend.

    Returns
    -------
    poses : dict   method -> (V (n, 3) float array, errors (n,) float array in metres)
    """
    cache = cache or BlendCache(space)
    w = space.check_weights(weights)
    exact = cache.exact_at(w, phase)
    poses = {}
    for method in METHODS:
        V = exact if method == "nonlinear" else np.asarray(cache.blender(method).blend(w, phase), dtype=float)
        poses[method] = (V, np.linalg.norm(V - exact, axis=1))
    return poses


def _canvas(width, height, dpi=100):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def _pixels(fig):
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()


def heatmap_figure(space, weights, phase, *, cache=None, azimuth=70.0, elevation=8.0, panel_width=300,
                   panel_height=520):
    """Fig. 3: the blended pose coloured by its error vs non-linear blending, method by method.

    Panels, left to right: linear, hybrid with 1 and 3 references, the space's hybrid (to its
    epsilon), non-linear. Colours run from dark blue (0) to red (the largest error of any panel,
    shared by all), with a colour bar in mm; each title gives the panel's maximum error.

    Parameters
    ----------
    space : MotionSpace
    weights : (N,) float array
    phase : float
    cache : BlendCache or None
    azimuth, elevation : float   camera (degrees; azimuth about +Y from +Z, 90 looks from the side)

    Returns
    -------
    image : (height, width, 3) uint8 array
    """
    cache = cache or BlendCache(space)
    poses = pose_errors(space, weights, phase, cache=cache)
    vmax = max(e.max() for _, e in poses.values())
    vmax_mm = max(1000.0 * vmax, 1e-3)
    F = np.asarray(space.faces)
    size = 1000.0 * space.model_size
    width = panel_width * len(METHODS) + 110
    fig = _canvas(width, panel_height + 70)
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    names = ", ".join(f"{n} {x:.2f}" for n, x in zip(space.source_names, w))
    fig.suptitle(f"{space.name}: error vs non-linear blend at weights ({names}), phase {phase:.3f}", fontsize=11)
    for i, method in enumerate(METHODS):
        V, e = poses[method]
        image = render_meshes([(V, F, error_colors(e, vmax))], azimuth=azimuth, elevation=elevation,
                              width=panel_width, height=panel_height)
        ax = fig.add_axes([i * panel_width / width, 0.0, panel_width / width, panel_height / (panel_height + 70)])
        ax.imshow(image)
        ax.axis("off")
        label = LABELS[method]
        if method == "hybrid":
            info = cache.info["hybrid"]
            label = f"Hybrid, epsilon {info['epsilon_mm']:g} mm ({info['references']} refs)"
        emax = 1000.0 * e.max()
        ax.set_title(f"{label}\nmax {emax:.2f} mm ({100 * emax / size:.2f}%)", fontsize=9)
    import matplotlib as mpl

    cax = fig.add_axes([(len(METHODS) * panel_width + 25) / width, 0.12, 18 / width, 0.7])
    mpl.colorbar.ColorbarBase(cax, cmap=mpl.colormaps["jet"], norm=mpl.colors.Normalize(0.0, vmax_mm),
                              label="error vs non-linear (mm)")
    return _pixels(fig)


# ------------------------------------------------------------------------------------------------
# Figures 4-6: the hybrid's error threshold epsilon
# ------------------------------------------------------------------------------------------------

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
    W = weight_grid(space.n_sources) if weights_list is None else np.asarray(weights_list, dtype=np.float64)
    if test_weights is None:
        test = np.full(space.n_sources, 1.0 / space.n_sources)
    else:
        test = space.check_weights(test_weights)
    area = vertex_areas(_rest(space), space.faces)
    rows = []
    for i, eps in enumerate(epsilons_mm):
        if eps <= 0:
            raise ValueError(f"epsilon must be positive, got {eps} mm")
        t0 = time.perf_counter()
        blender, tree, corrections, report = cache.build_hybrid(epsilon=eps / 1000.0)
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
            "build_s": build_s,
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


def sweep_figure(rows, *, uniform=None, title=None):
    """Figs. 5 and 6 from ``epsilon_sweep`` rows.

    (a) maximum error (mm, red) and corrected area (%, blue, right axis) against epsilon;
    (b) correction memory (MB) against epsilon; (c) maximum error against the number of
    references (and of uniform subdivisions when ``uniform`` is given).

    Parameters
    ----------
    rows : list of dict                 from ``epsilon_sweep``
    uniform : list of dict or None      from ``uniform_subdivision``
    title : str or None

    Returns
    -------
    image : (height, width, 3) uint8 array
    """
    eps = np.array([r["epsilon_mm"] for r in rows])
    err = np.array([r["max_error_mm"] for r in rows])
    fig = _canvas(1500, 480)
    axes = fig.subplots(1, 3)
    fig.subplots_adjust(left=0.05, right=0.97, bottom=0.13, top=0.84, wspace=0.38)
    if title:
        fig.suptitle(title, fontsize=12)
    a = axes[0]
    lines = a.plot(eps, err, "o-", color="tab:red", label="max error")
    lines += a.plot(eps, eps, ":", color="grey", label="error = epsilon")
    a.set_xlabel("epsilon (mm)")
    a.set_ylabel("max error vs non-linear (mm)", color="tab:red")
    a.tick_params(axis="y", colors="tab:red")
    a.set_ylim(bottom=0)
    b = a.twinx()
    lines += b.plot(eps, [r["corrected_area_percent"] for r in rows], "s-", color="tab:blue",
                    label="corrected area")
    b.legend(lines, [line.get_label() for line in lines], loc="center right", fontsize=8)
    b.set_ylabel("corrected area (%)", color="tab:blue")
    b.tick_params(axis="y", colors="tab:blue")
    b.set_ylim(0, max(5.0, 1.1 * max(r["corrected_area_percent"] for r in rows)))
    a.set_title("(a) error and corrected area vs epsilon (fig. 5)", fontsize=10)
    c = axes[1]
    c.plot(eps, [r["correction_mb"] for r in rows], "o-", color="tab:purple")
    for r in rows:
        c.annotate(f"{r['references']} refs", (r["epsilon_mm"], r["correction_mb"]), textcoords="offset points",
                   xytext=(4, 4), fontsize=7)
    c.set_xlabel("epsilon (mm)")
    c.set_ylabel("correction memory (MB)")
    c.set_ylim(bottom=0)
    c.set_title("(b) memory of the corrections D_NL vs epsilon (fig. 6b)", fontsize=10)
    d = axes[2]
    refs = np.array([r["references"] for r in rows])
    d.plot(refs, err, "o", color="tab:red", label="hybrid to epsilon")
    for r in rows:
        d.annotate(f"{r['epsilon_mm']:g} mm", (r["references"], r["max_error_mm"]), textcoords="offset points",
                   xytext=(4, 4), fontsize=7)
    if uniform:
        d.plot([u["references"] for u in uniform], [u["max_error_mm"] for u in uniform], "s--", color="tab:green",
               label="uniform subdivision (depth 1, 2, ...)")
    d.xaxis.get_major_locator().set_params(integer=True)
    d.set_xlim(left=-0.5)
    d.set_xlabel("references (non-linear reference meshes)")
    d.set_ylabel("max error vs non-linear (mm)")
    d.set_ylim(bottom=0)
    d.legend(fontsize=8)
    d.set_title("(c) max error vs number of references (fig. 6a)", fontsize=10)
    for ax in axes:
        ax.grid(alpha=0.3)
    return _pixels(fig)


# ------------------------------------------------------------------------------------------------
# Beyond the paper: blends against the generator's ground truth
# ------------------------------------------------------------------------------------------------

def gait_truth(body, speeds, *, turn_rates=None, fps=30.0, start_phases=None):
    """The generator's true motion for weights of a space of synthetic gaits.

    Parameters
    ----------
    body : Body
    speeds : (N,) float array         each source's speed (m/s)
    turn_rates : (N,) float or None   each source's turn rate (deg/s; default straight)
    fps : float
    start_phases : (N,) float or None gait phase of each source's first cycle frame (0 = left
                                      heel strike); default 0

    Returns
    -------
    true_motion : callable(weights) -> Motion
        the gait at speed sum_i w_i v_i (turn rate likewise), starting at the weighted mean
        start phase, one cycle plus two frames long (``gait(..., cycles=1 + 2 / N)``)
    """
    speeds = np.asarray(speeds, dtype=np.float64)
    turns = np.zeros_like(speeds) if turn_rates is None else np.asarray(turn_rates, dtype=np.float64)
    starts = np.zeros_like(speeds) if start_phases is None else np.asarray(start_phases, dtype=np.float64)
    starts = (starts + 0.5) % 1.0 - 0.5  # circular mean about the heel strike

    def true_motion(weights):
        w = np.asarray(weights, dtype=np.float64)
        w = w / w.sum()
        speed, turn, start = float(w @ speeds), float(w @ turns), float(w @ starts) % 1.0
        return gait(body.skeleton, speed, turn_rate=turn, fps=fps, cycles=2.0, start_phase=start)

    return true_motion


def true_samples(space, body, motion):
    """(P, n, 3) a true cyclic motion put on the space's phase grid exactly like its sources:
    root-local, one cycle, key poses aligned to the space's first source (``warp_cycle_onto``)."""
    V = animate(body, motion)
    clip = SourceClip(name=motion.name, vertices=V, fps=motion.fps, cyclic=True,
                      frames_per_cycle=motion.frames_per_cycle)
    rest = np.asarray(space.container["rest"])
    return warp_cycle_onto(clip, np.asarray(space.faces, dtype=np.int64), rest,
                           np.asarray(space.sources[:, 0], dtype=np.float64))


def _edges(F):
    """(e, 2) unique undirected edges of a triangle mesh."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return np.unique(np.sort(E, axis=1), axis=0)


def _truth_errors(V, T, F, E):
    """How (P, n, 3) frames V differ from true frames T: positions, edge lengths, volume."""
    e = np.linalg.norm(V - T, axis=2)
    length = np.linalg.norm(V[:, E[:, 0]] - V[:, E[:, 1]], axis=2)
    true_length = np.linalg.norm(T[:, E[:, 0]] - T[:, E[:, 1]], axis=2)
    volume, true_volume = enclosed_volume(V, F), enclosed_volume(T, F)
    return {"mean_mm": 1000.0 * float(e.mean()), "max_mm": 1000.0 * float(e.max()),
            "edge_error_percent": 100.0 * float(np.abs(length - true_length).sum() / true_length.sum()),
            "volume_error_percent": 100.0 * float(np.mean(np.abs(volume - true_volume) / true_volume))}


_RATIOS = {"ratio_mean": "mean_mm", "ratio_max": "max_mm", "ratio_edge": "edge_error_percent",
           "ratio_volume": "volume_error_percent"}


def _add_ratios(entry):
    if "linear" in entry and "nonlinear" in entry:
        for ratio, key in _RATIOS.items():
            entry[ratio] = entry["linear"][key] / max(entry["nonlinear"][key], 1e-12)


def ground_truth_comparison(space, body, true_motion_fn, weights_list=None, *,
                            methods=("linear", "hybrid", "nonlinear"), cache=None, progress=None):
    """Blends against the true motion the generator makes at the in-between parameters.

    Parameters
    ----------
    space : MotionSpace                built from synthetic cyclic captures of ``body``
    body : Body                        the generator's body (same vertices as the space)
    true_motion_fn : callable(weights) -> Motion   e.g. ``gait_truth``; at the unit weights it
                                       must reproduce the sources
    weights_list : (k, N) or None      default 0.25/0.5/0.75 (two sources) or ``weight_grid(N, 2)``
    methods : sequence of str          among ``METHODS``
    cache : BlendCache or None
    progress : callable(stage, done, total) or None

    Returns
    -------
    result : dict
        sources: per source, how well its true motion reproduces it (a check of the set-up:
        near zero) and the root offset found. rows: per weight vector, for each method over all
        phase samples: mean_mm and max_mm per-vertex distance, edge_error_percent (summed
        |edge length - true edge length| over summed true lengths) and volume_error_percent
        (mean |enclosed volume - true volume| / true volume); ratio_mean, ratio_max, ratio_edge,
        ratio_volume = linear / non-linear of each. summary: means over the rows (max for
        max_mm) and their ratios.

    Notes
    -----
    The sources sit on the phase grid in their own root frame, which may keep a horizontal
    offset (where the root was at the cycle's first frame). The offset c_i of each source is
    measured against its true motion and the target of a blend is the true motion at the blended
    parameters moved by sum_i w_i c_i, the offset of every blend of the sources.
    The true motion may differ from every blend (cadence, duty factor and stride change with
    speed in ways no blend of two gaits reproduces): positions measure that as well, while edge
    lengths and volume measure the shape alone, where linear blending's shrinking of rotating
    limbs shows.
    """
    progress = progress or _noop
    cache = cache or BlendCache(space, progress)
    N = space.n_sources
    if len(body.V) != space.n_vertices:
        raise ValueError(f"{space.name}: the body has {len(body.V)} vertices, the space {space.n_vertices}")
    if weights_list is None:
        weights_list = (np.array([[0.75, 0.25], [0.5, 0.5], [0.25, 0.75]]) if N == 2 else weight_grid(N, 2))
    W = np.asarray(weights_list, dtype=np.float64)
    F = np.asarray(space.faces, dtype=np.int64)
    E = _edges(F)
    sources = np.asarray(cache.sources, dtype=np.float64)
    offsets, report_sources = [], []
    for i in range(N):
        truth = true_samples(space, body, true_motion_fn(np.eye(N)[i]))
        offset = (sources[:, i] - truth).reshape(-1, 3).mean(axis=0)
        offset[1] = 0.0
        offsets.append(offset)
        report_sources.append({"name": space.source_names[i], "offset_m": offset.tolist(),
                               **_truth_errors(sources[:, i], truth + offset, F, E)})
        progress("ground truth", i + 1, N + len(W))
    offsets = np.array(offsets)
    rows = []
    for k, w in enumerate(W):
        w = w / w.sum()
        motion = true_motion_fn(w)
        target = true_samples(space, body, motion) + w @ offsets
        row = {"weights": w.tolist(),
               "params": {key: motion.params[key] for key in ("speed", "turn_rate") if key in motion.params}}
        for method in methods:
            row[method] = _truth_errors(cache.blend(method, w), target, F, E)
        _add_ratios(row)
        rows.append(row)
        progress("ground truth", N + k + 1, N + len(W))
    summary = {m: {key: float(np.max([r[m][key] for r in rows]) if key == "max_mm" else
                              np.mean([r[m][key] for r in rows])) for key in rows[0][m]} for m in methods}
    _add_ratios(summary)
    return {"space": space.name, "sources": report_sources, "rows": rows, "summary": summary}


__all__ = [
    "METHODS", "LABELS", "EPSILONS_MM", "BlendCache", "weight_grid", "time_per_frame", "blend_errors", "pose_errors",
    "heatmap_figure", "vertex_areas", "corrected_vertices", "epsilon_sweep", "uniform_subdivision", "sweep_figure",
    "gait_truth", "true_samples", "ground_truth_comparison",
]
