"""Correspondences between the deforming root surface and a target frame's surface.

``TargetSurface(V, F, colors)`` prepares one frame once (normals, k-d trees, edge length,
centre); the functions here pair points of the moving surface with it: closest points with
compatible normals both ways, robust weights, colour cues and a capped fit cost. ``options`` is
an :class:`engine.align.pairwise.AlignmentOptions`.
"""

from __future__ import annotations

import numpy as np

from engine.align.appearance import GAIN_RANGE
from engine.align.colour_reach import reach_for_colour
from engine.align.compiled import closest_among_faces, colour_choice
from engine.align.shape_histogram import shape_centre
from engine.nearest import PointTree
from engine.surface import main_components, vertex_normals


class TargetSurface:
    """A frame's unstructured surface prepared for correspondence queries.

    Parameters
    ----------
    V : (m, 3) float array
    F : (l, 3) int array
    colors : (m, 3) float array in [0, 1] or None

    Small floating pieces (reconstruction fragments, :func:`engine.surface.main_components`)
    are left out, so they attract no matches.
    """

    def __init__(self, V, F, colors=None):
        V = np.asarray(V, dtype=np.float64)
        if V.ndim != 2 or V.shape[1] != 3 or len(V) < 4:
            raise ValueError(f"target vertices must have shape (m >= 4, 3), got {V.shape}")
        V, F, kept = main_components(V, F)
        self.V = np.ascontiguousarray(V)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        self.colors = None if colors is None else np.asarray(colors, dtype=np.float64)[kept]
        self.normals = vertex_normals(self.V, self.F)
        self.tree = PointTree(self.V)
        self.face_centres = self.V[self.F].mean(axis=1)
        self.face_tree = PointTree(self.face_centres)
        edges = self.V[self.F] - self.V[np.roll(self.F, 1, axis=1)]
        self.edge_length = float(np.mean(np.linalg.norm(edges, axis=2)))
        self.centre = shape_centre(self.V, self.F)

    def closest(self, P, k=6):
        """Closest points on the surface among the ``k`` faces with the nearest centres.

        Returns
        -------
        points : (q, 3) float array
        distance : (q,) float array
        faces : (q,) int array
        """
        points, distance, faces, _ = closest_points(np.asarray(P, dtype=np.float64), self.V, self.F,
                                                    self.face_tree, k=k)
        return points, distance, faces


def normal_cosine(options):
    """Cosine of ``options.max_normal_angle``: pairs whose normals agree less are incompatible."""
    return np.cos(np.radians(options.max_normal_angle))


def nearest_compatible(P, N, target, options):
    """Per point: the nearest target vertex with a compatible normal, projected to its plane.

    Returns
    -------
    q : (p, 3) foot of P on that vertex's tangent plane
    m : (p, 3) its normal
    d : (p,) distance to the vertex
    ok : (p,) bool, False when none of the nearest vertices is compatible
    """
    k = min(options.neighbours, len(target.V))
    d, idx = target.tree.query(P, k=k)
    d, idx = d.reshape(len(P), k), idx.reshape(len(P), k)
    compatible = np.einsum("pkc,pc->pk", target.normals[idx], N) > normal_cosine(options)
    masked = np.where(compatible, d, np.inf)
    j = np.argmin(masked, axis=1)
    rows = np.arange(len(P))
    ok = np.isfinite(masked[rows, j])
    v, m = target.V[idx[rows, j]], target.normals[idx[rows, j]]
    q = P - np.einsum("pc,pc->p", P - v, m)[:, None] * m
    return q, m, d[rows, j], ok


def correspondences(x, n, target, options, colors=None, labels=None, count=1, reach=None):
    """Correspondences of source points x (normals n) on the target surface.

    The closest surface point (exact, among the faces with the nearest centres) when its
    normal is compatible, otherwise the foot on the tangent plane of the nearest compatible
    vertex; robust weights from the distances (outliers get 0). With the root's ``colors``
    (n, 3) the matches also shift towards the target's matching colours (:func:`colour_flow`);
    with ``reach`` (the points' smoothed colours (p, 3), metres per unit of colour, the root's
    model size) those whose colour disagrees reach further
    (:func:`engine.align.colour_reach.reach_for_colour`).

    Returns
    -------
    y : (p, 3) target points        m : (p, 3) target normals there
    w : (p,) weights in [0, 1]      tangential : (p,) tangential weight (colour cues)
    d : (p,) distances
    """
    o = options
    y, m, d, ok, face, bary = compatible_closest(x, n, target, o)
    w = robust_weights(d, ok, labels, count, o.outlier_factor, 1.5 * target.edge_length)
    tangential = np.full(len(x), o.tangential_damping)
    if colors is not None:
        # Pairs of weight 0 drive nothing (the rigid steps and the solves weigh them by w), so
        # only the others look for colours: the same result for less work.
        used = np.flatnonzero(w > 0)
        source = colors[used]
        if o.colour_regions and len(used):   # the frame's exposure and white balance: the source as seen there
            there = np.einsum("pk,pkc->pc", bary[used], target.colors[target.F[face[used]]])
            gain = np.clip(there.sum(axis=0) / np.maximum(source.sum(axis=0), 1e-9), *GAIN_RANGE)
            source = np.clip(source * gain, 0.0, 1.0)
        flow, strength = colour_flow(y[used], m[used], face[used], bary[used], target, source, o)
        y[used] += flow
        tangential[used] += o.colour_weight * strength
        if reach is not None:
            y, m, replaced = reach_for_colour(x, y, m, w, tangential, target, *reach)
            d = np.where(replaced, np.linalg.norm(x - y, axis=1), d)
    return y, m, w, tangential, d


def correspondence_weights(x, n, target, options, labels=None, count=1):
    """The robust weights :func:`correspondences` gives x (normals n), without the matches' colour cues."""
    _, _, d, ok, _, _ = compatible_closest(x, n, target, options)
    return robust_weights(d, ok, labels, count, options.outlier_factor, 1.5 * target.edge_length)


def compatible_closest(x, n, target, options):
    """Closest target points of x, or where the normals disagree, the nearest compatible vertex's plane.

    Returns
    -------
    y : (p, 3) points    m : (p, 3) unit target normals there    d : (p,) distances
    ok : (p,) bool, a compatible pair was found    face : (p,) int    bary : (p, 3) in that face
    """
    y, d, face, bary = closest_points(x, target.V, target.F, target.face_tree)
    m = np.einsum("pk,pkc->pc", bary, target.normals[target.F[face]])
    m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-12)
    ok = np.einsum("pc,pc->p", m, n) > normal_cosine(options)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        q, mq, dq, okq = nearest_compatible(x[bad], n[bad], target, options)
        y[bad], m[bad], d[bad], ok[bad] = q, mq, dq, okq
    return y, m, d, ok, face, bary


def colour_flow(y, m, face, bary, target, colors, options):
    """Tangential shift towards where the target shows each source vertex's colour.

    Candidates are the current match y (colour interpolated in its face), the nearest
    target vertices and the midpoints towards them; each is scored by its colour distance
    to the source vertex's (root) colour plus a distance penalty, and the best one wins if
    it beats y clearly. A match whose colour already agrees does not move, so uniform
    regions and exact matches get no shift.

    Returns
    -------
    flow : (p, 3) tangential shifts
    strength : (p,) in [0, 1)   how much better the chosen colour agrees than y's
    """
    o = options
    h = target.edge_length
    k = min(o.neighbours, len(target.V))
    _, idx = target.tree.query(y, k=k)
    idx = idx.reshape(len(y), k)
    # candidates: y (its colour interpolated in its face), the k vertices, the k midpoints
    # towards them, scored one point at a time (engine.align.compiled.colour_choice)
    return colour_choice(y, m, face, bary, idx, target, colors, o.colour_sigma, 2.0 * h * h)


def reverse_correspondences(x, n, F, target, options, labels=None, count=1, subset=None):
    """Target vertices paired with their closest points on the current source surface (x, F).

    ``subset``: indices of the target vertices to pair (default all).

    Returns
    -------
    points : (t, 3) source surface points    labels_from : (t,) a source vertex of each
    y : (t, 3) target vertices                m : (t, 3) target normals
    w : (t,) weights
    """
    o = options
    tree = PointTree(x[F].mean(axis=1))
    TV = target.V if subset is None else target.V[subset]
    TN = target.normals if subset is None else target.normals[subset]
    points, d, face, bary = closest_points(TV, x, F, tree)
    normal = np.einsum("tk,tkc->tc", bary, n[F[face]])
    ok = np.einsum("tc,tc->t", normal, TN) > normal_cosine(o)
    vertex = F[face, np.argmax(bary, axis=1)]
    w = robust_weights(d, ok, None if labels is None else labels[vertex], count, o.outlier_factor,
                        1.5 * target.edge_length)
    return points, vertex, TV, TN, 0.5 * w


def sample_cost(P, N, target, options):
    """Robust fit cost per point: squared distance to the target, capped; incompatible = cap."""
    cap = options.search_cap
    q, m, d, ok = nearest_compatible(P, N, target, options)
    plane = np.abs(np.einsum("pc,pc->p", P - q, m))
    gap = np.where(ok, np.minimum(np.maximum(plane, 0.5 * d), cap), cap)
    return (gap / cap) ** 2


def robust_weights(d, ok, labels, count, factor, floor):
    """Tukey-style weights with an outlier limit of factor x the median distance per patch.

    Parameters
    ----------
    d : (p,) distances     ok : (p,) bool, pairs that passed the normal test
    labels : (p,) int patch of each pair, or None for one global limit
    count : int number of patches
    factor, floor : the limit is max(factor * median, floor)

    Returns
    -------
    w : (p,) float in [0, 1]
    """
    if labels is None:
        labels, count = np.zeros(len(d), dtype=np.int64), 1
    median = np.full(count, np.inf)
    good = np.flatnonzero(ok)
    if len(good):
        order = good[np.lexsort((d[good], labels[good]))]
        lab = labels[order]
        starts = np.searchsorted(lab, np.arange(count), side="left")
        stops = np.searchsorted(lab, np.arange(count), side="right")
        has = stops > starts
        middle = (starts + stops - 1) // 2
        median[has] = d[order[middle[has]]]
    limit = np.maximum(factor * median, floor)[labels]
    return np.where(ok & (d < limit), (1.0 - (np.minimum(d, limit) / limit) ** 2) ** 2, 0.0)


def project_onto(S, F, target):
    """Closest points of the surface S (n, 3) with faces F on the target, except where that
    would fold or collapse faces: vertices of faces whose normal turns by more than 60 degrees
    or whose area shrinks below a fifth keep their unprojected positions (a few millimetres off
    the surface). Returns (n, 3)."""
    V, _, _ = target.closest(S)
    before_n = np.cross(S[F[:, 1]] - S[F[:, 0]], S[F[:, 2]] - S[F[:, 0]])
    before_a = np.linalg.norm(before_n, axis=1)
    for _ in range(3):
        after_n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        after_a = np.linalg.norm(after_n, axis=1)
        cosine = np.einsum("fc,fc->f", before_n, after_n) / np.maximum(before_a * after_a, 1e-300)
        bad = (cosine < 0.5) | (after_a < 0.2 * before_a)
        if not bad.any():
            break
        keep = np.unique(F[bad])
        V[keep] = S[keep]
    return V


def closest_points(P, V, F, face_tree, k=6):
    """Closest points on a mesh among the k faces whose centres (in face_tree) are nearest.

    Returns
    -------
    points : (p, 3)   distance : (p,)   face : (p,)   bary : (p, 3)
    """
    k = min(k, len(F))
    _, faces = face_tree.query(P, k=k)
    return closest_among_faces(P, V, F, faces.reshape(len(P), k))


def point_to_mesh_distance(P, V, F, k=6):
    """Distance from points P to the closest of the k faces (of V, F) with the nearest centres."""
    return closest_points(P, V, F, PointTree(V[F].mean(axis=1)), k=k)[1]


__all__ = ["TargetSurface", "closest_points", "colour_flow", "compatible_closest", "project_onto",
           "correspondence_weights", "correspondences", "nearest_compatible",
           "normal_cosine", "point_to_mesh_distance", "reverse_correspondences", "robust_weights", "sample_cost"]
