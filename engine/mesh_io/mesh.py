"""The `Mesh` record returned by every reader, and the checks every mesh passes through.

A `Mesh` is always valid when it exists: construction normalises dtypes and raises
`MeshValidationError` for an empty mesh, a non-finite coordinate, a face index out of range or
colours outside [0, 1]. Degenerate faces (a vertex index repeated within a triangle) are legal
and reported as warnings by `validate_mesh`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import MeshValidationError


def check_vertices(V, source):
    """Return `V` as an (n, 3) float64 array with finite entries, or raise.

    Parameters
    ----------
    V : (n, 3) array_like   vertex positions
    source : str            file name used as the message prefix

    Returns
    -------
    V : (n, 3) float64 array   (no copy when already float64)
    """
    try:
        V = np.asarray(V, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise MeshValidationError(f"{source}: vertices are not numeric ({err})") from err
    if V.ndim != 2 or V.shape[1] != 3:
        raise MeshValidationError(f"{source}: vertices must have shape (n, 3), got {V.shape}")
    if len(V) == 0:
        raise MeshValidationError(f"{source}: the mesh is empty (0 vertices)")
    finite = np.isfinite(V).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        value = V[bad[0]][~np.isfinite(V[bad[0]])][0]
        more = f" ({len(bad) - 1} more vertices have one too)" if len(bad) > 1 else ""
        raise MeshValidationError(
            f"{source}: vertex {bad[0]} has a non-finite coordinate ({value}){more}"
        )
    return V


def check_faces(F, n_vertices, source):
    """Return `F` as an (m, 3) int64 array of in-range vertex indices, or raise.

    Parameters
    ----------
    F : (m, 3) integer array_like   triangles, 0-based vertex indices
    n_vertices : int                number of vertices the indices refer to
    source : str                    file name used as the message prefix

    Returns
    -------
    F : (m, 3) int64 array   (no copy when already int64)
    """
    F = np.asarray(F)
    if F.size == 0 and F.dtype.kind not in "iu":
        F = F.astype(np.int64)  # an empty list arrives as float64
    if F.dtype.kind not in "iu":
        raise MeshValidationError(f"{source}: faces must be integers, got dtype {F.dtype}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise MeshValidationError(f"{source}: faces must have shape (m, 3), got {F.shape}")
    if len(F) == 0:
        raise MeshValidationError(f"{source}: the mesh is empty (0 faces)")
    if F.dtype == np.uint64 and F.max() > np.iinfo(np.int64).max:
        raise MeshValidationError(f"{source}: face index {F.max()} is out of range")
    F = F.astype(np.int64, copy=False)
    if F.min() < 0 or F.max() >= n_vertices:
        bad = (F < 0) | (F >= n_vertices)
        face = int(np.flatnonzero(bad.any(axis=1))[0])
        index = int(F[face][bad[face]][0])
        raise MeshValidationError(
            f"{source}: face {face} references vertex {index} "
            f"but the mesh has {n_vertices} vertices"
        )
    return F


def check_colors(colors, n_vertices, source, *, leading=()):
    """Return per-vertex colours as float32 in [0, 1], or None.

    Parameters
    ----------
    colors : (*leading, n, 3) array_like or None   RGB in [0, 1]
    n_vertices : int
    source : str
    leading : tuple of int   expected leading dimensions, e.g. (frames,) for a sequence

    Returns
    -------
    colors : (*leading, n, 3) float32 array or None
    """
    if colors is None:
        return None
    try:
        colors = np.asarray(colors, dtype=np.float32)
    except (TypeError, ValueError) as err:
        raise MeshValidationError(f"{source}: colours are not numeric ({err})") from err
    expected = (*leading, n_vertices, 3)
    if colors.shape != expected:
        raise MeshValidationError(
            f"{source}: colours must have shape {expected} (one RGB per vertex), "
            f"got {colors.shape}"
        )
    if not np.isfinite(colors).all() or colors.min() < 0.0 or colors.max() > 1.0:
        raise MeshValidationError(f"{source}: colours must be finite and within [0, 1]")
    return colors


@dataclass(frozen=True, eq=False)
class Mesh:
    """One triangle mesh read from a file (or built from arrays), validated on construction.

    Attributes
    ----------
    vertices : (n, 3) float64 array   positions in metres, Y up
    faces : (m, 3) int64 array        triangles, 0-based indices into `vertices`
    colors : (n, 3) float32 array or None   per-vertex RGB in [0, 1]
    source : str   where the mesh came from: a path, ``archive.zip:member.obj``, or a label

    Notes
    -----
    The fields cannot be reassigned, but the arrays are not copied (when their dtype already
    matches) and not locked: treat them as read-only.
    Polygons in the file have been fan-triangulated (see `fan_triangulate`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None = None
    source: str = "<arrays>"

    def __post_init__(self):
        source = str(self.source)
        V = check_vertices(self.vertices, source)
        F = check_faces(self.faces, len(V), source)
        colors = check_colors(self.colors, len(V), source)
        object.__setattr__(self, "source", source)
        object.__setattr__(self, "vertices", V)
        object.__setattr__(self, "faces", F)
        object.__setattr__(self, "colors", colors)

    @property
    def degenerate_faces(self):
        """Indices of faces that repeat a vertex index.

        Returns
        -------
        faces : (k,) int64 array
        """
        F = self.faces
        repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
        return np.flatnonzero(repeated)

    def __repr__(self):
        colors = "" if self.colors is None else ", colors"
        return (
            f"Mesh({len(self.vertices)} vertices, {len(self.faces)} faces{colors}, "
            f"source={self.source!r})"
        )


def validate_mesh(mesh):
    """Non-fatal problems with a mesh, as readable warnings.

    Fatal problems (empty, non-finite, index out of range) cannot exist in a `Mesh`: they are
    raised as `MeshValidationError` when it is built. What remains is reported here.

    Parameters
    ----------
    mesh : Mesh

    Returns
    -------
    warnings : list of str   empty when the mesh has no problems; currently reports
        degenerate faces (a vertex index repeated within a triangle)
    """
    warnings = []
    degenerate = mesh.degenerate_faces
    if len(degenerate):
        first = ", ".join(str(i) for i in degenerate[:5])
        more = ", ..." if len(degenerate) > 5 else ""
        warnings.append(
            f"{mesh.source}: {len(degenerate)} degenerate faces repeat a vertex index "
            f"(faces {first}{more})"
        )
    return warnings
