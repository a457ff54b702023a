"""Vertex codecs of the stream: ``f32`` (float32 triples) and ``q16`` (uint16 triples quantised
over the topology's bounds: ``v = bounds_min + q * (bounds_max - bounds_min) / 65535``).
"""

from __future__ import annotations

import numpy as np

from engine.blend.compiled import encode_q16


def quantisation_error(bounds):
    """Largest distance (m) between a point in ``bounds`` and its q16 reconstruction: half a
    step along each axis."""
    step = (np.asarray(bounds[1], dtype=np.float64) - np.asarray(bounds[0], dtype=np.float64)) / 65535.0
    return float(np.linalg.norm(step / 2))


class Quantiser:
    """The q16 codec over a box: ``q = round((v - lo) * 65535 / (hi - lo))`` per axis, clamped
    to [0, 65535].

    ``Quantiser(bounds, n_vertices).encode(V)`` is the hot path: the per-axis scale and offset
    are tiled over the flat (x, y, z, x, ...) array once, so every step is one contiguous pass.
    ``scale`` and ``offset`` (3,) float32 map metres to the codec's units *before* rounding
    (``offset`` includes the + 0.5 of round-to-nearest): ``floor(v * scale + offset)``.
    """

    def __init__(self, bounds, n_vertices):
        lo, hi = np.asarray(bounds[0], dtype=np.float32), np.asarray(bounds[1], dtype=np.float32)
        self.scale = (np.float32(65535.0) / np.maximum(hi - lo, np.float32(1e-12))).astype(np.float32)
        self.offset = (np.float32(0.5) - lo * self.scale).astype(np.float32)
        self.n_vertices = int(n_vertices)
        self._scale = np.tile(self.scale, self.n_vertices)
        self._offset = np.tile(self.offset, self.n_vertices)
        self.codes = (self._scale, self._offset)  # per flat value: what compiled encoders take
        self.key = ("q16", self.scale.tobytes(), self.offset.tobytes())

    def encode(self, V):
        """Raw little-endian uint16 bytes of (n, 3) vertices."""
        return self.encode_array(V).tobytes()

    def encode_array(self, V):
        """The encoded (3 n,) little-endian uint16 array of (n, 3) vertices (a new array each
        call: its raw bytes are ``encode(V)``): ``floor(clip(v * scale + offset, 0, 65535))`` in
        float32, one compiled pass (engine/blend/compiled.py)."""
        flat = np.ascontiguousarray(V, dtype=np.float32).reshape(-1)
        if flat.shape[0] != self._scale.shape[0]:
            raise ValueError(f"expected {self.n_vertices} vertices, got {flat.shape[0] / 3:g}")
        return encode_q16(flat, self._scale, self._offset)

    def table(self, table):
        """A PhaseTable (engine.blend.cache) in codec units: interpolating its rows and
        truncating to uint16 gives the encoded frame."""
        return table.scaled(self.scale, self.offset, 0.0, 65535.0, key=self.key)


def encode_vertices(V, codec, bounds):
    """Raw little-endian bytes of (n, 3) vertices in ``codec``; q16 clamps to ``bounds``."""
    if codec == "f32":
        return np.ascontiguousarray(V, dtype="<f4").tobytes()
    return Quantiser(bounds, len(V)).encode(V)


def decode_vertices(data, codec, n_vertices, bounds_min=None, bounds_max=None):
    """(n, 3) float32 vertices from a frame's bytes (the inverse of encode_vertices)."""
    if codec == "f32":
        return np.frombuffer(data, dtype="<f4").reshape(n_vertices, 3)
    lo = np.asarray(bounds_min, dtype=np.float32)
    hi = np.asarray(bounds_max, dtype=np.float32)
    q = np.frombuffer(data, dtype="<u2").reshape(n_vertices, 3).astype(np.float32)
    return lo + q * ((hi - lo) / np.float32(65535.0))
