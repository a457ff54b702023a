"""Reading and writing mesh sequences: one mesh file per frame, in a directory or a zip.

`read_sequence` / `write_sequence` handle consistent topology (every frame shares one face
array and vertex count); `read_frames` / `write_frames` handle unstructured sequences (each
frame its own mesh).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import MeshSequenceError, MeshValidationError
from .frames import DEFAULT_MAX_MEMBER_BYTES, DEFAULT_MAX_TOTAL_BYTES, FrameContainer
from .mesh import Mesh, check_colors, check_faces
from .mesh_file import WRITERS, mesh_file_type
from .mesh_sequence import MeshSequence, check_sequence_vertices


def read_sequence(
    path,
    *,
    progress=None,
    max_member_bytes=DEFAULT_MAX_MEMBER_BYTES,
    max_total_bytes=DEFAULT_MAX_TOTAL_BYTES,
):
    """Read a sequence with consistent topology from a directory or zip of mesh files.

    Parameters
    ----------
    path : str or os.PathLike   directory or zip archive (see `list_frames`)
    progress : callable(done: int, total: int), optional   called after each frame
    max_member_bytes, max_total_bytes : int   zip size limits, see `list_frames`

    Returns
    -------
    sequence : MeshSequence
        vertices (frames, n, 3) float64; faces (m, 3) int64 from the first frame; colours
        (frames, n, 3) only when every frame has vertex colours, otherwise None.

    Raises
    ------
    MeshSequenceError
        No frames, or a frame whose vertex count, face count or faces differ from the first
        frame's (faces must be identical, index for index).
    MeshFormatError, MeshValidationError
        From reading an individual frame.
    """
    with FrameContainer(path, max_member_bytes, max_total_bytes) as frames:
        names = frames.names
        first = frames.read(names[0])
        V = np.empty((len(names), *first.vertices.shape))
        V[0] = first.vertices
        colors = None
        if first.colors is not None:
            colors = np.empty((len(names), *first.colors.shape), dtype=np.float32)
            colors[0] = first.colors
        _report(progress, 1, len(names))
        for i, name in enumerate(names[1:], start=1):
            mesh = frames.read(name)
            _require_same_topology(mesh, first)
            V[i] = mesh.vertices
            if colors is not None:
                if mesh.colors is None:
                    colors = None
                else:
                    colors[i] = mesh.colors
            _report(progress, i + 1, len(names))
    return MeshSequence(V, first.faces, names, colors, str(path))


def read_frames(
    path,
    *,
    progress=None,
    max_member_bytes=DEFAULT_MAX_MEMBER_BYTES,
    max_total_bytes=DEFAULT_MAX_TOTAL_BYTES,
):
    """Read every frame of an unstructured sequence (each frame its own mesh).

    Parameters
    ----------
    path : str or os.PathLike   directory or zip archive (see `list_frames`)
    progress : callable(done: int, total: int), optional   called after each frame
    max_member_bytes, max_total_bytes : int   zip size limits, see `list_frames`

    Returns
    -------
    meshes : list of Mesh   in natural order of the file names; each `source` names its file
    """
    meshes = []
    with FrameContainer(path, max_member_bytes, max_total_bytes) as frames:
        for i, name in enumerate(frames.names):
            meshes.append(frames.read(name))
            _report(progress, i + 1, len(frames.names))
    return meshes


def _require_same_topology(mesh, first):
    a, b = first.source, mesh.source
    if len(mesh.vertices) != len(first.vertices):
        raise MeshSequenceError(
            f"{b} has {len(mesh.vertices)} vertices, {a} has {len(first.vertices)}; "
            f"consistent topology needs equal vertex counts"
        )
    if len(mesh.faces) != len(first.faces):
        raise MeshSequenceError(
            f"{b} has {len(mesh.faces)} faces, {a} has {len(first.faces)}; consistent "
            f"topology needs identical faces (the face count differs)"
        )
    if not np.array_equal(mesh.faces, first.faces):
        face = int(np.flatnonzero((mesh.faces != first.faces).any(axis=1))[0])
        raise MeshSequenceError(
            f"{b}: face {face} is {tuple(mesh.faces[face].tolist())} but in {a} it is "
            f"{tuple(first.faces[face].tolist())}; consistent topology needs identical faces "
            f"(the connectivity differs)"
        )


def write_sequence(
    directory, vertices, F, *, format="obj", prefix="frame_", colors=None, progress=None
):
    """Write a consistent-topology sequence as one mesh file per frame.

    Parameters
    ----------
    directory : str or os.PathLike   created if missing
    vertices : (frames, n, 3) float array
    F : (m, 3) int array   shared triangles, 0-based
    format : {"obj", "ply", "off"}   PLY is binary with float32 coordinates
    prefix : str   file names are ``{prefix}{i:04d}.{format}``, zero-padded to at least 4
        digits (more when there are more than 10000 frames) so they sort in any order
    colors : (frames, n, 3) float array in [0, 1], optional
    progress : callable(done: int, total: int), optional   called after each frame

    Returns
    -------
    paths : list of pathlib.Path   the files written, in frame order

    Raises
    ------
    MeshSequenceError
        The directory already holds other mesh files, which `read_sequence` would mix in.
    """
    directory = Path(directory)
    V = check_sequence_vertices(vertices, str(directory))
    F = check_faces(F, V.shape[1], str(directory))
    colors = check_colors(colors, V.shape[1], str(directory), leading=(len(V),))
    meshes = [(V[i], F, None if colors is None else colors[i]) for i in range(len(V))]
    return _write_meshes(directory, meshes, format, prefix, progress)


def write_frames(directory, meshes, *, format="obj", prefix="frame_", progress=None):
    """Write an unstructured sequence (each frame its own mesh) as one file per frame.

    Parameters
    ----------
    directory : str or os.PathLike   created if missing
    meshes : list of Mesh, or of (V, F) or (V, F, colors) tuples
    format, prefix, progress : see `write_sequence`

    Returns
    -------
    paths : list of pathlib.Path   the files written, in frame order
    """
    directory = Path(directory)
    if len(meshes) == 0:
        raise MeshValidationError(f"{directory}: no frames to write")
    items = []
    for i, mesh in enumerate(meshes):
        if isinstance(mesh, Mesh):
            items.append((mesh.vertices, mesh.faces, mesh.colors))
        elif isinstance(mesh, (tuple, list)) and len(mesh) in (2, 3):
            items.append((mesh[0], mesh[1], mesh[2] if len(mesh) == 3 else None))
        else:
            raise TypeError(f"frame {i}: expected a Mesh or a (V, F[, colors]) tuple")
    return _write_meshes(directory, items, format, prefix, progress)


def _write_meshes(directory, meshes, format, prefix, progress):
    if format not in WRITERS:
        raise ValueError(f"format must be one of {sorted(WRITERS)}, not {format!r}")
    digits = max(4, len(str(len(meshes) - 1)))
    paths = [directory / f"{prefix}{i:0{digits}d}.{format}" for i in range(len(meshes))]
    directory.mkdir(parents=True, exist_ok=True)
    new = {path.name for path in paths}
    stale = sorted(
        entry.name
        for entry in directory.iterdir()
        if entry.name not in new
        and not entry.name.startswith(".")
        and mesh_file_type(entry.name) is not None
    )
    if stale:
        raise MeshSequenceError(
            f"{directory}: already holds {len(stale)} other mesh files (e.g. {stale[0]}), "
            f"which reading the directory would mix with the new frames; write to an empty "
            f"directory or remove them first"
        )
    writer = WRITERS[format]
    for i, (path, (V, F, colors)) in enumerate(zip(paths, meshes)):
        writer(path, V, F, colors=colors)
        _report(progress, i + 1, len(meshes))
    return paths


def _report(progress, done, total):
    if progress is not None:
        progress(done, total)
