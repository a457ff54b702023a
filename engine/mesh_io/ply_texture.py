"""A PLY's texture baked into vertex colours (see ``texture``).

The conventions of MeshLab, Agisoft Metashape and similar tools: the image is named in a
``comment TextureFile name`` header line (several lines: several images, chosen per face by a
``texnumber`` property), and the texture coordinates are either per face corner (a face list
property ``texcoord`` of two numbers per corner) or per vertex (``u v``, ``s t``,
``texture_u texture_v`` or ``texture_s texture_t``).
"""

from __future__ import annotations

import numpy as np

from .errors import MeshFormatError
from .texture import bake_vertex_colours, load_texture, resource_name
from .triangulate import fan_triangulate

_VERTEX_UV = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


def texture_files(header_lines):
    """The image names of ``comment TextureFile`` header lines, in order."""
    names = []
    for line in header_lines:
        words = line.split(None, 2)
        if len(words) == 3 and words[0] == "comment" and words[1].lower() == "texturefile":
            names.append(resource_name(words[2]))
    return names


def ply_texture_colours(V, F, vertex, face, face_counts, names, resources, source):
    """Vertex colours from a PLY's texture, or None when it has no texture coordinates.

    Parameters
    ----------
    V : (n, 3) float array, F : (m, 3) int array   the mesh as read (polygons fanned)
    vertex : dict   the vertex element's properties (name -> array)
    face : dict     the face element's properties (a list property is (items, counts))
    face_counts : (p,) int array   corners per polygon
    names : list of str            images from ``texture_files``
    resources : callable(name) -> bytes
    source : str

    Returns
    -------
    colours : (n, 3) float32 array or None
    """
    per_triangle = np.repeat(np.arange(len(face_counts)), face_counts - 2)
    texcoord = face.get("texcoord")
    if isinstance(texcoord, tuple):
        items, counts = texcoord
        if not np.array_equal(counts, 2 * face_counts):
            raise MeshFormatError(f"{source}: the faces' texcoord lists must hold two numbers per corner")
        uv = np.asarray(items, dtype=np.float64).reshape(-1, 2)
        corner_uv = uv[fan_triangulate(np.arange(len(uv)), face_counts)]
    else:
        pair = next((p for p in _VERTEX_UV if p[0] in vertex and p[1] in vertex), None)
        if pair is None:
            return None
        uv = np.stack([np.asarray(vertex[pair[0]], dtype=np.float64), np.asarray(vertex[pair[1]], dtype=np.float64)],
                      axis=1)
        corner_uv = uv[F]
    number = face.get("texnumber")
    polygon_texture = np.zeros(len(face_counts), dtype=np.int64) if number is None or isinstance(number, tuple) \
        else np.asarray(number, dtype=np.int64)
    if len(polygon_texture) and (polygon_texture.min() < 0 or polygon_texture.max() >= len(names)):
        bad = int(np.flatnonzero((polygon_texture < 0) | (polygon_texture >= len(names)))[0])
        raise MeshFormatError(f"{source}: face {bad} uses texture {int(polygon_texture[bad])}, but the header "
                              f"names {len(names)} (comment TextureFile)")
    used = sorted(set(polygon_texture.tolist()))
    textures = [load_texture(resources(names[t]), f"{source}: {names[t]}") if t in used else np.zeros((1, 1, 3))
                for t in range(len(names))]
    return bake_vertex_colours(V, F, corner_uv, polygon_texture[per_triangle], textures)


__all__ = ["ply_texture_colours", "texture_files"]
