"""A played clip as a vertex-animation texture (VAT) with its mesh, for Unity and Unreal shaders.

Three files, in a directory or a ``.zip``:

- ``mesh.glb``: the first frame's root-local mesh (glTF 2.0, float32) whose ``TEXCOORD_0`` (the
  mesh has no other texture coordinates) is each vertex's texel in the texture: u = (column + 0.5) / width, v = (row + 0.5) / height of
  the vertex's first row, rows counted from the top of the image (glTF's convention; flip v for
  engines that count from the bottom);
- ``positions.png``: 16-bit RGB; frame k's vertex i is the texel at column i % width, row
  k * rows_per_frame + i // width, holding its displacement from the mesh (x, y, z in metres)
  mapped from [minimum, maximum] per axis to [0, 65535]: displacement = minimum + texel / 65535 *
  (maximum - minimum). Up to 8,192 vertices a frame take one row; more wrap onto further rows.
- ``vat.json``: width, height, frames, rows_per_frame, rate, the per-axis minimum and maximum,
  the largest rounding error (half a step of the widest axis), and the root motion per frame
  (root position and heading, which a script applies to the object's transform).

A vertex shader reads the texel of (its TEXCOORD_0, moved down frame * rows_per_frame rows), decodes the
displacement and adds it to the vertex position; between frames it may blend two rows.
"""

from __future__ import annotations

import json
import math
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

from engine.export.glb_container import ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, FLOAT, UNSIGNED_INT, UNSIGNED_SHORT, \
    GlbBuffer
from engine.export.sequence import write_member
from engine.mesh_io.atomic import atomic_write, discard_partial

MAX_WIDTH = 8192  # what Unity and Unreal import on every platform
LEVELS = 65535


def vat_layout(n_vertices, n_frames):
    """(width, rows per frame, height) of the texture for ``n_vertices`` x ``n_frames``."""
    width = min(n_vertices, MAX_WIDTH)
    rows = math.ceil(n_vertices / width)
    height = rows * n_frames
    if height > MAX_WIDTH * 4:
        raise ValueError(f"{n_frames} frames of {n_vertices} vertices need a {width} x {height} texture; at most "
                         f"{MAX_WIDTH * 4} rows: export a shorter clip or a lower rate")
    return width, rows, height


def png16_bytes(rgb):
    """A 16-bit RGB PNG of ``rgb`` ((h, w, 3) uint16), rows filtered with 'Up' (smaller for smooth motion)."""
    height, width, _ = rgb.shape
    rows = rgb.astype(">u2").view(np.uint8).reshape(height, width * 6)
    up = rows.copy()
    up[1:] = rows[1:] - rows[:-1]  # PNG filter 2 (Up), modulo 256
    raw = np.empty((height, width * 6 + 1), dtype=np.uint8)
    raw[:, 0] = 2
    raw[0, 0] = 0
    raw[0, 1:] = rows[0]
    raw[1:, 1:] = up[1:]

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 16, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw.tobytes(), 6))
            + chunk(b"IEND", b""))


def vat_files(frames):
    """{file name: bytes} of the VAT export of ``frames`` (ClipFrames), and the record (vat.json)."""
    local = frames.local
    n_frames, n = local.shape[:2]
    width, rows, height = vat_layout(n, n_frames)
    base = local[0]
    delta = local.astype(np.float64) - base
    lo, hi = delta.min(axis=(0, 1)), delta.max(axis=(0, 1))
    span = np.where(hi > lo, hi - lo, 1.0)
    texels = np.rint((delta - lo) / span * LEVELS).astype(np.uint16)
    image = np.zeros((n_frames, rows * width, 3), dtype=np.uint16)
    image[:, :n] = texels
    image = image.reshape(height, width, 3)
    index = np.arange(n)
    uv = np.stack([(index % width + 0.5) / width, (index // width + 0.5) / height], axis=1).astype(np.float32)
    record = {"space": frames.space, "rate": frames.rate, "frames": n_frames, "vertices": n, "width": width,
              "height": height, "rows_per_frame": rows, "encoding": "png16: minimum + texel / 65535 * (maximum - "
              "minimum), metres, added to mesh.glb's positions", "minimum": lo.tolist(), "maximum": hi.tolist(),
              "max_error_m": float(span.max() / LEVELS / 2), "times": np.round(frames.times, 9).tolist(),
              "root_position": np.round(frames.root_position, 9).tolist(),
              "heading_deg": np.round(np.degrees(frames.heading), 9).tolist(), "parameters": list(frames.names)}
    if frames.nodes is not None:  # a graph performance: the node each frame shows
        record["nodes"] = list(frames.nodes)
    return {"mesh.glb": _mesh_glb(base, frames.faces, uv, frames.space), "positions.png": png16_bytes(image),
            "vat.json": json.dumps(record, indent=1).encode()}, record


def _mesh_glb(V, F, uv, name):
    glb = GlbBuffer()
    position = glb.array_accessor(V, FLOAT, "VEC3", target=ARRAY_BUFFER, bounds=True)
    lookup = glb.array_accessor(uv, FLOAT, "VEC2", target=ARRAY_BUFFER)
    indices = glb.array_accessor(np.asarray(F).reshape(-1), UNSIGNED_SHORT if len(V) <= 0xFFFF else UNSIGNED_INT,
                                 "SCALAR", target=ELEMENT_ARRAY_BUFFER)
    document = {"asset": {"version": "2.0", "generator": "morphspace export (vat)"}, "scene": 0,
                "scenes": [{"nodes": [0]}], "nodes": [{"name": "mesh", "mesh": 0}],
                "meshes": [{"name": name, "primitives": [{"attributes": {"POSITION": position, "TEXCOORD_0": lookup},
                                                          "indices": indices, "mode": 4}]}]}
    return glb.to_bytes(document)


def write_vat(path, frames, progress=None):
    """Write the VAT export to ``path``: a directory, or a ``.zip`` archive. Returns the record."""
    files, record = vat_files(frames)
    path = Path(path)
    if path.suffix.lower() == ".zip":
        with atomic_write(path) as out, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as archive:
            for name, data in files.items():
                write_member(archive, name, data)
    else:
        if path.exists() and not path.is_dir():
            raise ValueError(f"{path}: exists and is not a directory")
        created, written = not path.exists(), 0
        try:
            path.mkdir(parents=True, exist_ok=True)
            for name, data in files.items():
                with atomic_write(path / name) as out:
                    out.write(data)
                written += 1
        except BaseException:  # interrupted or failed: no half-written export stays behind
            discard_partial(path, list(files)[:written + 1], created)
            raise
    if progress is not None:
        progress(len(frames), len(frames))
    return record
