"""Object File Format (OFF, and COFF with per-vertex colours): reading and writing.

Read: a header line ``OFF`` or ``COFF`` (the counts may follow on the same line), a line
``n_vertices n_faces [n_edges]``, one vertex per line (``x y z``, COFF adding ``r g b [a]`` as
0-255 integers or 0-1 floats), then one face per line (``k i_1 ... i_k`` with 0-based indices,
optionally followed by a face colour, which is ignored). Polygons are fan-triangulated;
``#`` starts a comment. Binary OFF is not supported.
"""

from __future__ import annotations

import numpy as np

from .atomic import atomic_write
from .errors import MeshFormatError, MeshValidationError
from .mesh import Mesh, check_colors, check_faces, check_vertices
from .text_tokens import tokens_per_line
from .triangulate import fan_triangulate, first_out_of_range


def read_off(data, source):
    """Parse an OFF or COFF file held in memory.

    Parameters
    ----------
    data : bytes   the whole file
    source : str   name used in the mesh and in error messages

    Returns
    -------
    mesh : Mesh   colours set for COFF files
    """
    if b"\x00" in data:
        raise MeshFormatError(f"{source}: contains binary data (NUL bytes); not a text OFF file")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    lines = data.splitlines()
    if b"#" in data:
        lines = [line.split(b"#", 1)[0] for line in lines]
    lines = [line for line in lines if line.strip()]
    if not lines:
        raise MeshFormatError(f"{source}: not an OFF file (it is empty)")

    header = lines[0].split()
    keyword = header[0]
    if keyword not in (b"OFF", b"COFF"):
        shown = keyword[:20].decode("utf-8", "replace")
        if keyword.endswith(b"OFF"):
            raise MeshFormatError(
                f"{source}: unsupported OFF variant {shown!r} (supported: OFF, COFF)"
            )
        raise MeshFormatError(f"{source}: not an OFF file (it starts with {shown!r})")
    if header[1:2] == [b"BINARY"]:
        raise MeshFormatError(f"{source}: binary OFF is not supported; use ascii OFF or PLY")
    counts_words, body = (header[1:], 1) if len(header) > 1 else (_split(lines, 1), 2)
    try:
        n_vertices, n_faces = int(counts_words[0]), int(counts_words[1])
    except (IndexError, ValueError):
        raise MeshFormatError(
            f"{source}: OFF header must give 'n_vertices n_faces n_edges' as integers"
        ) from None
    if n_vertices < 0 or n_faces < 0:
        raise MeshFormatError(f"{source}: OFF header has negative counts")
    if len(lines) < body + n_vertices + n_faces:
        raise MeshFormatError(
            f"{source}: truncated: the header declares {n_vertices} vertices and {n_faces} "
            f"faces but the file has only {len(lines) - body} data lines"
        )
    vertex_lines = lines[body : body + n_vertices]
    face_lines = lines[body + n_vertices : body + n_vertices + n_faces]
    V, colors = _parse_vertices(vertex_lines, keyword == b"COFF", source)
    F = _parse_faces(face_lines, n_vertices, source)
    return Mesh(V, F, colors, source)


def _split(lines, i):
    return lines[i].split() if i < len(lines) else []


def _numbers_by_line(lines, what, source):
    """Numbers of each line as one float64 array, plus each line's start and length."""
    text = b"\n".join(lines)
    counts = tokens_per_line(text, len(lines))
    try:
        values = np.array(text.split(), dtype=np.float64)
    except ValueError:
        for number, line in enumerate(lines):
            for token in line.split():
                try:
                    float(token)
                except ValueError:
                    shown = token[:30].decode("utf-8", "replace")
                    raise MeshFormatError(
                        f"{source}: {what} {number}: {shown!r} is not a number"
                    ) from None
        raise  # pragma: no cover
    return values, np.cumsum(counts) - counts, counts


def _parse_vertices(lines, has_colors, source):
    if not lines:
        return np.empty((0, 3)), None
    values, starts, counts = _numbers_by_line(lines, "vertex", source)
    needed = 6 if has_colors else 3
    short = np.flatnonzero(counts < needed)
    if len(short) and not (has_colors and (counts >= 3).all()):
        raise MeshFormatError(
            f"{source}: vertex {short[0]} has {counts[short[0]]} numbers, "
            f"expected at least {needed}"
        )
    V = values[starts[:, None] + np.arange(3)]
    colors = None
    if has_colors and not len(short):
        colors = values[starts[:, None] + np.arange(3, 6)]
        if colors.min() < 0 or colors.max() > 255:
            raise MeshFormatError(f"{source}: vertex colours must be within [0, 1] or 0-255")
        if colors.max() > 1:
            colors = colors / 255.0
    return V, colors


def _parse_faces(lines, n_vertices, source):
    if not lines:
        return np.empty((0, 3), dtype=np.int64)
    values, starts, counts = _numbers_by_line(lines, "face", source)
    sizes = values[starts]
    bad = np.flatnonzero((sizes != np.round(sizes)) | (sizes < 3) | (sizes > counts - 1))
    if len(bad):
        face = bad[0]
        raise MeshFormatError(
            f"{source}: face {face} starts with {sizes[face]:g} but a face needs a vertex "
            f"count of at least 3 followed by that many indices ({counts[face] - 1} given)"
        )
    sizes = sizes.astype(np.int64)
    first_index = np.cumsum(sizes) - sizes
    rank = np.arange(sizes.sum()) - np.repeat(first_index, sizes)
    raw = values[np.repeat(starts + 1, sizes) + rank]
    if (raw != np.round(raw)).any():
        raise MeshFormatError(f"{source}: face vertex indices must be integers")
    indices = raw.astype(np.int64)
    out_of_range = first_out_of_range(indices, sizes, n_vertices)
    if out_of_range is not None:
        raise MeshValidationError(
            f"{source}: face {out_of_range[0]} references vertex {out_of_range[1]} "
            f"but the mesh has {n_vertices} vertices"
        )
    return fan_triangulate(indices, sizes)


def write_off(path, V, F, colors=None):
    """Write a triangle mesh as OFF (or COFF when colours are given), atomically.

    Parameters
    ----------
    path : str or os.PathLike   destination; missing directories are created
    V : (n, 3) float array      vertex positions
    F : (m, 3) int array        triangles, 0-based
    colors : (n, 3) float array in [0, 1], optional   written as COFF 0-255 RGBA

    Returns
    -------
    path : str or os.PathLike   the `path` given

    Notes
    -----
    Coordinates use Python's shortest round-trip repr (bit-exact float64 round trip).
    """
    source = str(path)
    V = check_vertices(V, source)
    F = check_faces(F, len(V), source)
    colors = check_colors(colors, len(V), source)
    if colors is None:
        header = f"OFF\n{len(V)} {len(F)} 0\n"
        vertex_text = ("%r %r %r\n" * len(V)) % tuple(V.ravel().tolist())
    else:
        header = f"COFF\n{len(V)} {len(F)} 0\n"
        rgb = np.round(colors * 255.0).astype(np.float64)
        rows = np.hstack([V, rgb])
        vertex_text = ("%r %r %r %d %d %d 255\n" * len(V)) % tuple(rows.ravel().tolist())
    face_text = ("3 %d %d %d\n" * len(F)) % tuple(F.ravel().tolist())
    with atomic_write(path) as file:
        file.write((header + vertex_text + face_text).encode("ascii"))
    return path
