"""Boundary triangles of a tetrahedral mesh."""

from __future__ import annotations

import numpy as np

# The faces of tet (a, b, c, d) opposite each vertex, ordered so that their normals point out
# of a positively oriented tet (see tet_volumes).
_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def boundary_faces(T):
    """Triangles that belong to exactly one tetrahedron, with the tet that owns each.

    Parameters
    ----------
    T : (t, 4) int array   tetrahedra, positively oriented (as :func:`tetrahedralize` returns)

    Returns
    -------
    F : (m, 3) int64 array       boundary triangles, normals pointing out of the solid
    tet_index : (m,) int64 array  the tet each triangle is a face of
    """
    T = np.asarray(T, dtype=np.int64)
    if T.ndim != 2 or T.shape[1] != 4:
        raise ValueError(f"T must have shape (t, 4), got {T.shape}")
    faces = T[:, _FACES].reshape(-1, 3)  # 4 faces per tet, tet i at rows 4i..4i+3
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    once = counts[inverse.ravel()] == 1
    return faces[once], np.flatnonzero(once) // 4
