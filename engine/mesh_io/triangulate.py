"""Fan triangulation of polygon faces (quads, n-gons) as read from OBJ, PLY and OFF files."""

from __future__ import annotations

import numpy as np


def fan_triangulate(indices, counts):
    """Split each polygon into a fan of triangles around its first corner.

    Parameters
    ----------
    indices : (total,) int array   corners of all polygons, concatenated in file order
    counts : (p,) int array        corners per polygon, each >= 3, summing to total

    Returns
    -------
    F : (sum(counts - 2), 3) int64 array
        Polygon (c0, c1, ..., ck) becomes (c0, c1, c2), (c0, c2, c3), ..., (c0, ck-1, ck), so
        triangles keep the polygon's winding and appear in polygon order.

    Notes
    -----
    Exact (area-preserving) for convex and star-shaped-from-c0 polygons, which covers the quads
    and n-gons of scanned and modelled meshes; a strongly concave n-gon can come out with
    overlapping triangles.
    """
    indices = np.asarray(indices, dtype=np.int64)
    counts = np.asarray(counts, dtype=np.int64)
    if len(counts) == 0:
        return np.empty((0, 3), dtype=np.int64)
    if counts.min() == counts.max() == 3:
        return indices.reshape(-1, 3)
    triangles_per_polygon = counts - 2
    polygon = np.repeat(np.arange(len(counts)), triangles_per_polygon)
    first_corner = (np.cumsum(counts) - counts)[polygon]
    first_triangle = np.cumsum(triangles_per_polygon) - triangles_per_polygon
    k = np.arange(len(polygon)) - first_triangle[polygon] + 1
    return np.stack(
        [indices[first_corner], indices[first_corner + k], indices[first_corner + k + 1]], axis=1
    )


def first_out_of_range(indices, counts, n_vertices):
    """Locate the first polygon corner whose vertex index is outside [0, n_vertices).

    Parameters
    ----------
    indices : (total,) int array   corners of all polygons, concatenated
    counts : (p,) int array        corners per polygon
    n_vertices : int

    Returns
    -------
    found : (polygon, index) tuple of int, or None when every index is in range
    """
    indices = np.asarray(indices)
    if len(indices) == 0 or (indices.min() >= 0 and indices.max() < n_vertices):
        return None
    corner = int(np.flatnonzero((indices < 0) | (indices >= n_vertices))[0])
    polygon = int(np.searchsorted(np.cumsum(counts), corner, side="right"))
    return polygon, int(indices[corner])
