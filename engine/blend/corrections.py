"""Hybrid corrections: sparse quantised rows per (reference, phase sample) and their file encoding.

In memory a row is a list of vertex indices with one int8 (x, y, z) value each and one float32
scale (what ``HybridBlender`` scatters on the hot path). In a motion-space file the vertex set
of each row is written in whichever form is smaller, decided by the row's entry count alone:

- an index list, 2 bytes per entry (4 above 65,536 vertices), or
- a bitmask over all n vertices, ceil(n / 8) bytes (bit v of the row set = vertex v corrected),

so a row that corrects more than n / 16 vertices costs ceil(n / 8) bytes for its vertex set
instead of 2 per entry. Decoding (once, at load) gives back the index lists exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def vector_lengths(x):
    """The lengths of (..., 3) vectors: ``np.linalg.norm(x, axis=-1)`` to the bit (the same three
    squares summed in the same order, in ``x``'s dtype) without its (..., 3) temporary and its
    strided reduction, about 3 times faster; the hybrid build measures every test point's error
    this way."""
    return np.sqrt(x[..., 0] * x[..., 0] + x[..., 1] * x[..., 1] + x[..., 2] * x[..., 2])


QUANT_LEVELS = 127  # int8 range used by quantised corrections


def vertex_dtype(n_vertices):
    """uint16 when every vertex index fits, else uint32."""
    return np.dtype(np.uint16 if n_vertices <= np.iinfo(np.uint16).max + 1 else np.uint32)


def mask_rows(counts, n_vertices):
    """(K,) bool: rows whose vertex set is stored as a bitmask (smaller than the index list).

    counts : (K,) int array   entries per row
    """
    counts = np.asarray(counts, dtype=np.int64)
    return (n_vertices + 7) // 8 < counts * vertex_dtype(n_vertices).itemsize


@dataclass
class Corrections:
    """Hierarchical sparse corrections, one entry list per (reference, phase sample).

    Attributes
    ----------
    n_phases : int
    n_vertices : int
    pointer : (R * P + 1,) int64       entries of reference r at phase p: pointer[r*P+p] .. [r*P+p+1]
    vertex : (E,) uint16 or uint32     vertex of each entry, ascending within a row
    value : (E, 3) int8                quantised residual delta (multiply by ``scale[r*P+p]``)
    scale : (R * P,) float32           metres per quantisation step, per reference and phase

    Notes
    -----
    Quantisation error is at most half a step per component, max |delta| / 254 for that
    reference and phase; the bisection measures errors with these stored values.
    """

    n_phases: int
    n_vertices: int
    pointer: np.ndarray
    vertex: np.ndarray
    value: np.ndarray
    scale: np.ndarray

    @property
    def n_references(self):
        return len(self.scale) // self.n_phases

    def nbytes(self):
        """Storage of the corrections: the bytes of the arrays a motion-space file holds
        (``to_arrays``), counted without encoding them."""
        counts = np.diff(np.asarray(self.pointer, dtype=np.int64))
        masked = mask_rows(counts, self.n_vertices)
        vertex_bytes = (int(counts[~masked].sum()) * vertex_dtype(self.n_vertices).itemsize
                        + int(masked.sum()) * ((self.n_vertices + 7) // 8))
        return self.pointer.nbytes + vertex_bytes + self.value.nbytes + self.scale.nbytes

    def entries(self, r, p):
        k = r * self.n_phases + p
        s, e = self.pointer[k], self.pointer[k + 1]
        return self.vertex[s:e], self.value[s:e], self.scale[k]

    def dense(self, r, n_vertices=None):
        """(P, n, 3) float32 residual delta of reference r (for analysis and tests)."""
        out = np.zeros((self.n_phases, self.n_vertices, 3), dtype=np.float32)
        for p in range(self.n_phases):
            vertex, value, scale = self.entries(r, p)
            out[p, vertex] = value * scale
        return out

    def to_arrays(self):
        """The arrays a motion-space file stores (docs/file-formats.md, "Motion space files").

        Returns
        -------
        arrays : dict   ``pointer`` (R P + 1,) int64, ``vertex`` (E_list,) uint16/uint32 (the
                        index-list rows' vertices, row after row), ``mask`` (M, ceil(n / 8)) uint8
                        (the bitmask rows, bit order little: vertex v is bit v % 8 of byte v // 8),
                        ``value`` (E, 3) int8, ``scale`` (R P,) float32
        """
        counts = np.diff(np.asarray(self.pointer, dtype=np.int64))
        masked = mask_rows(counts, self.n_vertices)
        row_of_entry = np.repeat(np.arange(len(counts)), counts)
        listed = ~masked[row_of_entry]
        mask = np.zeros((int(masked.sum()), (self.n_vertices + 7) // 8), dtype=np.uint8)
        if len(mask):
            bits = np.zeros((len(mask), mask.shape[1] * 8), dtype=bool)
            slot = np.cumsum(masked) - 1  # row -> its bitmask
            chosen = ~listed
            bits[slot[row_of_entry[chosen]], np.asarray(self.vertex)[chosen].astype(np.intp)] = True
            mask = np.packbits(bits, axis=1, bitorder="little")
        return {"pointer": np.asarray(self.pointer, dtype=np.int64),
                "vertex": np.asarray(self.vertex)[listed].astype(vertex_dtype(self.n_vertices)),
                "mask": mask, "value": np.asarray(self.value), "scale": np.asarray(self.scale)}

    @classmethod
    def from_arrays(cls, n_phases, n_vertices, arrays):
        """Corrections from ``to_arrays``'s arrays (views of a mapped file are fine: ``value``
        and ``scale`` are used as they are, the vertex lists are decoded once)."""
        pointer = np.asarray(arrays["pointer"], dtype=np.int64)
        counts = np.diff(pointer)
        masked = mask_rows(counts, n_vertices)
        listed, mask = np.asarray(arrays["vertex"]), np.asarray(arrays["mask"])
        if len(mask) != masked.sum() or len(listed) != counts[~masked].sum():
            raise ValueError(f"corrections: {len(mask)} bitmask rows and {len(listed)} listed entries, "
                             f"the pointer needs {masked.sum()} and {counts[~masked].sum()}")
        vertex = np.empty(int(pointer[-1]), dtype=vertex_dtype(n_vertices))
        cursor, slot = 0, 0
        for k in np.flatnonzero(counts):
            s, e = pointer[k], pointer[k + 1]
            if masked[k]:
                row = np.flatnonzero(np.unpackbits(mask[slot], count=n_vertices, bitorder="little"))
                slot += 1
                if len(row) != e - s:
                    raise ValueError(f"corrections: bitmask of row {k} sets {len(row)} vertices, "
                                     f"the pointer gives {e - s}")
                vertex[s:e] = row
            else:
                vertex[s:e] = listed[cursor:cursor + e - s]
                cursor += e - s
        return cls(n_phases=n_phases, n_vertices=n_vertices, pointer=pointer, vertex=vertex,
                   value=arrays["value"], scale=arrays["scale"])


class CorrectionBuilder:
    """Accumulates quantised sparse residuals reference by reference."""

    def __init__(self, n_phases, n_vertices):
        self.n_phases, self.n_vertices = n_phases, n_vertices
        self.vertex_dtype = vertex_dtype(n_vertices)
        self.counts, self.vertices, self.values, self.scales = [], [], [], []

    def add(self, delta, threshold):
        """Store (P, n, 3) residual ``delta`` where |delta| > threshold; returns what is stored."""
        keep = vector_lengths(delta) > threshold
        stored = np.zeros_like(delta, dtype=np.float32)
        for p in range(self.n_phases):
            index = np.flatnonzero(keep[p])
            peak = float(np.abs(delta[p, index]).max()) if len(index) else 0.0
            scale = np.float32(peak / QUANT_LEVELS if peak > 0 else 1.0)
            q = np.clip(np.rint(delta[p, index] / scale), -QUANT_LEVELS, QUANT_LEVELS).astype(np.int8)
            self.counts.append(len(index))
            self.vertices.append(index.astype(self.vertex_dtype))
            self.values.append(q)
            self.scales.append(scale)
            stored[p, index] = q * scale
        return stored

    def add_empty(self):
        self.counts += [0] * self.n_phases
        self.vertices += [np.zeros(0, self.vertex_dtype)] * self.n_phases
        self.values += [np.zeros((0, 3), np.int8)] * self.n_phases
        self.scales += [np.float32(1.0)] * self.n_phases

    def finish(self):
        pointer = np.concatenate([[0], np.cumsum(self.counts)]).astype(np.int64)
        return Corrections(n_phases=self.n_phases, n_vertices=self.n_vertices, pointer=pointer,
                           vertex=np.concatenate(self.vertices).astype(self.vertex_dtype),
                           value=np.concatenate(self.values).reshape(-1, 3).astype(np.int8),
                           scale=np.asarray(self.scales, dtype=np.float32))
