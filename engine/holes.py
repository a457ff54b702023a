"""Holes in captured surfaces: boundary loops and caps.

Real reconstructions are open: soles, the top of the head and places where limbs touch come out
as holes whose count and shape change from frame to frame. ``loops = boundary_loops(F)`` finds
them; ``V_capped, F_capped = cap_holes(V, F)`` closes each with a fan about the loop's centroid,
so the solid the surface bounds (its volume, its inside) is defined, while the original vertices
and faces stay first and untouched (``F_capped[:len(F)] == F``).
"""

from __future__ import annotations

import numpy as np


def boundary_edges(F):
    """Directed edges (i, j) of faces whose twin (j, i) no face has.

    Parameters
    ----------
    F : (m, 3) int array

    Returns
    -------
    E : (b, 2) int64 array   in the faces' orientation, sorted by (i, j)
    """
    F = np.asarray(F, dtype=np.int64)
    if len(F) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    directed = np.stack([F, np.roll(F, -1, axis=1)], axis=-1).reshape(-1, 2)
    n = int(F.max()) + 1
    code = directed[:, 0] * n + directed[:, 1]
    twin = directed[:, 1] * n + directed[:, 0]
    open_ = ~np.isin(twin, code)
    E = np.unique(directed[open_], axis=0)
    return E


def boundary_loops(F):
    """The closed loops formed by the boundary edges of a surface.

    Parameters
    ----------
    F : (m, 3) int array

    Returns
    -------
    loops : list of (k,) int64 arrays   vertex indices in the faces' orientation, each loop
                                        once, deterministic order (by smallest edge)

    Notes
    -----
    Where a vertex has several outgoing boundary edges (two holes touching at a vertex, or a
    non-manifold rim), the walk takes them in index order; every boundary edge ends up in
    exactly one loop. Chains that do not close (inconsistent orientation) are returned as
    they are; a cap over them is still a fan about their centroid.
    """
    E = boundary_edges(F)
    if len(E) == 0:
        return []
    outgoing = {}
    for index, (i, _) in enumerate(E):
        outgoing.setdefault(int(i), []).append(index)
    used = np.zeros(len(E), dtype=bool)
    loops = []
    for start in range(len(E)):
        if used[start]:
            continue
        loop = []
        edge = start
        while edge is not None and not used[edge]:
            used[edge] = True
            i, j = int(E[edge, 0]), int(E[edge, 1])
            loop.append(i)
            edge = next((e for e in outgoing.get(j, ()) if not used[e]), None)
        loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def cap_holes(V, F, loops=None):
    """Close every boundary loop with a fan of triangles about its centroid.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array     faces, consistently oriented where the surface is manifold
    loops : list or None     :func:`boundary_loops` of F, when already known

    Returns
    -------
    V_capped : (n + h, 3) float64 array   V followed by one centroid per hole
    F_capped : (m + b, 3) int64 array     F followed by one triangle per boundary edge, each
                                          traversing its edge against the face beside it, so
                                          the caps continue the surface's orientation

    Notes
    -----
    A fan is not the minimal surface over a twisted hole, but it closes any loop, adds no
    vertex on the original surface and gives volume and inside tests a closed surface to
    work on; a planar hole (a cut sole, the top of a head) is capped exactly.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if loops is None:
        loops = boundary_loops(F)
    if not loops:
        return V.copy(), F.copy()
    centres = np.stack([V[loop].mean(axis=0) for loop in loops])
    caps = []
    for h, loop in enumerate(loops):
        c = len(V) + h
        nxt = np.roll(loop, -1)
        # the boundary edge i -> j belongs to a face; the cap uses it as j -> i
        caps.append(np.stack([nxt, loop, np.full(len(loop), c)], axis=1))
    return np.concatenate([V, centres]), np.concatenate([F, *caps])


def capped_volume(V, F, loops=None):
    """Volume enclosed by a surface once its holes are capped (:func:`cap_holes`).

    Parameters
    ----------
    V : (n, 3) or (frames, n, 3) float array
    F : (m, 3) int array
    loops : list or None   :func:`boundary_loops` of F

    Returns
    -------
    volume : float or (frames,) float array   positive for an outward-oriented surface
    """
    from engine.surface import enclosed_volume

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if loops is None:
        loops = boundary_loops(F)
    if not loops:
        return enclosed_volume(V, F)
    if V.ndim == 2:
        Vc, Fc = cap_holes(V, F, loops)
        return enclosed_volume(Vc, Fc)
    return np.array([capped_volume(frame, F, loops) for frame in V])
