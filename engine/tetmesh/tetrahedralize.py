"""Tetrahedral mesh of the solid a captured surface bounds: a voxel lattice, deterministic."""

from __future__ import annotations

import itertools

import numpy as np

from ..holes import cap_holes
from ..surface import enclosed_volume, welded_faces
from ._validate import as_vertices
from .occupancy import grid_occupancy
from .tet_components import tet_components
from .tet_volumes import tet_volumes

# The lattice sits off the surface's own coordinates by an irrational fraction of a cell, so
# parity rays do not run exactly through vertices or along edges of axis-aligned models.
_OFFSET = np.array([0.2360679775, 0.4142135624, 0.7320508076])
# Kuhn (Freudenthal) split of the unit cube into 6 tets along its main diagonal: for each
# permutation (a, b, c) of the axes, 000 -> e_a -> e_a + e_b -> 111. Neighbouring cubes share
# the split of every common face, so the tets of any set of cubes form a conforming mesh.
_KUHN = np.array([[(0, 0, 0), tuple(int(i == a) for i in range(3)),
                   tuple(int(i in (a, b)) for i in range(3)), (1, 1, 1)]
                  for a, b, _ in itertools.permutations(range(3))])


def tetrahedralize(V, F, *, resolution=56, cell=None, max_cells=4000, min_inside=2):
    """Fill the solid bounded by a (possibly open) surface with a lattice of tetrahedra.

    Parameters
    ----------
    V : (n, 3) float array   surface vertices
    F : (m, 3) int array     triangles; holes and open boundaries are capped first, small
                             cracks and self-intersections are tolerated (three-axis vote)
    resolution : float       lattice cells along the model size (the largest bounding-box
                             extent); the default gives cells of 3.1 cm on a 1.75 m body
    cell : float or None     the cell edge length in the data's units, overriding resolution
                             and max_cells
    max_cells : int          cells are made larger when the solid would fill more than about
                             this many (a box fills its whole bounding box; a body ~15% of it)
    min_inside : int         a cell is solid when at least this many of its 8 sub-cell centres
                             are inside the surface (1-8; 2 keeps limbs down to ~half a cell)

    Returns
    -------
    V_tet : (k, 3) float64 array   lattice vertices used by some tet
    T : (t, 4) int64 array         tetrahedra (6 per solid cell), all positively oriented

    Raises
    ------
    ValueError
        Bad shapes, indices or coordinates, or a surface that encloses no cell.

    Notes
    -----
    Step 7 of DESIGN.md (Casas et al. 2012, section 4.1 blends per tetrahedron). The tet mesh
    follows the body's size, not the surface's vertex count: a 10k- or 50k-vertex capture of
    a body gets the same cells, and the surface rides on them through
    :func:`embed_barycentric`. Holes are capped (:func:`engine.holes.cap_holes`), the inside
    is found by ray parity on a grid twice as fine as the cells
    (:func:`grid_occupancy`), and solid cells are split into Kuhn tets. Tet components that
    no surface vertex is embedded in (a sliver cut off by the lattice) are dropped, so every
    component is held by the surface in a fit. Everything is plain arithmetic on the input:
    the same surface gives the same tets, byte for byte, and nothing is written anywhere.
    """
    V = as_vertices(V, "V")
    F = _faces(F, len(V))
    if not 1 <= int(min_inside) <= 8:
        raise ValueError(f"min_inside must be 1..8, got {min_inside}")
    size = float(np.max(V.max(axis=0) - V.min(axis=0)))
    if not size > 0:
        raise ValueError("V has no extent: every vertex is at the same place")
    V_capped, F_capped = cap_holes(V, _welded(V, F))
    if cell is not None:
        h = float(cell)
    else:
        volume = abs(float(enclosed_volume(V_capped, F_capped)))
        h = max(size / float(resolution), (volume / max(int(max_cells), 1)) ** (1.0 / 3.0))
    if not np.isfinite(h) or h <= 0 or size / h > 1000:
        raise ValueError(f"cell size {h} is not usable for a model of size {size}")
    lo = V.min(axis=0) - (1.0 + _OFFSET) * h
    cells = np.ceil((V.max(axis=0) + h - lo) / h).astype(np.int64)
    half = 0.5 * h
    inside = grid_occupancy(V_capped, F_capped, lo + 0.5 * half, half, 2 * cells)
    count = inside.reshape(cells[0], 2, cells[1], 2, cells[2], 2).sum(axis=(1, 3, 5))
    solid = np.argwhere(count >= int(min_inside))
    if len(solid) == 0:
        raise ValueError(f"the surface encloses no lattice cell of {h:.4g}: is it too thin, or open "
                         f"beyond what capping its holes can close?")
    corners = solid[:, None, None, :] + _KUHN[None]                    # (cells, 6, 4, 3)
    stride = np.array([(cells[1] + 1) * (cells[2] + 1), cells[2] + 1, 1])
    ids = (corners @ stride).reshape(-1, 4)
    used, T = np.unique(ids, return_inverse=True)
    T = T.reshape(-1, 4).astype(np.int64)
    grid = np.stack(np.unravel_index(used, cells + 1), axis=1)
    V_tet = lo + grid * h
    volume = tet_volumes(V_tet, T)
    flip = volume < 0
    T[flip] = T[flip][:, [0, 1, 3, 2]]
    return _held_components(V, V_tet, T)


def _welded(V, F):
    """The faces that bound the solid: as given, unless vertices repeat a place or faces repeat a
    triangle. An unwelded triangle soup (STL's way: three vertices of its own for every face)
    shares no edge, so capping takes every face for a hole; a surface saved twice over counts every
    crossing twice, so ray parity finds nothing inside. Then the faces are welded
    (:func:`engine.surface.welded_faces`: the vertices themselves are kept, and every one is still
    embedded), and of those, the ones that repeat a corner or another face's corners are left out."""
    welded = welded_faces(V, F)
    corners = np.sort(welded, axis=1)
    _, once = np.unique(corners, axis=0, return_index=True)
    if welded is F and len(once) == len(F):
        return F  # the usual case, left exactly as it was
    proper = (corners[:, 0] != corners[:, 1]) & (corners[:, 1] != corners[:, 2])
    keep = np.zeros(len(welded), dtype=bool)
    keep[once] = True
    return welded[keep & proper]


def _held_components(P, V_tet, T):
    """Drop tet components that no point of P is embedded in (they would float in a fit)."""
    from .embed_barycentric import tet_barycentric

    count, label = tet_components(T, len(V_tet))
    if count == 1:
        return V_tet, T
    tet_index, _, _ = tet_barycentric(P, V_tet, T)
    held = np.zeros(count, dtype=bool)
    held[label[T[tet_index, 0]]] = True
    keep = held[label[T[:, 0]]]
    used, T = np.unique(T[keep], return_inverse=True)
    return V_tet[used], T.reshape(-1, 4).astype(np.int64)


def _faces(F, n_vertices):
    """``F`` as (m, 3) int64 after checking shapes and indices (open surfaces are fine)."""
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        raise ValueError(f"F must be a non-empty (m, 3) array of triangles, got shape {F.shape}")
    if not np.issubdtype(F.dtype, np.integer):
        raise ValueError(f"F must hold integer vertex indices, got dtype {F.dtype}")
    F = F.astype(np.int64)
    if F.min() < 0 or F.max() >= n_vertices:
        raise ValueError(f"F indexes vertices outside 0..{n_vertices - 1}")
    return F
