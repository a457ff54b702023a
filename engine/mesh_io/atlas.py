"""Writing a mesh with its colours in a texture atlas, as multi-view studios deliver frames.

``write_textured(path, V, F, colors)`` writes ``path`` (OBJ or PLY), an image ``<stem>.png``
beside it, and for OBJ a material library ``<stem>.mtl``. The atlas gives every pair of faces a
square cell of ``cell`` x ``cell`` texels, one face in each half, inset from the cell's edges and
from each other so that bilinear sampling inside a face never reads its neighbour's texels; a
texel holds the face's vertex colours interpolated at its centre (extrapolated and clamped in
the gutter). Reading the file back (``read_mesh``) bakes the texture into vertex colours again:
each vertex then has the mean over its faces' corners, slightly smoothed towards its
neighbours, as a photographed texture averaged at the mesh's spacing would be.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .errors import MeshFormatError
from .mesh import check_colors, check_faces, check_vertices

CELL = 8   # texels per cell side (two faces per cell)
_EDGE, _DIAGONAL = 1.0, 3.0   # insets in texels: from the cell's edges, and from its diagonal


def atlas(F, colors, *, cell=CELL):
    """The texture and each face corner's texture coordinates.

    Parameters
    ----------
    F : (m, 3) int array
    colors : (n, 3) float array in [0, 1]
    cell : int   texels per cell side, at least 8

    Returns
    -------
    image : (H, W, 3) uint8 array   row 0 at the top
    corner_uv : (m, 3, 2) float array   u right, v up from the bottom edge
    """
    if cell < 8:
        raise ValueError(f"cell must be at least 8 texels, got {cell}")
    F = np.asarray(F, dtype=np.int64)
    colors = np.asarray(colors, dtype=np.float64)
    cells = (len(F) + 1) // 2
    columns = int(np.ceil(np.sqrt(cells)))
    rows = int(np.ceil(cells / columns))
    s, e, d = float(cell), _EDGE, _DIAGONAL
    # corners in texels within a cell (x right, y down): lower-left and upper-right halves
    halves = np.array([[[e, e], [s - d, e], [e, s - d]],
                       [[s - e, s - e], [d, s - e], [s - e, d]]])
    face = np.arange(len(F))
    origin = np.stack([(face // 2) % columns, (face // 2) // columns], axis=1) * s     # (m, 2) x, y
    corners = origin[:, None, :] + halves[face % 2]                                      # (m, 3, 2)
    height, width = rows * cell, columns * cell
    corner_uv = np.stack([corners[..., 0] / width, 1.0 - corners[..., 1] / height], axis=-1)

    # every texel: its cell, its half, and the barycentric coordinates of its centre there
    y, x = np.mgrid[0:height, 0:width]
    cx, cy = x % cell + 0.5, y % cell + 0.5
    half = (cx + cy >= s).astype(np.int64)
    owner = 2 * ((y // cell) * columns + (x // cell)) + half
    image = np.full((height, width, 3), 0.5)
    valid = owner < len(F)
    P = np.stack([cx[valid], cy[valid]], axis=1)
    tri = halves[half[valid]]                                                            # (k, 3, 2)
    weights = _barycentric(P, tri)
    weights = np.clip(weights, 0.0, None)
    weights /= weights.sum(axis=1, keepdims=True)
    image[valid] = np.einsum("kc,kcj->kj", weights, colors[F[owner[valid]]])
    return np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8), corner_uv


def _barycentric(P, T):
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    v0, v1, v2 = b - a, c - a, P - a
    den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
    w1 = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
    w2 = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
    return np.stack([1.0 - w1 - w2, w1, w2], axis=1)


def write_textured(path, V, F, colors, *, cell=CELL):
    """Write a mesh with its colours as a texture: OBJ (with an MTL) or PLY, and a PNG.

    Parameters
    ----------
    path : str or os.PathLike   ``.obj`` or ``.ply``; the image is ``<stem>.png`` beside it
    V : (n, 3) float array, F : (m, 3) int array
    colors : (n, 3) float array in [0, 1]
    cell : int   see :func:`atlas`

    Returns
    -------
    path : the ``path`` given
    """
    from PIL import Image

    path = Path(path)
    source = str(path)
    V = check_vertices(V, source)
    F = check_faces(F, len(V), source)
    colors = check_colors(colors, len(V), source)
    if colors is None:
        raise MeshFormatError(f"{source}: a textured mesh needs colours")
    kind = path.suffix.lower()
    if kind not in (".obj", ".ply"):
        raise MeshFormatError(f"{source}: a textured mesh is written as .obj or .ply")
    image, corner_uv = atlas(F, colors, cell=cell)
    png = io.BytesIO()
    Image.fromarray(image).save(png, format="PNG")
    texture = path.with_suffix(".png")
    with atomic_write(texture) as file:
        file.write(png.getvalue())
    if kind == ".obj":
        _write_obj(path, V, F, corner_uv, texture.name)
    else:
        _write_ply(path, V, F, corner_uv, texture.name)
    return path


def _write_obj(path, V, F, corner_uv, texture):
    library = path.with_suffix(".mtl")
    with atomic_write(library) as file:
        file.write(f"newmtl capture\nKd 1 1 1\nmap_Kd {texture}\n".encode())
    uv = corner_uv.reshape(-1, 2)
    corner = np.arange(1, len(uv) + 1).reshape(-1, 3)
    faces = np.stack([F + 1, corner], axis=2).reshape(len(F), 6)
    with atomic_write(path) as file:
        file.write(f"# {len(V)} vertices, {len(F)} faces\nmtllib {library.name}\n".encode())
        file.write((("v %r %r %r\n" * len(V)) % tuple(V.ravel().tolist())).encode())
        file.write((("vt %.7f %.7f\n" * len(uv)) % tuple(uv.ravel().tolist())).encode())
        file.write(b"usemtl capture\n")
        file.write((("f %d/%d %d/%d %d/%d\n" * len(F)) % tuple(faces.ravel().tolist())).encode())


def _write_ply(path, V, F, corner_uv, texture):
    header = "\n".join([
        "ply", "format binary_little_endian 1.0", "comment written by morphspace", f"comment TextureFile {texture}",
        f"element vertex {len(V)}", "property float x", "property float y", "property float z",
        f"element face {len(F)}", "property list uchar int vertex_indices", "property list uchar float texcoord",
        "end_header", ""]).encode()
    row = np.dtype([("n", "u1"), ("f", "<i4", (3,)), ("m", "u1"), ("t", "<f4", (6,))])
    faces = np.empty(len(F), dtype=row)
    faces["n"], faces["f"], faces["m"], faces["t"] = 3, F, 6, corner_uv.reshape(len(F), 6)
    with atomic_write(path) as file:
        file.write(header)
        file.write(np.asarray(V, dtype="<f4").tobytes())
        file.write(faces.tobytes())


__all__ = ["CELL", "atlas", "write_textured"]
