"""An OBJ's materials and texture coordinates, baked into vertex colours (see ``texture``).

Read from the material library (``mtllib``): ``newmtl``, ``Kd r g b`` and ``map_Kd [options]
file`` (options ``-s`` and ``-o`` scale and offset the coordinates, ``-clamp on`` clamps them;
the others are skipped). A face with a textured material (``usemtl``) and texture coordinates
(``f v/vt ...``) takes its colours from the image, as renderers show it (the image is not
multiplied by ``Kd``); a face whose material has only ``Kd`` takes that colour. When some face
has neither (no material, or texture coordinates missing where the material has only an image),
the mesh has no colours, as a file with colours on some ``v`` lines only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import MeshFormatError, MeshValidationError
from .texture import bake_vertex_colours, load_texture, resource_name
from .text_tokens import tokens_per_line
from .triangulate import fan_triangulate

# map_Kd options and how many values follow each
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
                "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1}


@dataclass
class ObjTextureLines:
    """What the OBJ parser collected for materials: filled while the lines are read."""

    uv_lines: list = field(default_factory=list)
    uv_line_numbers: list = field(default_factory=list)
    uvs_before_face: list = field(default_factory=list)
    libraries: list = field(default_factory=list)      # (line number, names as bytes)
    materials: list = field(default_factory=list)      # (faces read before it, name as bytes)


@dataclass
class _Material:
    colour: np.ndarray | None = None
    texture: str | None = None
    scale: tuple = (1.0, 1.0)
    offset: tuple = (0.0, 0.0)
    clamp: bool = False


def parse_mtl(data, library, source):
    """Materials of an MTL file: ``{name: _Material}`` (texture names relative to the mesh).

    ``library`` is the file's name relative to the mesh (its textures are relative to it),
    ``source`` the mesh's name in messages.
    """
    folder = library.rsplit("/", 1)[0] if "/" in library else ""
    name = f"{source}: {library}"
    materials, current = {}, None
    for number, raw in enumerate(data.decode("utf-8", "replace").splitlines(), start=1):
        words = raw.split("#", 1)[0].split()
        if not words:
            continue
        keyword = words[0].lower()
        if keyword == "newmtl":
            current = materials.setdefault(" ".join(words[1:]), _Material())
        elif current is None:
            continue
        elif keyword == "kd" and len(words) >= 4:
            try:
                colour = np.array([float(w) for w in words[1:4]])
            except ValueError:
                raise MeshFormatError(f"{name}: line {number}: 'Kd' needs three numbers") from None
            current.colour = np.clip(colour, 0.0, 1.0)
        elif keyword == "map_kd" and len(words) >= 2:
            _texture_statement(current, words[1:], folder, name, number)
    return materials


def _texture_statement(material, words, folder, name, number):
    i = 0
    while i < len(words) - 1 and words[i].lower() in _MAP_OPTIONS:
        option, count = words[i].lower(), _MAP_OPTIONS[words[i].lower()]
        i += 1
        if option in ("-s", "-o", "-t", "-mm"):   # one to three numbers
            values = []
            while i < len(words) - 1 and len(values) < count and _is_number(words[i]):
                values.append(float(words[i]))
                i += 1
            if not values:
                raise MeshFormatError(f"{name}: line {number}: map_Kd option {option} needs a number")
            if option == "-s":
                material.scale = (values[0], values[1] if len(values) > 1 else 1.0)
            elif option == "-o":
                material.offset = (values[0], values[1] if len(values) > 1 else 0.0)
        else:
            if option == "-clamp":
                material.clamp = words[i].lower() == "on"
            i += count
    material.texture = resource_name(" ".join(words[i:]), folder)


def _is_number(word):
    try:
        float(word)
    except ValueError:
        return False
    return True


def texture_colours(V, F, face_lines, face_line_numbers, lines, resources, source):
    """Vertex colours from an OBJ's materials, or None (see the module notes).

    Parameters
    ----------
    V : (n, 3) float array, F : (m, 3) int array   the mesh as read (polygons fanned)
    face_lines : list of bytes   the ``f`` line bodies (trailing comments removed)
    face_line_numbers : list of int
    lines : ObjTextureLines
    resources : callable(name) -> bytes   reads the files the OBJ refers to
    source : str

    Returns
    -------
    colours : (n, 3) float32 array or None
    """
    materials = {}
    for _, names in lines.libraries:
        for library in names.decode("utf-8", "replace").split():
            library = resource_name(library)
            materials.update(parse_mtl(resources(library), library, source))
    counts = tokens_per_line(b"\n".join(face_lines), len(face_lines))
    polygon_material = _polygon_materials(lines.materials, len(face_lines))
    names = sorted({n for n in polygon_material if n is not None})
    chosen = [materials.get(n) for n in names]
    index = {n: i for i, n in enumerate(names)}
    poly = np.array([index.get(n, -1) if n is not None else -1 for n in polygon_material], dtype=np.int64)
    uv_index = _corner_uv_indices(face_lines, face_line_numbers, counts, lines, source)
    has_uv = np.minimum.reduceat(uv_index >= 0, np.cumsum(counts) - counts) if len(counts) else np.zeros(0, bool)
    textures, texture_of, clamp = [], {}, []
    poly_texture = np.full(len(poly), -1, dtype=np.int64)
    poly_colour = np.full((len(poly), 3), np.nan)
    for i, material in enumerate(chosen):
        at = poly == i
        if material is None:
            continue
        if material.colour is not None:
            poly_colour[at] = material.colour
        if material.texture is not None:
            if material.texture not in texture_of:
                texture_of[material.texture] = len(textures)
                textures.append(load_texture(resources(material.texture), f"{source}: {material.texture}"))
                clamp.append(material.clamp)
            poly_texture[at & has_uv] = texture_of[material.texture]
    if (poly_texture < 0).all() and np.isnan(poly_colour).all():
        return None
    uv = _texture_coordinates(lines, source) if lines.uv_lines else np.zeros((1, 2))
    scale = np.array([[1.0, 1.0]] + [list(m.scale) if m is not None else [1.0, 1.0] for m in chosen])
    offset = np.array([[0.0, 0.0]] + [list(m.offset) if m is not None else [0.0, 0.0] for m in chosen])
    per_triangle = np.repeat(np.arange(len(counts)), counts - 2)
    corner_uv_index = fan_triangulate(np.maximum(uv_index, 0), counts)
    corner_uv = uv[np.minimum(corner_uv_index, len(uv) - 1)]
    tri_material = poly[per_triangle] + 1
    corner_uv = corner_uv * scale[tri_material][:, None, :] + offset[tri_material][:, None, :]
    return bake_vertex_colours(V, F, corner_uv, poly_texture[per_triangle], textures, poly_colour[per_triangle],
                               clamp=clamp)


def _texture_coordinates(lines, source):
    """(k, 2) u, v of the ``vt`` lines (a third coordinate is ignored)."""
    bodies = [line.split(b"#", 1)[0] for line in lines.uv_lines] if any(b"#" in line for line in lines.uv_lines) \
        else lines.uv_lines
    text = b"\n".join(bodies)
    counts = tokens_per_line(text, len(bodies))
    bad = np.flatnonzero((counts < 1) | (counts > 3))
    if len(bad):
        raise MeshFormatError(f"{source}: line {lines.uv_line_numbers[bad[0]]}: a texture coordinate needs 'vt u v', "
                              f"found {counts[bad[0]]} numbers")
    try:
        values = np.array(text.split(), dtype=np.float64)
    except ValueError:
        number = next(n for n, line in zip(lines.uv_line_numbers, bodies) if not all(map(_is_number, line.split())))
        raise MeshFormatError(f"{source}: line {number}: a texture coordinate is not a number") from None
    starts = np.cumsum(counts) - counts
    uv = np.zeros((len(bodies), 2))
    uv[:, 0] = values[starts]
    has_v = counts >= 2
    uv[has_v, 1] = values[starts[has_v] + 1]
    return uv


def _polygon_materials(events, n_polygons):
    """The material name in force for every polygon (None before the first ``usemtl``)."""
    out = [None] * n_polygons
    for k, (start, name) in enumerate(events):
        stop = events[k + 1][0] if k + 1 < len(events) else n_polygons
        text = name.decode("utf-8", "replace").strip()
        out[start:stop] = [text or None] * (stop - start)
    return out


def _corner_uv_indices(face_lines, face_line_numbers, counts, lines, source):
    """0-based texture coordinate index of every polygon corner, -1 where a corner has none."""
    n_uv = len(lines.uv_lines)
    before = np.repeat(np.asarray(lines.uvs_before_face, dtype=np.int64), counts)
    raw = []
    for line in face_lines:
        for token in line.split():
            parts = token.split(b"/")
            raw.append(parts[1] if len(parts) > 1 and parts[1] else b"0")
    try:
        values = np.array(raw, dtype=np.int64)
    except ValueError:
        polygon = next(i for i, line in enumerate(face_lines) if any(
            not _is_int(t.split(b"/")[1]) for t in line.split() if len(t.split(b"/")) > 1 and t.split(b"/")[1]))
        raise MeshFormatError(f"{source}: line {face_line_numbers[polygon]}: a texture coordinate index is not an "
                              "integer") from None
    index = np.where(values > 0, values - 1, np.where(values < 0, before + values, -1))
    bad = (values != 0) & ((index < 0) | (index >= n_uv))
    if bad.any():
        corner = int(np.flatnonzero(bad)[0])
        polygon = int(np.searchsorted(np.cumsum(counts), corner, side="right"))
        raise MeshValidationError(f"{source}: face {polygon} (line {face_line_numbers[polygon]}) references texture "
                                  f"coordinate {int(values[corner])}, out of range (the file has {n_uv})")
    return index


def _is_int(word):
    try:
        int(word)
    except ValueError:
        return False
    return True


__all__ = ["ObjTextureLines", "parse_mtl", "texture_colours"]
