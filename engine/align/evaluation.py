"""Scoring aligned mesh sequences against ground truth, and pattern renders (paper fig. 2).

Synthetic captures know where every template vertex is in every frame
(``template_positions``). A root-mesh vertex is located on the template surface of the root
frame (face and barycentric coordinates); its true position in any other frame is the same
point of that frame's template surface. The correspondence error of an aligned vertex is its
distance from there. Errors are reported in % of the model size (DESIGN.md).
"""

from __future__ import annotations

import numpy as np

from engine.align.facing import body_facing
from engine.rotations import rot_y
from engine.surface import SurfaceQuery


def surface_coordinates(P, V, F):
    """Where points lie on a surface: closest face and barycentric coordinates.

    Parameters
    ----------
    P : (n, 3) float array   points near the surface (e.g. the root mesh's vertices)
    V : (m, 3) float array   the surface at the same instant (e.g. the template at the root frame)
    F : (l, 3) int array

    Returns
    -------
    faces : (n,) int array
    bary : (n, 3) float array
    distance : (n,) float array   how far each point was from the surface
    """
    points, faces, bary, distance = SurfaceQuery(V, F).closest(np.asarray(P, dtype=np.float64))
    return faces, bary, distance


def true_positions(template_positions, F, faces, bary):
    """Positions (frames, n, 3) of surface points given by (faces, bary) in every frame.

    Parameters
    ----------
    template_positions : (frames, m, 3) float array
    F : (l, 3) int array       template faces
    faces : (n,) int array, bary : (n, 3) float array
    """
    corners = np.asarray(template_positions)[:, F[faces]]  # (frames, n, 3, 3)
    return np.einsum("nk,fnkc->fnc", bary, corners)


def correspondence_errors(aligned, truth):
    """Per-vertex distances (frames, n) between aligned and true positions."""
    return np.linalg.norm(np.asarray(aligned, dtype=np.float64) - np.asarray(truth, dtype=np.float64), axis=-1)


def error_summary(errors, model_size):
    """Mean, 95th percentile and max of errors, in metres and in % of the model size.

    Parameters
    ----------
    errors : array of distances (any shape)
    model_size : float

    Returns
    -------
    summary : dict  mean_mm, p95_mm, max_mm, mean_pct, p95_pct, max_pct
    """
    e = np.asarray(errors, dtype=np.float64).ravel()
    if e.size == 0:
        raise ValueError("no errors to summarise")
    mean, p95, top = float(e.mean()), float(np.percentile(e, 95)), float(e.max())
    scale = 100.0 / model_size
    return {"mean_mm": 1000 * mean, "p95_mm": 1000 * p95, "max_mm": 1000 * top,
            "mean_pct": scale * mean, "p95_pct": scale * p95, "max_pct": scale * top}


def score_alignment(aligned, root, root_vertices, truth, template_faces, model_size):
    """Correspondence errors of aligned frames against ground truth.

    Parameters
    ----------
    aligned : (N, n, 3) float array        every frame in the root's topology (frames of all
                                           sequences concatenated)
    root : int                             index of the root frame
    root_vertices : (n, 3) float array     the root mesh as captured
    truth : (N, m, 3) float array          template vertex positions in every frame, same order
    template_faces : (l, 3) int array
    model_size : float                     metres (errors are also given in % of it)

    Returns
    -------
    errors : (N, n) float array   per frame and root vertex, metres
    summary : dict                error_summary over all frames but the root
    """
    aligned = np.asarray(aligned, dtype=np.float64)
    truth = np.asarray(truth)
    if aligned.shape[0] != truth.shape[0]:
        raise ValueError(f"{aligned.shape[0]} aligned frames but ground truth for {truth.shape[0]}")
    faces, bary, _ = surface_coordinates(root_vertices, truth[root], template_faces)
    errors = np.empty(aligned.shape[:2])
    for start in range(0, len(aligned), 64):  # bounded memory
        stop = min(start + 64, len(aligned))
        errors[start:stop] = correspondence_errors(aligned[start:stop],
                                                   true_positions(truth[start:stop], template_faces, faces, bary))
    others = np.ones(len(aligned), dtype=bool)
    others[root] = False
    return errors, error_summary(errors[others] if others.any() else errors, model_size)


def nearest_template_vertices(root_vertices, truth_root, template_faces):
    """The template vertex each root vertex lies nearest to on the true surface of the root frame
    (the corner of its closest face with the largest barycentric weight): (n,) int array."""
    faces, bary, _ = surface_coordinates(root_vertices, truth_root, template_faces)
    return np.asarray(template_faces)[faces, np.argmax(bary, axis=1)]


def part_labels(root_vertices, truth_root, template_faces, part_counts):
    """The template part (0, 1, ...) each root vertex lies on.

    Parameters
    ----------
    root_vertices : (n, 3) float array   the root mesh as aligned
    truth_root : (m, 3) float array      the template at the root frame
    template_faces : (l, 3) int array
    part_counts : dict name -> int        the template's vertices part by part, in order

    Returns
    -------
    labels : (n,) int array   index into ``list(part_counts)``
    """
    nearest = nearest_template_vertices(root_vertices, truth_root, template_faces)
    bounds = np.cumsum([0] + [int(c) for c in part_counts.values()])
    return np.searchsorted(bounds, nearest, side="right") - 1


def part_errors(errors, root, root_vertices, truth, template_faces, part_counts, model_size):
    """Error summaries per part of the body (the body, a skirt, each sleeve ...).

    Parameters
    ----------
    errors : (N, n) float array    from :func:`score_alignment`
    root, root_vertices, truth, template_faces : as for :func:`score_alignment`
    part_counts : dict name -> int   the template's vertices part by part, in order (a studio
                                     manifest's ``body.parts``)
    model_size : float

    Returns
    -------
    dict name -> dict   ``error_summary`` of the root vertices that lie on that part (over all
                        frames but the root) and ``vertices``, how many there are
    """
    label = part_labels(root_vertices, truth[root], template_faces, part_counts)
    others = np.ones(len(errors), dtype=bool)
    others[root] = False
    out = {}
    for k, name in enumerate(part_counts):
        mine = label == k
        if mine.any():
            summary = error_summary(errors[others][:, mine] if others.any() else errors[:, mine], model_size)
            out[name] = {"vertices": int(mine.sum()), **{key: round(v, 4) for key, v in summary.items()}}
    return out


def pattern_colors(V, *, period=0.1, facing=None):
    """A checker fixed on a mesh's rest positions (paper fig. 2 style).

    The checker is projected from the body's own front (cells of ``period`` across the body
    and up, about the middle of its bounding box), so it forms clean squares on the body,
    with one colour pair on the body's right half (yellow / blue: the left of a front view)
    and another on its left (red / green): a cell that slides shows a correspondence error, a
    limb of the other side's colours a swap.

    Parameters
    ----------
    V : (n, 3) float array   rest (root) vertex positions (metres, +Y up)
    period : float           cell size in metres
    facing : (3,) array or None   the way the body faces (default:
                                  :func:`engine.align.facing.body_facing` of ``V``); for a body
                                  facing +Z the cells are squares in x and y

    Returns
    -------
    colors : (n, 3) float array in [0, 1]   a function of the rest positions only, so every
                                            aligned frame shows where each root point went
    """
    V = np.asarray(V, dtype=np.float64)
    facing = body_facing(V) if facing is None else np.asarray(facing, dtype=np.float64)
    left = np.array([facing[2], 0.0, -facing[0]]) / max(np.hypot(facing[0], facing[2]), 1e-300)  # up x facing
    across = V @ left
    x = across - 0.5 * (across.min() + across.max())
    y = V[:, 1] - 0.5 * (V[:, 1].min() + V[:, 1].max())
    checker = (np.floor(x / period).astype(np.int64) + np.floor(y / period).astype(np.int64)) % 2
    side = (x > 0).astype(np.int64)
    palette = np.array([[0.98, 0.80, 0.25], [0.20, 0.35, 0.80],   # body's right: yellow / blue
                        [0.90, 0.30, 0.35], [0.25, 0.65, 0.45]])  # body's left: red / green
    return palette[2 * side + checker].copy()


def pattern_render(frames, F, colors, *, columns=3, size=1100, title=None, azimuth=20.0, facing=None):
    """Render aligned frames on a grid with per-vertex colours fixed on the root mesh.

    Parameters
    ----------
    frames : list of (n, 3) float arrays   aligned vertex positions (root topology), up to
                                           2 * columns of them
    F : (m, 3) int array
    colors : (n, 3) float array            e.g. :func:`pattern_colors` of the root
    columns : int                          frames per row (two rows)
    size : int                             image width and height in pixels
    facing : (3,) array or None            the direction to show from the front (``azimuth``
                                           degrees aside): every frame is turned about +Y by
                                           the one rotation taking it to +Z (default: +Z, as is)

    Returns
    -------
    image : (size, size, 3) uint8 array
    """
    from engine.render import render_meshes

    frames = [np.asarray(V, dtype=np.float64) for V in frames[:2 * columns]]
    if facing is not None:
        turn = rot_y(-np.arctan2(facing[0], facing[2]))  # facing -> +Z
        frames = [V @ turn.T for V in frames]
    width = 1.05 * max(max(float(np.ptp(V[:, 0])) for V in frames), 0.55)
    height = 1.15 * max(float(np.ptp(V[:, 1])) for V in frames)
    meshes = []
    for i, V in enumerate(frames):
        row, column = divmod(i, columns)
        centre = V.mean(axis=0)
        offset = np.array([column * width - centre[0], -row * height - V[:, 1].min(), -centre[2]])
        meshes.append((V + offset, F, colors))
    return render_meshes(meshes, azimuth=azimuth, elevation=8.0, width=size, height=size, title=title,
                         ground=False)


def pattern_frames(lengths, count=6):
    """Indices of ``count`` frames spread over the sequences (for :func:`pattern_sheet`).

    Frames are taken round-robin from the sequences, each sequence's picks spread evenly over
    its interior, so a sheet shows as many different motions as it has room for; with more
    sequences than frames, sequences spread evenly over the list are used.
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    total = int(lengths.sum())
    count = min(int(count), total)
    if len(lengths) > count > 0:
        keep = np.unique(np.linspace(0, len(lengths) - 1, count).round().astype(int))
        lengths, starts = lengths[keep], starts[keep]
    per = -(-count // max(len(lengths), 1))
    lists = [[int(s + k) for k in np.linspace(0, n - 1, per + 2)[1:-1].round().astype(int)] if n > 2
             else [int(s + k) for k in range(n)] for s, n in zip(starts, lengths)]
    picks = []
    for rank in range(per):
        picks.extend(lst[rank] for lst in lists if rank < len(lst))
    picks = list(dict.fromkeys(picks))[:count]
    for extra in np.linspace(0, total - 1, count).round().astype(int):  # short sequences: top up
        if len(picks) >= count:
            break
        if int(extra) not in picks:
            picks.append(int(extra))
    return picks


def pattern_sheet(vertices, faces, root, lengths, names=None, *, count=6, title=None, size=1100):
    """Paper fig. 2 analogue: the root mesh and aligned frames, all wearing one pattern.

    The pattern (:func:`pattern_colors`) is a function of the root mesh's vertex positions; every
    aligned frame shares the root's vertices and faces, so the colours travel with the
    correspondence: a stripe or checker that stays on the same body part in every frame shows
    the alignment holds, a smeared or jumping one shows where it slipped. The pattern's sides
    and the view follow the root's own facing (:func:`engine.align.facing.body_facing`): the
    frames are shown turned so that the root faces the camera.

    Parameters
    ----------
    vertices : (N, n, 3) float array   aligned frames (root topology, sequences concatenated)
    faces : (m, 3) int array
    root : int                         the root frame (shown first)
    lengths : (S,) int array           frames per sequence
    names : list of str or None        sequence names (for the title)
    count : int                        frames shown besides the root (the grid has 3 columns)

    Returns
    -------
    image : (size, size, 3) uint8 array
    """
    vertices = np.asarray(vertices)
    facing = body_facing(vertices[root])
    colors = pattern_colors(vertices[root], facing=facing)
    picks = [k for k in pattern_frames(lengths, count + 1) if k != root][:count]
    frames = [vertices[root]] + [vertices[k] for k in picks]
    if title is None:
        sequence_of = np.repeat(np.arange(len(lengths)), lengths)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        label = (lambda k: f"{names[sequence_of[k]]}:{k - starts[sequence_of[k]]}") if names else str
        title = (f"pattern fixed on the root mesh ({label(root)}, first), carried by the alignment into\n"
                 + ", ".join(label(k) for k in picks))
    columns = max(1, -(-len(frames) // 2))
    return pattern_render(frames, faces, colors, columns=columns, size=size, title=title, facing=facing)


__all__ = ["correspondence_errors", "score_alignment", "error_summary", "nearest_template_vertices", "part_errors",
           "part_labels", "pattern_colors",
           "pattern_frames",
           "pattern_render", "pattern_sheet",
           "surface_coordinates", "true_positions"]
