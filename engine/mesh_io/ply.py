"""Stanford PLY: reading (ascii, binary little and big endian) and writing.

Read: vertex ``x y z`` of any numeric type, optional ``red green blue`` (integer types scaled by
their maximum, so uchar / 255; float types as they are, or / 255 when a value is above 1), and the face element's
``vertex_indices`` (or ``vertex_index``) list with any count and index types; polygons are
fan-triangulated. Without vertex colours, a texture named in the header is baked per vertex
(``ply_texture``). Other elements and properties are skipped. The element rows are read in
``ply_rows``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .atomic import atomic_write
from .errors import MeshFormatError, MeshValidationError
from .mesh import Mesh, check_colors, check_faces, check_vertices
from .ply_rows import read_ascii_element, read_binary_element
from .ply_texture import ply_texture_colours, texture_files
from .triangulate import fan_triangulate, first_out_of_range

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_FACE_LISTS = ("vertex_indices", "vertex_index")


@dataclass(frozen=True)
class _Property:
    name: str
    dtype: np.dtype  # item type (with byte order for binary files)
    count_dtype: np.dtype | None = None  # set for list properties


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    properties: tuple


def read_ply(data, source, resources=None):
    """Parse a PLY file held in memory.

    Parameters
    ----------
    data : bytes   the whole file
    source : str   name used in the mesh and in error messages
    resources : callable(name) -> bytes, optional
        reads a texture the header names (``comment TextureFile``), by name relative to the
        PLY's directory; without it a texture is ignored

    Returns
    -------
    mesh : Mesh   colours from ``red green blue``, or else baked from the texture
                  (``ply_texture``)
    """
    byte_order, elements, body, textures = _parse_header(data, source)
    _check_counts(elements, byte_order, len(data) - body, source)
    wanted = {"vertex", "face"}
    values = {}
    if byte_order is None:
        tokens = data[body:].split()
        position = 0
        for element in elements:
            values[element.name], position = read_ascii_element(tokens, position, element, source)
        if position < len(tokens):
            raise MeshFormatError(
                f"{source}: {len(tokens) - position} values after the last element; "
                f"the rows do not match the header's element counts"
            )
    else:
        position = body
        for element in elements:
            if wanted <= values.keys():
                break
            values[element.name], position = read_binary_element(data, position, element, source)
    mesh = _mesh_from_elements(values, elements, source)
    if mesh.colors is None and textures and resources is not None and "face" in values:
        face = values["face"]
        counts = next((face[n][1] for n in _FACE_LISTS if isinstance(face.get(n), tuple)), None)
        colors = None if counts is None else ply_texture_colours(
            mesh.vertices, mesh.faces, values["vertex"], face, counts, textures, resources, source)
        if colors is not None:
            mesh = Mesh(mesh.vertices, mesh.faces, colors, source)
    return mesh


def _check_counts(elements, byte_order, available, source):
    """Refuse element counts the file cannot hold (before anything is allocated for them): a
    binary row takes at least its scalars' and list lengths' bytes, an ascii row at least one
    byte a value."""
    need = 0
    for element in elements:
        if byte_order is None:
            row = len(element.properties)
        else:
            row = sum((p.count_dtype or p.dtype).itemsize for p in element.properties)
        need += element.count * row
    if need > available:
        counts = ", ".join(f"{e.count} {e.name}" for e in elements)
        raise MeshFormatError(f"{source}: truncated, or its counts are wrong: the header declares {counts}, "
                              f"which need at least {need} bytes; "
                              f"the file has {available} after its header")


def _parse_header(data, source):
    """Return (byte order or None for ascii, elements, offset of the first body byte, texture names)."""
    if not data.startswith(b"ply"):
        raise MeshFormatError(f"{source}: not a PLY file (it does not start with 'ply')")
    end = data.find(b"end_header")
    if end < 0:
        raise MeshFormatError(f"{source}: PLY header has no 'end_header' line")
    body = end + len(b"end_header")
    if data[body : body + 2] == b"\r\n":
        body += 2
    elif data[body : body + 1] in (b"\n", b"\r"):
        body += 1
    try:
        header = data[:end].decode("ascii")
    except UnicodeDecodeError:
        raise MeshFormatError(f"{source}: PLY header contains non-ASCII bytes") from None

    byte_order = "missing"
    elements = []
    for number, line in enumerate(header.splitlines()[1:], start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _FORMATS:
                raise MeshFormatError(f"{source}: line {number}: unsupported PLY format {line!r}")
            byte_order = _FORMATS[words[1]]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise MeshFormatError(f"{source}: line {number}: malformed element {line!r}")
            elements.append(_Element(words[1], int(words[2]), ()))
        elif words[0] == "property":
            if not elements:
                raise MeshFormatError(f"{source}: line {number}: property before any element")
            prop = _parse_property(words, number, line, source)
            last = elements[-1]
            elements[-1] = _Element(last.name, last.count, (*last.properties, prop))
        else:
            raise MeshFormatError(f"{source}: line {number}: unknown PLY header line {line!r}")
    if byte_order == "missing":
        raise MeshFormatError(f"{source}: PLY header has no 'format' line")
    if byte_order is not None:
        elements = [_with_byte_order(element, byte_order) for element in elements]
    return byte_order, elements, body, texture_files(header.splitlines()[1:])


def _parse_property(words, number, line, source):
    try:
        if words[1] == "list" and len(words) == 5:
            count_dtype = np.dtype(_TYPES[words[2]])
            if count_dtype.kind not in "iu":
                raise MeshFormatError(
                    f"{source}: line {number}: a list length type must be an integer type"
                )
            return _Property(words[4], np.dtype(_TYPES[words[3]]), count_dtype)
        if len(words) == 3:
            return _Property(words[2], np.dtype(_TYPES[words[1]]))
    except KeyError as err:
        raise MeshFormatError(
            f"{source}: line {number}: unknown PLY property type {err.args[0]!r}"
        ) from None
    raise MeshFormatError(f"{source}: line {number}: malformed property {line!r}")


def _with_byte_order(element, byte_order):
    properties = tuple(
        _Property(
            p.name,
            p.dtype.newbyteorder(byte_order),
            None if p.count_dtype is None else p.count_dtype.newbyteorder(byte_order),
        )
        for p in element.properties
    )
    return _Element(element.name, element.count, properties)


def _mesh_from_elements(values, elements, source):
    declared = {element.name: element for element in elements}
    if "vertex" not in values:
        raise MeshFormatError(f"{source}: PLY file has no 'vertex' element")
    vertex, vertex_types = values["vertex"], {p.name: p for p in declared["vertex"].properties}
    missing = [axis for axis in "xyz" if axis not in vertex]
    if missing:
        raise MeshFormatError(f"{source}: PLY vertex element has no {missing[0]!r} property")
    if any(isinstance(vertex[axis], tuple) for axis in "xyz"):
        raise MeshFormatError(f"{source}: PLY vertex x, y, z must be scalar properties")
    # ascii values arrive as float64: round them to the declared type first ("float" is float32)
    V = np.stack(
        [np.asarray(vertex[a], dtype=vertex_types[a].dtype).astype(np.float64) for a in "xyz"],
        axis=1,
    )

    colors = None
    if all(channel in vertex_types for channel in ("red", "green", "blue")):
        channels = []
        for channel in ("red", "green", "blue"):
            kind = vertex_types[channel].dtype
            scale = float(np.iinfo(kind).max) if kind.kind in "iu" else 1.0
            channels.append(np.asarray(vertex[channel], dtype=np.float64) / scale)
        colors = _float_colours_in_range(np.stack(channels, axis=1), source)

    F = np.empty((0, 3), dtype=np.int64)
    if "face" in values:
        name = next((n for n in _FACE_LISTS if n in values["face"]), None)
        face = values["face"].get(name)
        if not isinstance(face, tuple):
            if declared["face"].count == 0:
                face = (np.empty(0), np.empty(0, dtype=np.int64))
            else:
                raise MeshFormatError(
                    f"{source}: PLY face element has no 'vertex_indices' list property"
                )
        F = _faces_from_lists(*face, len(V), source)
    return Mesh(V, F, colors, source)


def _faces_from_lists(items, counts, n_vertices, source):
    if len(counts) and counts.min() < 3:
        face = int(np.flatnonzero(counts < 3)[0])
        raise MeshFormatError(
            f"{source}: face {face} has {counts[face]} vertices; a face needs at least 3"
        )
    if items.dtype.kind == "f":  # ascii values
        if len(items) and (items != np.round(items)).any():
            raise MeshFormatError(f"{source}: face vertex indices must be integers")
    indices = items.astype(np.int64)
    bad = first_out_of_range(indices, counts, n_vertices)
    if bad is not None:
        raise MeshValidationError(
            f"{source}: face {bad[0]} references vertex {bad[1]} "
            f"but the mesh has {n_vertices} vertices"
        )
    return fan_triangulate(indices, counts)


def _float_colours_in_range(colors, source):
    """Colours in [0, 1]: float values above 1 are taken as 0-255 (as OBJ and COFF colours are);
    a value below 0, above 255 or not finite is refused, naming the vertex and the channel."""
    bad = ~np.isfinite(colors) | (colors < 0) | (colors > 255)
    if bad.any():
        vertex, channel = (int(i) for i in np.argwhere(bad)[0])
        raise MeshFormatError(
            f"{source}: vertex {vertex} has {('red', 'green', 'blue')[channel]} {colors[vertex, channel]:g}: vertex "
            f"colours must be within [0, 1] or 0-255"
        )
    return colors / 255.0 if len(colors) and colors.max() > 1 else colors


def write_ply(path, V, F, colors=None, binary=True, dtype=np.float32):
    """Write a triangle mesh as PLY, atomically.

    Parameters
    ----------
    path : str or os.PathLike   destination; missing directories are created
    V : (n, 3) float array      vertex positions
    F : (m, 3) int array        triangles, 0-based
    colors : (n, 3) float array in [0, 1], optional   stored as uchar red/green/blue
        (rounded to 1/255)
    binary : bool   binary little endian (default) or ascii
    dtype : np.float32 or np.float64   coordinate type; float32 is the PLY convention

    Returns
    -------
    path : str or os.PathLike   the `path` given

    Notes
    -----
    Faces are stored as ``property list uchar int vertex_indices``.
    """
    source = str(path)
    V = check_vertices(V, source)
    F = check_faces(F, len(V), source)
    colors = check_colors(colors, len(V), source)
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"{source}: PLY coordinates must be float32 or float64, not {dtype}")
    if len(V) > np.iinfo(np.int32).max:
        raise MeshValidationError(f"{source}: too many vertices for PLY int indices")
    type_name = "float" if dtype == np.float32 else "double"
    lines = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        "comment written by morphspace",
        f"element vertex {len(V)}",
        *(f"property {type_name} {axis}" for axis in "xyz"),
    ]
    if colors is not None:
        lines += [f"property uchar {channel}" for channel in ("red", "green", "blue")]
        rgb = np.round(colors * 255.0).astype(np.uint8)
    lines += [f"element face {len(F)}", "property list uchar int vertex_indices", "end_header"]
    header = ("\n".join(lines) + "\n").encode("ascii")

    if binary:
        fields = [(axis, dtype.newbyteorder("<")) for axis in "xyz"]
        if colors is not None:
            fields += [(channel, "u1") for channel in ("red", "green", "blue")]
        vertex_table = np.empty(len(V), dtype=fields)
        for i, axis in enumerate("xyz"):
            vertex_table[axis] = V[:, i]
        if colors is not None:
            for i, channel in enumerate(("red", "green", "blue")):
                vertex_table[channel] = rgb[:, i]
        face_table = np.empty(len(F), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        face_table["n"] = 3
        face_table["v"] = F
        body = vertex_table.tobytes() + face_table.tobytes()
    else:
        number = "%r" if dtype == np.float64 else "%.9g"
        rows = V.astype(dtype).astype(np.float64)
        if colors is None:
            vertex_text = (f"{number} {number} {number}\n" * len(V)) % tuple(rows.ravel().tolist())
        else:
            rows = np.hstack([rows, rgb.astype(np.float64)])
            row_format = f"{number} {number} {number} %d %d %d\n"
            vertex_text = (row_format * len(V)) % tuple(rows.ravel().tolist())
        face_text = ("3 %d %d %d\n" * len(F)) % tuple(F.ravel().tolist())
        body = (vertex_text + face_text).encode("ascii")
    with atomic_write(path) as file:
        file.write(header)
        file.write(body)
    return path
