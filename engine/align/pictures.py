"""Pictures of the alignment's structure: the dissimilarity matrix and the similarity tree.

``similarity_image(D, lengths)`` is the paper's fig. 1c, ``tree_image(tree, lengths)`` its fig. 1d;
both return RGB arrays (writing files is the caller's business).
"""

from __future__ import annotations

import numpy as np

from engine.render import offscreen_figure


def similarity_image(D, lengths, names=None, *, size=900, title=None):
    """Picture of a dissimilarity matrix, blue = similar, red = dissimilar (paper fig. 1c).

    Parameters
    ----------
    D : (N, N) float array
    lengths : (S,) int array   frames per sequence, drawn as block boundaries
    names : list of str or None   sequence names for the axes
    size : int                 image width and height in pixels

    Returns
    -------
    image : (size, size, 3) uint8 array
    """
    D = np.asarray(D, dtype=np.float64)
    lengths = np.asarray(lengths, dtype=np.int64)
    fig = offscreen_figure(size, size)
    ax = fig.add_axes([0.16, 0.16, 0.72, 0.74])
    off = D[~np.eye(len(D), dtype=bool)] if len(D) > 1 else D.ravel()
    vmax = float(np.percentile(off, 98)) if off.size else 1.0
    shown = ax.imshow(D, cmap="jet", vmin=0.0, vmax=max(vmax, 1e-12), interpolation="nearest")
    bounds = np.cumsum(lengths)[:-1] - 0.5
    for b in bounds:
        ax.axhline(b, color="white", lw=0.6)
        ax.axvline(b, color="white", lw=0.6)
    if names is not None:
        centres = np.cumsum(lengths) - lengths / 2.0 - 0.5
        ax.set_xticks(centres)
        ax.set_xticklabels(names, rotation=90, fontsize=7)
        ax.set_yticks(centres)
        ax.set_yticklabels(names, fontsize=7)
    cax = fig.add_axes([0.9, 0.16, 0.025, 0.74])
    fig.colorbar(shown, cax=cax, label="dissimilarity")
    fig.text(0.5, 0.95, title or f"shape dissimilarity, {len(D)} frames", ha="center", fontsize=11)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()


def tree_image(tree, lengths, names=None, *, size=900, title=None):
    """Radial drawing of the tree, nodes coloured by sequence, root at the centre (paper fig. 1d).

    Parameters
    ----------
    tree : SimilarityTree
    lengths : (S,) int array     frames per sequence
    names : list of str or None  legend entries

    Returns
    -------
    image : (size, size, 3) uint8 array
    """
    import matplotlib as mpl
    from matplotlib.collections import LineCollection

    n = tree.n_frames
    sequence = np.repeat(np.arange(len(lengths)), lengths)
    children = tree.children()
    # Leaves get consecutive angles in depth-first order; inner nodes the mean of their children.
    leaves = np.zeros(n)
    angle = np.zeros(n)
    stack, visit = [tree.root], []
    while stack:
        node = stack.pop()
        visit.append(node)
        stack.extend(children[node][::-1].tolist())
    count = 0
    for node in visit:
        if len(children[node]) == 0:
            leaves[node] = count
            count += 1
    for node in visit[::-1]:
        angle[node] = leaves[node] if len(children[node]) == 0 else np.mean(angle[children[node]])
    theta = 2.0 * np.pi * angle / max(count, 1)
    radius = tree.depth.astype(float)
    xy = np.stack([radius * np.cos(theta), radius * np.sin(theta)], axis=1)
    fig = offscreen_figure(size, size)
    ax = fig.add_axes([0.02, 0.02, 0.96, 0.9])
    segments = np.stack([xy[tree.edges[:, 0]], xy[tree.edges[:, 1]]], axis=1) if len(tree.edges) else np.zeros((0, 2, 2))
    ax.add_collection(LineCollection(segments, colors=(0.55, 0.55, 0.55), linewidths=0.6, zorder=1))
    cmap = mpl.colormaps["tab20"]
    colors = cmap(sequence % 20)
    ax.scatter(xy[:, 0], xy[:, 1], s=9, c=colors, zorder=2, linewidths=0)
    ax.scatter(xy[tree.root, 0], xy[tree.root, 1], s=90, marker="*", c="black", zorder=3)
    span = max(1.0, float(radius.max()))
    ax.set_xlim(-1.05 * span, 1.05 * span)
    ax.set_ylim(-1.05 * span, 1.05 * span)
    ax.set_aspect("equal")
    ax.axis("off")
    if names is not None:
        handles = [mpl.lines.Line2D([], [], marker="o", ls="", color=cmap(i % 20), label=name)
                   for i, name in enumerate(names)]
        ax.legend(handles=handles, loc="upper left", fontsize=7, frameon=False, ncol=2)
    fig.text(0.5, 0.96, title or f"shape similarity tree: {n} frames, depth {int(tree.depth.max())}, "
             f"root {tree.root}", ha="center", fontsize=11)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()


__all__ = ["similarity_image", "tree_image"]
