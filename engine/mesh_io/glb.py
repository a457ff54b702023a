"""Binary glTF (GLB) reading, through trimesh.

The file is loaded as a scene without any processing (no vertex merging or reordering); every
triangle geometry instance is moved by its node's world transform and the instances are
concatenated in scene-graph order. Points and lines are skipped.
"""

from __future__ import annotations

import io
import struct

import numpy as np

from .errors import MeshFormatError
from .mesh import Mesh

_MAGIC = b"glTF"


def read_glb(data, source):
    """Parse a GLB file held in memory.

    Parameters
    ----------
    data : bytes   the whole file
    source : str   name used in the mesh and in error messages

    Returns
    -------
    mesh : Mesh   colours set only when every triangle geometry has per-vertex colours

    Notes
    -----
    An instance whose transform has a negative determinant (a mirror) has its triangles'
    winding reversed, as the glTF 2.0 specification (section 3.7.4) requires, so all output
    triangles are counter-clockwise seen from outside.
    """
    _check_glb_header(data, source)
    import trimesh  # imported here: only GLB needs it, and it is slow to import

    try:
        scene = trimesh.load_scene(io.BytesIO(data), file_type="glb", process=False)
    except Exception as err:  # trimesh raises many types for a malformed file
        raise MeshFormatError(f"{source}: unreadable GLB file ({err})") from err

    vertices, faces, colors = [], [], []
    offset = 0
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        geometry = scene.geometry[geometry_name]
        if not isinstance(geometry, trimesh.Trimesh) or len(geometry.faces) == 0:
            continue
        V = np.asarray(geometry.vertices, dtype=np.float64)
        F = np.asarray(geometry.faces, dtype=np.int64)
        transform = np.asarray(transform, dtype=np.float64)
        V = V @ transform[:3, :3].T + transform[:3, 3]
        if np.linalg.det(transform[:3, :3]) < 0:
            F = F[:, ::-1]
        vertices.append(V)
        faces.append(F + offset)
        offset += len(V)
        colors.append(_vertex_colors(geometry, source))

    if not vertices:
        return Mesh(np.empty((0, 3)), np.empty((0, 3), dtype=np.int64), None, source)
    all_colors = None
    if all(c is not None for c in colors):
        all_colors = np.concatenate(colors)
    return Mesh(np.concatenate(vertices), np.concatenate(faces), all_colors, source)


def _check_glb_header(data, source):
    if len(data) < 12 or data[:4] != _MAGIC:
        raise MeshFormatError(f"{source}: not a GLB file (no 'glTF' magic at the start)")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise MeshFormatError(f"{source}: glTF version {version} is not supported (only 2)")
    if length > len(data):
        raise MeshFormatError(
            f"{source}: truncated: the GLB header declares {length} bytes, the file has "
            f"{len(data)}"
        )


def _vertex_colors(geometry, source):
    """(n, 3) float RGB in [0, 1] if the geometry has per-vertex colours or a base colour
    texture (baked per vertex, times the base colour factor), else None."""
    visual = geometry.visual
    if getattr(visual, "kind", None) == "texture":
        return _texture_colors(geometry, source)
    if getattr(visual, "kind", None) != "vertex":
        return None
    rgba = np.asarray(visual.vertex_colors)
    if rgba.shape[0] != len(geometry.vertices):
        return None
    return rgba[:, :3].astype(np.float64) / 255.0


def _texture_colors(geometry, source):
    """A geometry's base colour texture baked per vertex (``texture.bake_vertex_colours``)."""
    from .texture import bake_vertex_colours, texture_array

    visual = geometry.visual
    material = getattr(visual, "material", None)
    image = getattr(material, "baseColorTexture", None)
    if image is None:
        image = getattr(material, "image", None)
    uv = getattr(visual, "uv", None)
    if image is None or uv is None or len(uv) != len(geometry.vertices):
        return None
    pixels = texture_array(image, f"{source}: base colour texture")
    F = np.asarray(geometry.faces, dtype=np.int64)
    colours = bake_vertex_colours(geometry.vertices, F, np.asarray(uv, dtype=np.float64)[F],
                                  np.zeros(len(F), dtype=np.int64), [pixels])
    factor = getattr(material, "baseColorFactor", None)
    if factor is not None:
        factor = np.asarray(factor, dtype=np.float64).ravel()[:3]
        colours = colours * (factor / 255.0 if factor.max() > 1.0 else factor)
    return np.clip(colours, 0.0, 1.0).astype(np.float64)
