"""Offscreen mesh pictures (no GPU): painter's-algorithm rasterisation with matplotlib.

Used for previews of generated captures, error heatmaps (paper figs. 3-4) and trails (figs. 7-8).
Returns RGB images as arrays; writing files is the caller's business.
"""

from __future__ import annotations

import numpy as np

from engine.rotations import rot_x, rot_y


def offscreen_figure(width, height, dpi=100):
    """An off-screen matplotlib figure of the given pixel size (Agg canvas, no pyplot state)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def render_meshes(meshes, *, azimuth=30.0, elevation=10.0, width=800, height=800, background=(1, 1, 1),
                  ground=True, title=None, colorbar=None):
    """Render one or more triangle meshes to an RGB image.

    Parameters
    ----------
    meshes : list of (V, F, colors)
        V (n, 3) float vertices, F (m, 3) int faces, colors (n, 3) per-vertex RGB in [0, 1],
        a single (3,) RGB, or None for grey.
    azimuth, elevation : float      camera angles in degrees (azimuth about +Y from +Z)
    width, height : int             image size in pixels
    ground : bool                   draw a ground grid at y = 0
    title : str or None
    colorbar : (cmap_name, vmin, vmax, label) or None   adds a colour bar

    Returns
    -------
    image : (height, width, 3) uint8 array
    """
    from matplotlib.collections import PolyCollection

    R = rot_x(np.radians(elevation)) @ rot_y(-np.radians(azimuth))
    light = np.array([0.3, 0.5, 1.0])
    light /= np.linalg.norm(light)
    polys, shades, depths = [], [], []
    all_points = []
    for V, F, colors in meshes:
        V = np.asarray(V, dtype=float)
        F = np.asarray(F, dtype=np.int64)
        P = V @ R.T
        all_points.append(P)
        tri = P[F]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-15)
        facing = n[:, 2] > 0
        tri, n = tri[facing], n[facing]
        if colors is None:
            base = np.full((len(tri), 3), 0.75)
        else:
            colors = np.asarray(colors, dtype=float)
            base = np.broadcast_to(colors, (len(tri), 3)) if colors.ndim == 1 else colors[F[facing]].mean(axis=1)
        lambert = 0.35 + 0.65 * np.clip(n @ light, 0.0, 1.0)
        polys.append(tri[:, :, :2])
        shades.append(np.clip(base * lambert[:, None], 0.0, 1.0))
        depths.append(tri[:, :, 2].mean(axis=1))
    polys = np.concatenate(polys)
    shades = np.concatenate(shades)
    order = np.argsort(np.concatenate(depths))
    fig = offscreen_figure(width, height)
    top = 0.92 if title else 1.0
    ax = fig.add_axes([0, 0, 1, top] if colorbar is None else [0, 0, 0.86, top])
    ax.set_facecolor(background)
    fig.patch.set_facecolor(background)
    points = np.concatenate(all_points)
    lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    if ground:
        _draw_ground(ax, R, np.concatenate([np.asarray(m[0]) for m in meshes]))
    ax.add_collection(PolyCollection(polys[order], facecolors=shades[order], edgecolors="none",
                                     antialiaseds=False))
    pad = 0.05 * max(hi - lo)
    span = max(hi - lo) / 2 + pad
    mid = (lo + hi) / 2
    aspect = (width if colorbar is None else 0.86 * width) / (top * height)
    ax.set_xlim(mid[0] - span * max(aspect, 1), mid[0] + span * max(aspect, 1))
    ax.set_ylim(mid[1] - span / min(aspect, 1), mid[1] + span / min(aspect, 1))
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        fig.text(0.5, 0.96, title, ha="center", va="center", fontsize=11)
    if colorbar is not None:
        import matplotlib as mpl

        cmap, vmin, vmax, label = colorbar
        cax = fig.add_axes([0.88, 0.15, 0.03, 0.7])
        mpl.colorbar.ColorbarBase(cax, cmap=mpl.colormaps[cmap],
                                  norm=mpl.colors.Normalize(vmin=vmin, vmax=vmax), label=label)
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    return image


def _draw_ground(ax, R, V):
    lo, hi = V.min(axis=0), V.max(axis=0)
    step = 0.5
    x0, x1 = np.floor(lo[0] / step - 1) * step, np.ceil(hi[0] / step + 1) * step
    z0, z1 = np.floor(lo[2] / step - 1) * step, np.ceil(hi[2] / step + 1) * step
    for x in np.arange(x0, x1 + 1e-9, step):
        seg = np.array([[x, 0, z0], [x, 0, z1]]) @ R.T
        ax.plot(seg[:, 0], seg[:, 1], color=(0.8, 0.8, 0.8), lw=0.6, zorder=0)
    for z in np.arange(z0, z1 + 1e-9, step):
        seg = np.array([[x0, 0, z], [x1, 0, z]]) @ R.T
        ax.plot(seg[:, 0], seg[:, 1], color=(0.8, 0.8, 0.8), lw=0.6, zorder=0)


def error_colors(errors, vmax, cmap="jet"):
    """Per-vertex RGB colours for an error heatmap (dark blue = 0, red = vmax).

    Parameters
    ----------
    errors : (n,) float array
    vmax : float   error mapped to the top of the colour map

    Returns
    -------
    colors : (n, 3) float array
    """
    import matplotlib as mpl

    t = np.clip(np.asarray(errors, dtype=float) / max(vmax, 1e-12), 0.0, 1.0)
    return mpl.colormaps[cmap](t)[:, :3]
