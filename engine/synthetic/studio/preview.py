"""Preview pictures of studio sequences: what the true surface does, and what the studio made of it.

The reconstructions are drawn in their captured colours with the defects marked: faces on the
rim of a hole in red, floating fragments in magenta, surface more than a centimetre away from
any true surface (limbs merged where they touch, bridges over gaps) in blue.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from engine.surface import SurfaceQuery
from engine.synthetic.studio.reconstruct import contact_vertices

HOLE_RIM = np.array([0.9, 0.05, 0.05])
FRAGMENT = np.array([0.85, 0.1, 0.85])
MERGED = np.array([0.1, 0.3, 0.95])


def defect_colors(V, F, colors, V_true, F_true, contact, *, merged_distance=0.01):
    """Per-vertex colours marking hole rims, fragments and merged regions.

    Parameters
    ----------
    V, F, colors : a reconstructed frame (colors (k, 3) or None)
    V_true, F_true : the true surfaces of the same frame
    contact : (n,) bool array   true vertices in contact (``reconstruct.contact_vertices``)

    Returns
    -------
    colors : (k, 3) float array
    counts : dict   rim_vertices, fragment_vertices, merged_vertices
    """
    out = np.full((len(V), 3), 0.75) if colors is None else np.array(colors, dtype=float)
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    rim = np.unique(unique[counts == 1])
    A = sp.coo_matrix((np.ones(3 * len(F)), (F.ravel(), np.roll(F, 1, axis=1).ravel())), shape=(len(V),) * 2)
    labels = sp.csgraph.connected_components(A, directed=False)[1]
    main = np.argmax(np.bincount(labels[F[:, 0]]))
    fragment = labels != main
    _, faces, _, distance = SurfaceQuery(V_true, F_true, k=4).closest(V)
    merged = (distance > merged_distance) | contact[F_true[faces]].any(axis=1)
    out[merged & ~fragment] = MERGED
    out[rim] = HOLE_RIM
    out[fragment] = FRAGMENT
    return out, {"rim_vertices": int(len(rim)), "fragment_vertices": int(fragment.sum()),
                 "merged_vertices": int((merged & ~fragment).sum())}


def _tiles(meshes, titles, *, size, azimuth, elevation):
    """Render each mesh in its own square tile (so each fills its tile) side by side."""
    from engine.render import render_meshes

    return np.concatenate([render_meshes([m], azimuth=azimuth, elevation=elevation, width=size, height=size,
                                         title=t, ground=False) for m, t in zip(meshes, titles)], axis=1)


def studio_preview(name, body, vertices, picks, reconstructions, *, width=1400):
    """Preview image of one sequence.

    Parameters
    ----------
    name : str
    body : StudioBody
    vertices : (frames, n, 3) float array    true surfaces (truth frame: metres, Y up)
    picks : list of 4 int                    frames shown
    reconstructions : list of (V, F, colors) the reconstructed ``picks`` (truth frame)

    Returns
    -------
    image : (width, width, 3) uint8 array   the true surfaces (top row), their reconstructions
                                            with the defects marked (middle), a close-up of the
                                            frame with the most defects (bottom)
    """
    tile = width // len(picks)
    true = [(vertices[k], body.F, body.colors) for k in picks]
    marked, amount = [], []
    for k, (V, F, C) in zip(picks, reconstructions):
        colors, counts = defect_colors(V, F, C, vertices[k], body.F, contact_vertices(body.V, vertices[k]))
        marked.append((V, F, colors))
        amount.append(sum(counts.values()))
    top = _tiles(true, [f"{name} frame {k}: true surface" for k in picks], size=tile, azimuth=25.0, elevation=8.0)
    middle = _tiles(marked, [f"reconstruction ({len(m[0])} vertices)" for m in marked], size=tile,
                    azimuth=25.0, elevation=8.0)
    k = int(np.argmax(amount))
    bottom = _tiles([true[k], marked[k]], [f"frame {picks[k]}: true surface (body, skirt, sleeves)",
                                           "hole rims red, fragments magenta, merged contacts blue"],
                    size=width // 2, azimuth=35.0, elevation=25.0)
    rows = [top, middle, bottom]
    return np.concatenate([r[:, :width] if r.shape[1] >= width else
                           np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows])


def preview_frames(body, vertices, count=4, candidates=24):
    """Frames to show: the one with the most contact among evenly spread candidates, and others
    spread over the sequence (sorted)."""
    n = len(vertices)
    if n <= count:
        return list(range(n))
    pool = np.unique(np.linspace(0, n - 1, min(n, candidates)).round().astype(int))
    touching = [int(contact_vertices(body.V, np.asarray(vertices[k], dtype=float)).sum()) for k in pool]
    best = int(pool[int(np.argmax(touching))])
    spread = list(np.linspace(0, n - 1, count).round().astype(int))
    spread[int(np.argmin([abs(k - best) for k in spread]))] = best
    return sorted({int(k) for k in spread})
