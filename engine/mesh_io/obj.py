"""Wavefront OBJ: reading (vertices, optional vertex colours, polygon faces) and writing.

Read: ``v x y z``, ``v x y z w`` (w ignored) and ``v x y z r g b`` (vertex colour, in [0, 1] or
0-255); ``f`` corners in the forms ``a``, ``a/b``, ``a//c`` and ``a/b/c`` with 1-based or
negative (relative) indices; polygons are fan-triangulated. Without vertex colours, the
materials (``mtllib``, ``usemtl``) and texture coordinates (``vt``) give the colours: the
texture baked per vertex (``obj_texture``). Normals, groups, objects, smoothing, lines,
comments (whole-line or trailing) and other statements are ignored.
A backslash at the end of a line continues it.
"""

from __future__ import annotations

import numpy as np

from .atomic import atomic_write
from .errors import MeshFormatError, MeshValidationError
from .mesh import Mesh, check_colors, check_faces, check_vertices
from .obj_texture import ObjTextureLines, texture_colours
from .text_tokens import first_field_of_tokens, tokens_per_line
from .triangulate import fan_triangulate

# Statements of the OBJ specification (and common extensions) that carry no triangle geometry.
_IGNORED = {
    b"vt", b"vn", b"vp", b"g", b"o", b"s", b"mg", b"usemtl", b"mtllib", b"l", b"p",
    b"cstype", b"deg", b"bmat", b"step", b"curv", b"curv2", b"surf", b"parm", b"trim",
    b"hole", b"scrv", b"sp", b"end", b"con", b"bevel", b"c_interp", b"d_interp", b"lod",
    b"maplib", b"usemap", b"shadow_obj", b"trace_obj", b"ctech", b"stech", b"call", b"csh",
}


def read_obj(data, source, resources=None):
    """Parse an OBJ file held in memory.

    Parameters
    ----------
    data : bytes   the whole file
    source : str   name used in the mesh and in error messages
    resources : callable(name) -> bytes, optional
        reads the files the OBJ refers to (material library, textures), by name relative to
        the OBJ's directory (``texture.directory_resources``); without it materials are ignored

    Returns
    -------
    mesh : Mesh   colours set when every ``v`` line carries r g b, or else when every face has
                  a texture or material colour (baked per vertex: ``obj_texture``)
    """
    if b"\x00" in data:
        raise MeshFormatError(f"{source}: contains binary data (NUL bytes); not a text OBJ file")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if b"\\" in data:
        data = data.replace(b"\\\r\n", b" ").replace(b"\\\n", b" ")

    vertex_lines, face_lines = [], []
    vertex_line_numbers, face_line_numbers, vertices_before_face = [], [], []
    texture = ObjTextureLines()
    unknown = None
    for number, line in enumerate(data.splitlines(), start=1):
        head = line[:2]
        if head == b"v ":
            vertex_lines.append(line[1:])
            vertex_line_numbers.append(number)
        elif head == b"f ":
            face_lines.append(line[1:])
            face_line_numbers.append(number)
            vertices_before_face.append(len(vertex_lines))
            texture.uvs_before_face.append(len(texture.uv_lines))
        elif head == b"vt" and line[2:3] in (b" ", b"\t"):
            texture.uv_lines.append(line[3:])
            texture.uv_line_numbers.append(number)
        else:
            stripped = line.strip()
            if not stripped or stripped.startswith(b"#"):
                continue
            keyword = stripped.split(None, 1)[0]
            if keyword == b"v":
                vertex_lines.append(stripped[1:])
                vertex_line_numbers.append(number)
            elif keyword == b"f":
                face_lines.append(stripped[1:])
                face_line_numbers.append(number)
                vertices_before_face.append(len(vertex_lines))
                texture.uvs_before_face.append(len(texture.uv_lines))
            elif keyword == b"vt":
                texture.uv_lines.append(stripped[2:].split(b"#", 1)[0])
                texture.uv_line_numbers.append(number)
            elif keyword == b"mtllib":
                texture.libraries.append((number, stripped[6:].split(b"#", 1)[0]))
            elif keyword == b"usemtl":
                texture.materials.append((len(face_lines), stripped[6:].split(b"#", 1)[0]))
            elif keyword not in _IGNORED and unknown is None:
                unknown = (number, keyword)

    if not vertex_lines and unknown is not None:
        number, keyword = unknown
        shown = keyword[:20].decode("utf-8", "replace")
        raise MeshFormatError(
            f"{source}: not an OBJ file: no vertex ('v') lines, and line {number} starts with "
            f"{shown!r}, which is not an OBJ statement"
        )
    V, colors = _parse_vertices(vertex_lines, vertex_line_numbers, source)
    if vertex_lines and not face_lines:
        raise MeshValidationError(
            f"{source}: the mesh is empty (0 faces): {len(vertex_lines)} vertices and no 'f' lines (a point "
            f"cloud, or a file cut short before its faces)"
        )
    _check_last_face_whole(data, face_lines, face_line_numbers, source)
    F = _parse_faces(face_lines, face_line_numbers, vertices_before_face, len(V), source)
    if colors is None and texture.libraries and resources is not None:
        colors = texture_colours(V, F, _without_trailing_comments(face_lines), face_line_numbers, texture,
                                 resources, source)
    return Mesh(V, F, colors, source)


def _parse_vertices(lines, line_numbers, source):
    """(n, 3) float64 positions and (n, 3) float32 colours or None from ``v`` line bodies."""
    if not lines:
        return np.empty((0, 3)), None
    lines = _without_trailing_comments(lines)
    text = b"\n".join(lines)
    counts = tokens_per_line(text, len(lines))
    bad = np.flatnonzero((counts != 3) & (counts != 4) & (counts != 6))
    if len(bad):
        raise MeshFormatError(
            f"{source}: line {line_numbers[bad[0]]}: a vertex needs 'v x y z', 'v x y z w' or "
            f"'v x y z r g b', found {counts[bad[0]]} numbers"
        )
    try:
        values = np.array(text.split(), dtype=np.float64)
    except ValueError:
        _raise_first_bad_number(lines, line_numbers, float, "vertex coordinate", source)
    starts = np.cumsum(counts) - counts
    V = values[starts[:, None] + np.arange(3)]
    colors = None
    if (counts == 6).all():
        colors = values[starts[:, None] + np.arange(3, 6)]
        if colors.min() < 0 or colors.max() > 255:
            raise MeshFormatError(f"{source}: vertex colours must be within [0, 1] or 0-255")
        if colors.max() > 1:
            colors = colors / 255.0
    return V, colors


def _parse_faces(lines, line_numbers, vertices_before, n_vertices, source):
    """(m, 3) int64 triangles (0-based) from ``f`` line bodies; polygons fan-triangulated."""
    if not lines:
        return np.empty((0, 3), dtype=np.int64)
    lines = _without_trailing_comments(lines)
    text = first_field_of_tokens(b"\n".join(lines))
    counts = tokens_per_line(text, len(lines))
    short = np.flatnonzero(counts < 3)
    if len(short):
        raise MeshFormatError(
            f"{source}: line {line_numbers[short[0]]}: a face needs at least 3 vertices, "
            f"found {counts[short[0]]}"
        )
    try:
        raw = np.array(text.split(), dtype=np.int64)
    except ValueError:
        _raise_first_bad_number(lines, line_numbers, _obj_index, "face vertex index", source)
    if len(raw) != counts.sum():  # a corner such as "/2/3" has an empty vertex field
        _raise_first_bad_number(lines, line_numbers, _obj_index, "face vertex index", source)

    before = np.repeat(np.asarray(vertices_before, dtype=np.int64), counts)
    indices = np.where(raw > 0, raw - 1, before + raw)
    bad = (raw == 0) | (indices < 0) | (indices >= n_vertices)
    if bad.any():
        corner = int(np.flatnonzero(bad)[0])
        face = int(np.searchsorted(np.cumsum(counts), corner, side="right"))
        index = int(raw[corner])
        where = f"{source}: face {face} (line {line_numbers[face]})"
        if index == 0:
            raise MeshValidationError(f"{where} uses vertex index 0; OBJ indices start at 1")
        if index < 0:
            raise MeshValidationError(
                f"{where} references vertex {index}, but only {before[corner]} vertices "
                f"precede it (negative indices count back from the latest vertex)"
            )
        raise MeshValidationError(
            f"{where} references vertex {index} but the file has {n_vertices} vertices"
        )
    return fan_triangulate(indices, counts)


def _corner_form(token):
    """Which of a corner's vertex / texture / normal fields are present: ``12//3`` -> (1, 0, 1)."""
    return tuple(bool(field) for field in token.split(b"/"))


def _check_last_face_whole(data, face_lines, line_numbers, source):
    """Refuse a file cut inside its last face line, where the cut shows.

    Only a file that does not end with a newline is looked at. Its last face was cut when its
    last corner ends with ``/``, or has another form than the face's other corners, which all
    agree (``3/1`` after ``1/1/1 2/2/2``), or when the face has fewer corners than each of the
    (4 to 16) faces before it, which all have the same number. A cut that leaves a whole corner of
    the same form behind (``f 1 2 34`` cut to ``f 1 2 3``) cannot be told from a valid face.
    """
    if not face_lines or data.rstrip(b" \t").endswith((b"\n", b"\r")):
        return
    corners = face_lines[-1].split(b"#", 1)[0].split()
    if len(corners) < 3:
        return  # _parse_faces says a face needs 3 vertices
    where = f"{source}: line {line_numbers[-1]}: the file does not end with a newline, and its last face"
    forms = {_corner_form(corner) for corner in corners[:-1]}
    if corners[-1].endswith(b"/") or (len(forms) == 1 and _corner_form(corners[-1]) not in forms):
        shown = corners[-1][:20].decode("utf-8", "replace")
        raise MeshFormatError(
            f"{where} ends in a corner {shown!r} unlike its others: a file cut short inside its last line?"
        )
    before = [len(line.split(b"#", 1)[0].split()) for line in face_lines[-17:-1]]
    if len(before) >= 4 and len(set(before)) == 1 and len(corners) < before[0]:
        raise MeshFormatError(
            f"{where} has {len(corners)} corners where the {len(before)} faces before it have {before[0]}: a file "
            f"cut short inside its last line?"
        )


def _without_trailing_comments(lines):
    """Drop ``# ...`` at the end of statement lines (only scanned for when a '#' is present)."""
    if any(b"#" in line for line in lines):
        return [line.split(b"#", 1)[0] for line in lines]
    return lines


def _obj_index(token):
    return int(token.split(b"/", 1)[0])


def _raise_first_bad_number(lines, line_numbers, parse, what, source):
    """Slow path after a vectorised parse failed: find the offending line and raise."""
    for line, number in zip(lines, line_numbers):
        for token in line.split():
            try:
                parse(token)
            except ValueError:
                shown = token[:30].decode("utf-8", "replace")
                raise MeshFormatError(
                    f"{source}: line {number}: {shown!r} is not a valid {what}"
                ) from None
    raise MeshFormatError(f"{source}: could not parse the {what}s")  # pragma: no cover


def write_obj(path, V, F, colors=None, precision=None):
    """Write a triangle mesh as OBJ, atomically.

    Parameters
    ----------
    path : str or os.PathLike   destination; missing directories are created
    V : (n, 3) float array      vertex positions
    F : (m, 3) int array        triangles, 0-based
    colors : (n, 3) float array in [0, 1], optional   written as ``v x y z r g b``
    precision : int, optional   decimal places of coordinates (e.g. 6 = micrometres for metres);
                                default: exact round trip

    Returns
    -------
    path : str or os.PathLike   the `path` given

    Notes
    -----
    By default coordinates are written with Python's shortest round-trip repr, so reading the
    file back gives bit-identical float64 values; colours with 9 significant digits (exact for
    float32). With ``precision`` files are about half the size: coordinates are rounded to that
    many decimals and colours to 4 significant digits.
    """
    source = str(path)
    V = check_vertices(V, source)
    F = check_faces(F, len(V), source)
    colors = check_colors(colors, len(V), source)
    coordinate = "%r" if precision is None else f"%.{int(precision)}f"
    channel = "%.9g" if precision is None else "%.4g"
    if colors is None:
        vertex_text = (f"v {coordinate} {coordinate} {coordinate}\n" * len(V)) % tuple(V.ravel().tolist())
    else:
        rows = np.hstack([V, colors.astype(np.float64)])
        line = f"v {coordinate} {coordinate} {coordinate} {channel} {channel} {channel}\n"
        vertex_text = (line * len(V)) % tuple(rows.ravel().tolist())
    face_text = ("f %d %d %d\n" * len(F)) % tuple((F + 1).ravel().tolist())
    with atomic_write(path) as file:
        file.write(f"# {len(V)} vertices, {len(F)} faces\n".encode())
        file.write(vertex_text.encode())
        file.write(face_text.encode())
    return path
