"""Texture-mapped meshes: the texture baked into per-vertex colours when a mesh is read.

Multi-view studios deliver each frame as a mesh with a texture atlas (OBJ + MTL + image, glTF,
PLY with texture coordinates) more often than with vertex colours. The alignment reads colours
per vertex (colour cues, the confidence, the repair's choice), so a reader that finds a texture
bakes it: every vertex gets the mean of the texture over the corners of its faces, each corner
sampled at four points of its third of the face (the corner, two points along its edges and one
towards the centre: a box filter about the size of the mesh's own spacing, so a fine atlas is
averaged down rather than aliased), the faces weighted by their area. A vertex on a UV seam
(different texture coordinates in different faces) averages both sides.

Files a mesh refers to (an OBJ's material library, the images) are found through a *resource
reader* ``resources(name) -> bytes`` with ``name`` relative to the mesh file's directory (see
:func:`directory_resources`; a zip archive of frames gives its own). It raises
:class:`~engine.mesh_io.errors.MeshFormatError` naming the missing file (``read_mesh`` turns an
``OSError`` or ``KeyError`` from a reader of the caller's, or a ``None``, into one).
"""

from __future__ import annotations

import io
import os
import posixpath
from pathlib import Path

import numpy as np

from .errors import MeshFormatError

MAX_TEXTURE_PIXELS = 8192 * 8192   # larger images are refused (a decompression bomb, or no capture)
# the files a mesh may refer to: material libraries and images
RESOURCE_SUFFIXES = (".mtl", ".png", ".jpg", ".jpeg", ".bmp", ".tga", ".tif", ".tiff", ".webp")

# barycentric weights of the four samples of a corner's third of its face: (own, next, previous)
_CORNER_SAMPLES = np.array([[1.0, 0.0, 0.0], [0.75, 0.25, 0.0], [0.75, 0.0, 0.25], [4 / 6, 1 / 6, 1 / 6]])


def resource_name(name, relative_to=""):
    """A referenced file's name as a POSIX path relative to the mesh's directory.

    Parameters
    ----------
    name : str           as written in the file (Windows separators and quotes accepted)
    relative_to : str    directory of the file that refers to it, relative to the mesh's

    Returns
    -------
    name : str   normalised; an absolute path keeps only its last part (exporters write
                 where the image was on the author's disk; captures ship it beside the mesh)
    """
    text = str(name).strip().strip('"').replace("\\", "/")
    if text.startswith("/") or (len(text) > 1 and text[1] == ":"):
        text = text.rsplit("/", 1)[-1]
    joined = posixpath.normpath(posixpath.join(relative_to, text)) if relative_to else posixpath.normpath(text)
    return joined


def directory_resources(mesh_path, source):
    """A resource reader for a mesh file on disk: names relative to its directory.

    Parameters
    ----------
    mesh_path : str or os.PathLike
    source : str   the mesh's name in messages

    Returns
    -------
    resources : callable(name) -> bytes
    """
    base = Path(os.fspath(mesh_path)).parent

    def read(name):
        path = base / name
        try:
            return path.read_bytes()
        except OSError as err:
            reason = err.strerror or type(err).__name__
            raise MeshFormatError(f"{source}: refers to {name!r}, which cannot be read beside it ({reason})") from None
    return read


def load_texture(data, name):
    """Decode an image (PNG, JPEG, or anything Pillow reads) to (H, W, 3) float32 RGB in [0, 1].

    Parameters
    ----------
    data : bytes
    name : str   used in error messages (``mesh: texture``)

    Returns
    -------
    image : (H, W, 3) float32 array   row 0 is the image's top row
    """
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as image:
            return texture_array(image, name)
    except MeshFormatError:
        raise
    except Exception as err:  # Pillow raises many types for a broken image
        raise MeshFormatError(f"{name}: not a readable image ({type(err).__name__})") from None


def texture_array(image, name):
    """A Pillow image as (H, W, 3) float32 RGB in [0, 1] (row 0 its top row); one over
    ``MAX_TEXTURE_PIXELS`` is refused before it is decoded (``name`` in the message)."""
    width, height = image.size
    if width * height > MAX_TEXTURE_PIXELS:
        raise MeshFormatError(f"{name}: the texture is {width} x {height} pixels, over the limit of "
                              f"{MAX_TEXTURE_PIXELS} pixels")
    if image.mode in ("I;16", "I;16B", "I;16L", "I"):
        array = np.asarray(image, dtype=np.float32) / 65535.0
        return np.ascontiguousarray(np.repeat(np.clip(array, 0, 1)[:, :, None], 3, axis=2))
    return np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0


def sample_texture(image, uv, *, clamp=False):
    """Bilinear samples of an image at texture coordinates.

    Parameters
    ----------
    image : (H, W, 3) float array   row 0 at the top
    uv : (k, 2) float array         u to the right, v up from the bottom edge (OBJ, PLY and
                                    trimesh's convention), the image spanning [0, 1] in each
    clamp : bool                    clamp outside [0, 1] instead of repeating the image

    Returns
    -------
    colours : (k, 3) float32 array
    """
    image = np.asarray(image, dtype=np.float32)
    H, W = image.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    if clamp:
        u, v = np.clip(uv[:, 0], 0.0, 1.0), np.clip(uv[:, 1], 0.0, 1.0)
    else:
        u, v = uv[:, 0] - np.floor(uv[:, 0]), uv[:, 1] - np.floor(uv[:, 1])
    x = u * W - 0.5
    y = (1.0 - v) * H - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    if clamp:
        xa, xb = np.clip(x0, 0, W - 1), np.clip(x0 + 1, 0, W - 1)
        ya, yb = np.clip(y0, 0, H - 1), np.clip(y0 + 1, 0, H - 1)
    else:
        xa, xb, ya, yb = x0 % W, (x0 + 1) % W, y0 % H, (y0 + 1) % H
    top = image[ya, xa] * (1 - fx) + image[ya, xb] * fx
    bottom = image[yb, xa] * (1 - fx) + image[yb, xb] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def bake_vertex_colours(V, F, corner_uv, face_texture, textures, face_colour=None, clamp=None):
    """Per-vertex colours from the textures (and plain material colours) of a mesh's faces.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array
    corner_uv : (m, 3, 2) float array   texture coordinates of every face corner (rows of faces
                                        without a texture are not read)
    face_texture : (m,) int array       index into ``textures`` of each face's image, -1 for none
    textures : list of (H, W, 3) float arrays
    face_colour : (m, 3) float array or None   the colour of a face without an image (a plain
                                        material); NaN where a face has no colour at all
    clamp : list of bool or None        per texture: clamp coordinates instead of repeating

    Returns
    -------
    colours : (n, 3) float32 array in [0, 1], or None when some face has neither an image nor a
              colour (a vertex in no face takes the mean colour)
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    face_texture = np.asarray(face_texture, dtype=np.int64)
    m = len(F)
    corner = np.full((m, 3, 3), np.nan, dtype=np.float32)
    corner_uv = np.asarray(corner_uv, dtype=np.float64)
    for t, image in enumerate(textures):
        faces = np.flatnonzero(face_texture == t)
        if len(faces) == 0:
            continue
        uv = corner_uv[faces]                                           # (k, 3, 2)
        # corner c's samples mix its own, the next and the previous corner's coordinates
        own, nxt, prv = uv, np.roll(uv, -1, axis=1), np.roll(uv, 1, axis=1)
        w = _CORNER_SAMPLES
        points = (w[None, None, :, 0, None] * own[:, :, None] + w[None, None, :, 1, None] * nxt[:, :, None]
                  + w[None, None, :, 2, None] * prv[:, :, None])        # (k, 3, 4, 2)
        samples = sample_texture(image, points.reshape(-1, 2), clamp=bool(clamp[t]) if clamp else False)
        corner[faces] = samples.reshape(len(faces), 3, len(w), 3).mean(axis=2)
    if face_colour is not None:
        plain = face_texture < 0
        corner[plain] = np.asarray(face_colour, dtype=np.float32)[plain][:, None, :]
    if np.isnan(corner).any():
        return None
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    weight = np.repeat(area + 1e-30, 3)          # a degenerate face still colours its corners
    total = np.zeros((len(V), 3))
    for channel in range(3):
        total[:, channel] = np.bincount(F.ravel(), weights=weight * corner[:, :, channel].ravel(), minlength=len(V))
    mass = np.bincount(F.ravel(), weights=weight, minlength=len(V))
    used = mass > 0
    colours = np.empty((len(V), 3))
    colours[used] = total[used] / mass[used, None]
    colours[~used] = colours[used].mean(axis=0) if used.any() else 0.5
    return np.clip(colours, 0.0, 1.0).astype(np.float32)


__all__ = ["MAX_TEXTURE_PIXELS", "RESOURCE_SUFFIXES", "bake_vertex_colours", "directory_resources", "load_texture", "resource_name",
           "sample_texture", "texture_array"]
