"""The `MeshSequence` record: frames that share one triangulation (consistent topology)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import MeshValidationError
from .mesh import Mesh, check_colors, check_faces


@dataclass(frozen=True, eq=False)
class MeshSequence:
    """Animated mesh with consistent topology, validated on construction.

    Attributes
    ----------
    vertices : (frames, n, 3) float64 array   positions per frame, metres, Y up
    faces : (m, 3) int64 array                triangles shared by every frame, 0-based
    names : list of str   one per frame: file names (directory) or member paths (zip);
        defaults to ``frame_0000``, ``frame_0001``, ...
    colors : (frames, n, 3) float32 array in [0, 1], or None
    source : str   the directory, zip or npz the frames came from, or a label
    metadata : dict   JSON-compatible values stored with the sequence (npz files)
    arrays : dict     name -> numpy array stored with the sequence (npz files)

    Notes
    -----
    The fields cannot be reassigned, but the arrays are not copied (when their dtype already
    matches) and not locked: treat them as read-only.
    """

    vertices: np.ndarray
    faces: np.ndarray
    names: list = None
    colors: np.ndarray | None = None
    source: str = "<arrays>"
    metadata: dict = field(default_factory=dict)
    arrays: dict = field(default_factory=dict)

    def __post_init__(self):
        source = str(self.source)
        V = check_sequence_vertices(self.vertices, source)
        F = check_faces(self.faces, V.shape[1], source)
        names = self.names
        if names is None:
            names = [f"frame_{i:04d}" for i in range(len(V))]
        names = [str(name) for name in names]
        if len(names) != len(V):
            raise MeshValidationError(
                f"{source}: {len(names)} frame names for {len(V)} frames"
            )
        colors = check_colors(self.colors, V.shape[1], source, leading=(len(V),))
        object.__setattr__(self, "source", source)
        object.__setattr__(self, "vertices", V)
        object.__setattr__(self, "faces", F)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "colors", colors)
        object.__setattr__(self, "metadata", dict(self.metadata))
        object.__setattr__(self, "arrays", dict(self.arrays))

    def __len__(self):
        return len(self.vertices)

    def frame(self, i):
        """Frame `i` as a `Mesh` (sharing this sequence's arrays).

        Parameters
        ----------
        i : int

        Returns
        -------
        mesh : Mesh
        """
        colors = None if self.colors is None else self.colors[i]
        return Mesh(self.vertices[i], self.faces, colors, self.names[i])

    def __repr__(self):
        frames, n, _ = self.vertices.shape
        colors = "" if self.colors is None else ", colors"
        return (
            f"MeshSequence({frames} frames, {n} vertices, {len(self.faces)} faces{colors}, "
            f"source={self.source!r})"
        )


def check_sequence_vertices(V, source):
    """Return `V` as a (frames, n, 3) float64 array with finite entries, or raise.

    Parameters
    ----------
    V : (frames, n, 3) array_like
    source : str   file name used as the message prefix

    Returns
    -------
    V : (frames, n, 3) float64 array   (no copy when already float64)
    """
    try:
        V = np.asarray(V, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise MeshValidationError(f"{source}: vertices are not numeric ({err})") from err
    if V.ndim != 3 or V.shape[2] != 3:
        raise MeshValidationError(
            f"{source}: sequence vertices must have shape (frames, n, 3), got {V.shape}"
        )
    if V.shape[0] == 0:
        raise MeshValidationError(f"{source}: the sequence has no frames")
    if V.shape[1] == 0:
        raise MeshValidationError(f"{source}: the mesh is empty (0 vertices)")
    if not np.isfinite(V).all():
        frame, vertex = np.argwhere(~np.isfinite(V).all(axis=2))[0]
        value = V[frame, vertex][~np.isfinite(V[frame, vertex])][0]
        raise MeshValidationError(
            f"{source}: frame {frame} vertex {vertex} has a non-finite coordinate ({value})"
        )
    return V
