"""Stanford PLY: reading (ascii, binary little and big endian) and writing.

Read: vertex ``x y z`` of any numeric type, optional ``red green blue`` (integer types scaled by
their maximum, so uchar / 255; float types taken as they are), and the face element's
``vertex_indices`` (or ``vertex_index``) list with any count and index types; polygons are
fan-triangulated. Other elements and properties are skipped.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from .atomic import atomic_write
from .errors import MeshFormatError, MeshValidationError
from .mesh import Mesh, check_colors, check_faces, check_vertices
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


def read_ply(data, source):
    """Parse a PLY file held in memory.

    Parameters
    ----------
    data : bytes   the whole file
    source : str   name used in the mesh and in error messages

    Returns
    -------
    mesh : Mesh
    """
    byte_order, elements, body = _parse_header(data, source)
    wanted = {"vertex", "face"}
    values = {}
    if byte_order is None:
        tokens = data[body:].split()
        position = 0
        for element in elements:
            values[element.name], position = _read_ascii_element(tokens, position, element, source)
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
            values[element.name], position = _read_binary_element(data, position, element, source)
    return _mesh_from_elements(values, elements, source)


def _parse_header(data, source):
    """Return (byte order or None for ascii, elements, offset of the first body byte)."""
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
    return byte_order, elements, body


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


def _read_binary_element(data, offset, element, source):
    """Decode one binary element.

    Returns
    -------
    values : dict   property name -> (count,) array, or for a list property a tuple
        ((total,) items, (count,) int64 list lengths)
    offset : int    first byte after the element
    """
    properties = element.properties
    if all(p.count_dtype is None for p in properties):
        row = np.dtype([(f"p{i}", p.dtype) for i, p in enumerate(properties)])
        _require(data, offset, row.itemsize * element.count, element, source)
        table = np.frombuffer(data, dtype=row, count=element.count, offset=offset)
        values = {p.name: table[f"p{i}"] for i, p in enumerate(properties)}
        return values, offset + row.itemsize * element.count
    fixed = _read_binary_fixed_lists(data, offset, element)
    if fixed is not None:
        return fixed
    return _read_binary_variable_lists(data, offset, element, source)


def _read_binary_fixed_lists(data, offset, element):
    """Fast path: every row's lists as long as the first row's (all triangles, all quads).

    Returns None when the guess does not hold.
    """
    if element.count == 0:
        return {p.name: _empty(p) for p in element.properties}, offset
    fields, lengths, position = [], {}, offset
    for i, p in enumerate(element.properties):
        if p.count_dtype is None:
            fields.append((f"p{i}", p.dtype))
            position += p.dtype.itemsize
            continue
        if position + p.count_dtype.itemsize > len(data):
            return None
        length = int(np.frombuffer(data, p.count_dtype, 1, position)[0])
        if length < 0:
            return None
        lengths[i] = length
        fields += [(f"c{i}", p.count_dtype), (f"p{i}", p.dtype, (length,))]
        position += p.count_dtype.itemsize + length * p.dtype.itemsize
    row = np.dtype(fields)
    size = row.itemsize * element.count
    if offset + size > len(data):
        return None
    table = np.frombuffer(data, dtype=row, count=element.count, offset=offset)
    if any((table[f"c{i}"] != length).any() for i, length in lengths.items()):
        return None
    values = {}
    for i, p in enumerate(element.properties):
        if p.count_dtype is None:
            values[p.name] = table[f"p{i}"]
        else:
            counts = np.full(element.count, lengths[i], dtype=np.int64)
            values[p.name] = (table[f"p{i}"].reshape(-1), counts)
    return values, offset + size


def _read_binary_variable_lists(data, offset, element, source):
    """General path: walk the rows in Python to find each list's length, then gather."""
    properties = element.properties
    count_formats = [
        None if p.count_dtype is None else _struct_format(p.count_dtype) for p in properties
    ]
    starts = [np.empty(element.count, dtype=np.int64) for _ in properties]
    lengths = [np.zeros(element.count, dtype=np.int64) for _ in properties]
    position, size = offset, len(data)
    for row in range(element.count):
        for i, p in enumerate(properties):
            if p.count_dtype is None:
                starts[i][row] = position
                position += p.dtype.itemsize
                continue
            if position + p.count_dtype.itemsize > size:
                _raise_truncated(element, row, source)
            length = struct.unpack_from(count_formats[i], data, position)[0]
            if length < 0:
                raise MeshFormatError(
                    f"{source}: element '{element.name}' row {row} has a negative list length"
                )
            position += p.count_dtype.itemsize
            starts[i][row], lengths[i][row] = position, length
            position += length * p.dtype.itemsize
        if position > size:
            _raise_truncated(element, row, source)
    codes = np.frombuffer(data, dtype=np.uint8)
    values = {}
    for i, p in enumerate(properties):
        width = p.dtype.itemsize
        if p.count_dtype is None:
            item_offsets = starts[i]
        else:
            first_item = np.cumsum(lengths[i]) - lengths[i]
            rank = np.arange(lengths[i].sum()) - np.repeat(first_item, lengths[i])
            item_offsets = np.repeat(starts[i], lengths[i]) + rank * width
        raw = codes[item_offsets[:, None] + np.arange(width)]
        items = np.ascontiguousarray(raw).view(p.dtype).reshape(-1)
        values[p.name] = items if p.count_dtype is None else (items, lengths[i])
    return values, position


def _read_ascii_element(tokens, position, element, source):
    """Decode one ascii element from the body's token list (values as float64).

    Returns
    -------
    values : dict   as for `_read_binary_element`
    position : int  index of the first token after the element
    """
    properties = element.properties
    n_rows = element.count
    if n_rows == 0:
        return {p.name: _empty(p) for p in properties}, position
    # Where each property's value(s) start within a row, assuming every row is as long as the
    # first; verified below, with a row-by-row walk when it does not hold.
    layout, cursor = [], position
    for p in properties:
        if p.count_dtype is None:
            layout.append((cursor - position, None))
            cursor += 1
        else:
            length = _ascii_int(tokens, cursor, element, source)
            if length < 0:
                return _read_ascii_rows(tokens, position, element, source)
            layout.append((cursor - position, length))
            cursor += 1 + length
    row_length = cursor - position
    end = position + row_length * n_rows
    if end <= len(tokens):
        table = _ascii_numbers(tokens[position:end], element, source).reshape(n_rows, row_length)
        if all(length is None or (table[:, at] == length).all() for at, length in layout):
            values = {}
            for p, (at, length) in zip(properties, layout):
                if length is None:
                    values[p.name] = table[:, at]
                else:
                    items = table[:, at + 1 : at + 1 + length].reshape(-1)
                    values[p.name] = (items, np.full(n_rows, length, dtype=np.int64))
            return values, end
    return _read_ascii_rows(tokens, position, element, source)


def _read_ascii_rows(tokens, position, element, source):
    properties = element.properties
    starts = [np.empty(element.count, dtype=np.int64) for _ in properties]
    lengths = [np.zeros(element.count, dtype=np.int64) for _ in properties]
    begin = position
    for row in range(element.count):
        for i, p in enumerate(properties):
            if p.count_dtype is None:
                starts[i][row] = position
                position += 1
            else:
                length = _ascii_int(tokens, position, element, source)
                if length < 0:
                    raise MeshFormatError(
                        f"{source}: element '{element.name}' row {row} has a negative list length"
                    )
                starts[i][row], lengths[i][row] = position + 1, length
                position += 1 + length
    if position > len(tokens):
        _raise_truncated(element, element.count - 1, source)
    numbers = _ascii_numbers(tokens[begin:position], element, source)
    values = {}
    for i, p in enumerate(properties):
        if p.count_dtype is None:
            values[p.name] = numbers[starts[i] - begin]
        else:
            first_item = np.cumsum(lengths[i]) - lengths[i]
            rank = np.arange(lengths[i].sum()) - np.repeat(first_item, lengths[i])
            at = np.repeat(starts[i] - begin, lengths[i]) + rank
            values[p.name] = (numbers[at], lengths[i])
    return values, position


def _ascii_int(tokens, position, element, source):
    if position >= len(tokens):
        raise MeshFormatError(
            f"{source}: file ends inside element '{element.name}' (truncated or wrong counts)"
        )
    try:
        return int(tokens[position])
    except ValueError:
        shown = tokens[position][:30].decode("utf-8", "replace")
        raise MeshFormatError(
            f"{source}: element '{element.name}': list length {shown!r} is not an integer"
        ) from None


def _ascii_numbers(tokens, element, source):
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for token in tokens:
            try:
                float(token)
            except ValueError:
                shown = token[:30].decode("utf-8", "replace")
                raise MeshFormatError(
                    f"{source}: element '{element.name}': {shown!r} is not a number"
                ) from None
        raise  # pragma: no cover


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
        colors = np.stack(channels, axis=1)

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


def _empty(p):
    if p.count_dtype is None:
        return np.empty(0, dtype=p.dtype)
    return np.empty(0, dtype=p.dtype), np.empty(0, dtype=np.int64)


def _struct_format(dtype):
    return ("<" if dtype.byteorder in "<=|" else ">") + dtype.char


def _require(data, offset, size, element, source):
    if offset + size > len(data):
        raise MeshFormatError(
            f"{source}: truncated: element '{element.name}' needs {size} bytes, "
            f"only {max(len(data) - offset, 0)} remain"
        )


def _raise_truncated(element, row, source):
    raise MeshFormatError(
        f"{source}: truncated: the file ends inside row {row} of element '{element.name}' "
        f"({element.count} rows declared)"
    )


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
