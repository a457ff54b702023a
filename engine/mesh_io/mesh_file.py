"""`read_mesh` and `write_mesh`: one mesh file of any supported type, chosen by extension."""

from __future__ import annotations

import os
from pathlib import Path, PurePosixPath

from .errors import MeshFormatError, MeshValidationError
from .glb import read_glb
from .obj import read_obj, write_obj
from .off import read_off, write_off
from .ply import read_ply, write_ply
from .texture import directory_resources

READERS = {"obj": read_obj, "ply": read_ply, "off": read_off, "glb": read_glb}
TEXTURED_READERS = (read_obj, read_ply)   # take a resource reader for the files they refer to
WRITERS = {"obj": write_obj, "ply": write_ply, "off": write_off}
MESH_EXTENSIONS = tuple(f".{kind}" for kind in READERS)


def mesh_file_type(name):
    """The reader key for a file name ("obj", "ply", "off", "glb"), or None if unsupported.

    Parameters
    ----------
    name : str or os.PathLike   file name or path; the extension is matched case-insensitively

    Returns
    -------
    file_type : str or None
    """
    suffix = PurePosixPath(os.fspath(name)).suffix.lower().lstrip(".")
    return suffix if suffix in READERS else None


def read_mesh(path_or_file, *, name=None, file_type=None, resources=None):
    """Read one mesh file: OBJ, PLY (ascii or binary), OFF/COFF or GLB.

    Parameters
    ----------
    path_or_file : str, os.PathLike, bytes or binary file object
        A path, or the file's content (e.g. a zip member read into memory).
    name : str, optional
        Name used as the mesh's `source` and in error messages, and for choosing the reader
        by extension; defaults to the path (or the file object's ``name``).
        Required for bytes unless `file_type` is given.
    file_type : {"obj", "ply", "off", "glb"}, optional
        Overrides the extension (a leading dot and any case are accepted).
    resources : callable(name) -> bytes, optional
        Reads the files an OBJ or PLY refers to (material library, texture images), by name
        relative to the mesh's directory. Default for a path: the files beside it; for bytes
        and file objects: none (a texture is then not read, and the mesh has no colours).

    Returns
    -------
    mesh : Mesh
        Validated: finite vertices, in-range faces, at least one vertex and one face.
        Polygons are fan-triangulated; see `validate_mesh` for non-fatal warnings.

    Raises
    ------
    MeshFormatError
        Unsupported type, missing or unreadable file, parse error, truncated file.
    MeshValidationError
        Empty mesh or file, non-finite coordinate, face index out of range.
    """
    if isinstance(path_or_file, (str, os.PathLike)):
        source = name if name is not None else os.fspath(path_or_file)
        reader = _reader(source, file_type)
        if resources is None:
            resources = directory_resources(path_or_file, str(source))
        try:
            data = Path(path_or_file).read_bytes()
        except OSError as err:
            reason = err.strerror or type(err).__name__
            raise MeshFormatError(f"{source}: cannot read the file ({reason})") from err
    elif isinstance(path_or_file, (bytes, bytearray, memoryview)):
        source = name if name is not None else f"<{file_type or 'unnamed'} bytes>"
        if name is None and file_type is None:
            raise MeshFormatError(f"{source}: reading bytes needs a name or a file_type")
        reader = _reader(source, file_type)
        data = bytes(path_or_file)
    elif hasattr(path_or_file, "read"):
        source = name if name is not None else str(getattr(path_or_file, "name", "<file>"))
        reader = _reader(source, file_type)
        data = path_or_file.read()
        if not isinstance(data, bytes):
            raise MeshFormatError(f"{source}: open the file in binary mode ('rb')")
    else:
        raise TypeError(
            f"read_mesh needs a path, bytes or a binary file, not {type(path_or_file).__name__}"
        )
    if len(data) == 0:  # whatever its type (a PLY reader would say "not a PLY file")
        raise MeshValidationError(f"{source}: the mesh is empty (the file has 0 bytes)")
    if reader in TEXTURED_READERS:
        return reader(data, str(source), None if resources is None else _checked(resources, str(source)))
    return reader(data, str(source))


def _checked(resources, source):
    """A caller's resource reader whose failures (OSError, KeyError, None) become MeshFormatError."""
    def read(name):
        try:
            data = resources(name)
        except (OSError, KeyError) as err:
            raise MeshFormatError(f"{source}: refers to {name!r}, which cannot be read ({type(err).__name__}: "
                                  f"{err})") from None
        if data is None:
            raise MeshFormatError(f"{source}: refers to {name!r}, which cannot be read (no data)")
        return bytes(data)
    return read


def _reader(source, file_type):
    if file_type is not None:
        kind = str(file_type).lower().lstrip(".")
        if kind not in READERS:
            raise MeshFormatError(
                f"{source}: unsupported mesh file type {file_type!r} "
                f"(supported: {', '.join(READERS)})"
            )
        return READERS[kind]
    kind = mesh_file_type(source)
    if kind is None:
        suffix = PurePosixPath(os.fspath(source)).suffix
        what = f"extension {suffix!r}" if suffix else "no extension"
        raise MeshFormatError(
            f"{source}: unsupported mesh file ({what}; supported: {', '.join(MESH_EXTENSIONS)})"
        )
    return READERS[kind]


def write_mesh(path, V, F, colors=None):
    """Write a triangle mesh, the format chosen by the extension (.obj, .ply, .off).

    Parameters
    ----------
    path : str or os.PathLike   destination; missing directories are created
    V : (n, 3) float array
    F : (m, 3) int array
    colors : (n, 3) float array in [0, 1], optional

    Returns
    -------
    path : str or os.PathLike   the `path` given

    Notes
    -----
    PLY is written binary with float32 coordinates (see `write_ply` for other options).
    """
    return WRITERS[writable_type(path)](path, V, F, colors=colors)


def writable_type(path):
    """The mesh file type ``write_mesh`` would write at ``path`` (from its extension); a
    MeshFormatError naming the path and the writable types when there is none."""
    kind = mesh_file_type(path)
    if kind not in WRITERS:
        raise MeshFormatError(
            f"{path}: cannot write this file type (writable: "
            f"{', '.join('.' + k for k in WRITERS)})"
        )
    return kind
