"""The pictures of the blend evaluation: fig. 3 (one pose coloured by each method's error against
the non-linear blend) and figs. 5-6 (the hybrid's error threshold epsilon swept), as RGB arrays."""

from __future__ import annotations

import numpy as np

from engine.evaluation.table import LABELS, METHODS, BlendCache
from engine.render import error_colors, render_meshes


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
