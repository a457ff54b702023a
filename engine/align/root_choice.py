"""Choosing the root frame: central in the similarity tree, and with its limbs apart.

Every frame is aligned by deforming the root's mesh, so every frame inherits the root's surface
structure. A studio reconstruction merges limbs that touch (a hand on the hip, arms crossed, a
sleeve against the skirt); a root captured like that ties the hand to the hip in every aligned
frame, and where the hand leaves the hip the aligned surface cannot follow (studio dance: frames
105-126 aligned 2.4-7.3% of the model size off from frame 99, whose sleeves touch the skirt). The
most central frame of the tree (the paper's choice) is often exactly such a pose: a performer's
rest pose, hands on hips.

Merged contacts are short cuts on the surface: a walk along the surface from the hand to the
foot goes over the hip instead of up the arm and down the body. So a frame's *geodesic spread*
(the mean surface distance between well-spread sample points) drops when limbs merge, while
posing alone leaves surface distances nearly unchanged (a body bends almost isometrically). On
the first 200 frames of the studio dance the spread correlates at -0.71 with the true count of
merged contacts. :func:`choose_root` takes, among the frames nearly as central as the most
central one, the frame with the largest spread, less what it gives up in centrality: a frame
10% less central must spread 10% wider (``CENTRALITY_WEIGHT``), and no frame replaces the central
one unless it spreads at least 8% wider (``MIN_GAIN``): posing alone moves the spread by a few
per cent (on the tiny preset, whose procedural body merges nothing, the widest candidate spread
4% wider than the central frame and aligned worse from there: 1.06% mean error against 0.79%),
a merged hand or sleeve takes 10-16% off it. Depth costs too: rooted at the
least merged frame of those 200 (150: 30% less central, 149 frames deep) the alignment erred
more (3.78% mean) than from the central one (2.50%); the weight picks frame 105 there (0.5%
less central, spread 12% wider than the central frame 99, whose sleeves are merged with the
skirt), for any weight from 0.5 to 2 (docs/evaluation.md).

A contact merged with a gap beside it (a hand on the hip with the elbow out, a sleeve against
the skirt) also closes a loop on the surface: a handle, counted exactly from the Euler
characteristic (:func:`surface_handles`), where the spread drops only by what the short cut
saves. So only the candidates with at most ``HANDLE_SLACK`` handles more than the fewest are
chosen from, the most central of them standing for the central frame above. On the studio's
strikes (every 2nd frame) the spread alone took frame 164 (4 handles; its right sleeve merged
with the skirt, 7.2% off in every frame aligned from it, 1.32% mean), the handles frame 134
(none; 1.10% mean, docs/evaluation.md).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from engine.holes import cap_holes
from engine.surface import main_components

ROOT_SLACK = 0.35       # candidates: a tree centrality total at most this much above the best
ROOT_CANDIDATES = 64    # at most this many candidates (the most central ones)
SPREAD_SAMPLES = 48     # farthest-point samples per frame for the geodesic spread
CENTRALITY_WEIGHT = 1.0   # score = spread / central spread - weight * (total / best total - 1)
MIN_GAIN = 0.08         # the central frame stays the root unless a candidate spreads this much wider
HANDLE_SLACK = 1.0      # candidates have at most this many handles more than the fewest among them


def geodesic_spread(vertices, faces, *, samples=SPREAD_SAMPLES):
    """Mean surface (mesh-edge) distance between farthest-point samples of a frame.

    Parameters
    ----------
    vertices : (n, 3) float array
    faces : (m, 3) int array
    samples : int

    Returns
    -------
    float   in the mesh's units, over the main piece of the surface with its holes capped;
            pairs in different pieces count as 0 (a surface in pieces is no better a root than
            a merged one)
    """
    V, F, _ = main_components(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64))
    n = len(V)
    if n < 2 or len(F) == 0:
        return 0.0
    # walks cross the holes (over their caps), so a frame with holes is no better a root than a
    # whole one: a hole would otherwise lengthen the walks around it and look like limbs apart
    V_all, F_all = cap_holes(V, F)
    edges = np.concatenate([F_all[:, [0, 1]], F_all[:, [1, 2]], F_all[:, [2, 0]]])
    length = np.linalg.norm(V_all[edges[:, 0]] - V_all[edges[:, 1]], axis=1) + 1e-12
    graph = sp.csr_matrix((length, (edges[:, 0], edges[:, 1])), shape=(len(V_all), len(V_all)))
    picked = _farthest_points(V, min(int(samples), n))
    distance = dijkstra(graph, directed=False, indices=picked)[:, picked]
    distance[~np.isfinite(distance)] = 0.0
    k = len(picked)
    return float(distance.sum() / max(k * (k - 1), 1))


def surface_handles(vertices, faces):
    """How many handles (the genus) the main pieces of a reconstructed surface have.

    A body's surface is a sphere with holes: no handle. Where a reconstruction merges two parts
    that touch (a hand on the hip, a sleeve against the skirt) the surface closes a loop through
    the contact, one handle per merged contact (more where a long strip merges in several
    places). Counted from the Euler characteristic, ``chi = V - E + F = 2k - 2g - b`` over the
    ``k`` pieces, ``b`` the boundary loops (holes: the cycle rank of the boundary edges, so loops
    that touch at a vertex count apart). Non-manifold edges and vertices, which reconstructions
    leave here and there, move the count by a half or so; it is an estimate, not a proof.

    Returns
    -------
    float   ``g``; 0 for a closed or holed sphere, 1 for a torus
    """
    V, F, _ = main_components(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64))
    n = len(V)
    if n == 0 or len(F) == 0:
        return 0.0
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    unique, uses = np.unique(edges, axis=0, return_counts=True)
    pieces, _ = connected_components(sp.coo_matrix((np.ones(len(unique)), (unique[:, 0], unique[:, 1])),
                                                   shape=(n, n)), directed=False)
    chi = n - len(unique) + len(F)
    border = unique[uses == 1]
    loops = 0
    if len(border):
        on, local = np.unique(border, return_inverse=True)
        local = local.reshape(-1, 2)
        parts, _ = connected_components(sp.coo_matrix((np.ones(len(local)), (local[:, 0], local[:, 1])),
                                                      shape=(len(on), len(on))), directed=False)
        loops = len(border) - len(on) + parts
    return float(2 * pieces - chi - loops) / 2.0


def _farthest_points(V, count):
    """Deterministic Euclidean farthest-point samples, starting farthest from the centroid."""
    first = int(np.argmax(np.linalg.norm(V - V.mean(axis=0), axis=1)))
    picked = [first]
    nearest = np.linalg.norm(V - V[first], axis=1)
    for _ in range(count - 1):
        nxt = int(np.argmax(nearest))
        picked.append(nxt)
        nearest = np.minimum(nearest, np.linalg.norm(V - V[nxt], axis=1))
    return np.array(picked, dtype=np.int64)


def choose_root(meshes, centrality, *, slack=ROOT_SLACK, max_candidates=ROOT_CANDIDATES,
                centrality_weight=CENTRALITY_WEIGHT, min_gain=MIN_GAIN, samples=SPREAD_SAMPLES,
                handle_slack=HANDLE_SLACK, progress=None):
    """The root frame: nearly the most central, with the largest geodesic spread.

    Parameters
    ----------
    meshes : sequence of Mesh-like (vertices, faces)   all frames (the same units)
    centrality : (N,) float array   each frame's sum of tree path lengths to all frames
                                    (:func:`engine.align.similarity_tree.tree_centrality`)
    slack : float                   candidates have a total at most (1 + slack) times the best
    max_candidates : int            at most this many candidates, the most central first
    centrality_weight : float       trade of spread against centrality (see the module notes)
    min_gain : float                the most central frame stays the root unless a candidate's
                                    spread is at least (1 + min_gain) times its spread (posing
                                    alone moves the spread by a few per cent)
    samples : int                   see :func:`geodesic_spread`
    handle_slack : float or None    only candidates with at most this many handles
                                    (:func:`surface_handles`) more than the fewest of them are
                                    chosen, the most central of those taking the central
                                    frame's part above; None: handles are not counted
    progress : callable(done, total) or None

    Returns
    -------
    root : int
    report : dict   ``candidates`` (frame indices), ``spread`` (their spreads; NaN for those not
                    allowed by their handles, whose spread is not measured), ``handles`` (their
                    handles, None when not counted), ``allowed`` (the candidates' frames allowed by
                    their handles, most central first), ``score``, ``central`` (the most central frame)
    """
    centrality = np.asarray(centrality, dtype=np.float64)
    order = np.argsort(centrality, kind="stable")
    best_total = max(float(centrality[order[0]]), 1e-300)
    within = order[centrality[order] <= (1.0 + float(slack)) * best_total]
    candidates = within[:max(int(max_candidates), 1)]
    allowed = np.ones(len(candidates), dtype=bool)
    handles = None
    if handle_slack is not None:  # counted first (milliseconds): the spread's walks only for those allowed
        handles = np.array([surface_handles(meshes[f].vertices, meshes[f].faces) for f in candidates])
        allowed = handles <= handles.min() + float(handle_slack)
    spread = np.full(len(candidates), np.nan)
    for i, frame in enumerate(candidates):
        if allowed[i]:
            spread[i] = geodesic_spread(meshes[frame].vertices, meshes[frame].faces, samples=samples)
        if progress is not None:
            progress(i + 1, len(candidates))
    first = int(np.argmax(allowed))  # the most central allowed candidate (candidates[0] is the most central frame)
    central = max(float(spread[first]), 1e-300)
    score = spread / central - centrality_weight * (centrality[candidates] / best_total - 1.0)
    # the most central allowed frame keeps its own score; a wider one must beat it, its centrality paid
    narrow = spread < (1.0 + float(min_gain)) * central   # (NaN: not allowed, scored out below)
    narrow[first] = False
    score[narrow | ~allowed] = -np.inf
    root = int(candidates[int(np.argmax(score))])
    return root, {"candidates": candidates, "spread": spread, "handles": handles,
                  "allowed": [int(f) for f in candidates[allowed]], "score": score, "central": int(order[0])}


__all__ = ["HANDLE_SLACK", "choose_root", "geodesic_spread", "surface_handles"]
