"""Many blends at once: ``ManyBlender(blender).blend(W, phases)``, one weight vector and one
phase per row, for a server that blends every moving client of a tick together.

- Linear: each row is ``blend_rows`` of the sources, exactly as ``LinearBlender.blend`` makes it
  (the same BLAS product on the same numbers: the same bytes).
- Hybrid: in w's leaf of the simplex tree (references w_j, barycentric coordinates g_j) the hybrid
  blend is the nodal interpolation M(t, w) = sum_j g_j H(t, w_j) (paper eq. 3: the linear part is
  linear in w, and the correction interpolates the references' corrections; H(t, w_j) =
  M_L(t, w_j) + D_NL(t, w_j) is the hybrid blend at the reference itself). So each reference's
  hybrid blends at the phase samples are made once, by ``HybridBlender.blend``, when a row first
  needs them (P x 3n float32: 1.2 MB for 32 phases of 3,000 vertices), and a frame is
  sum_j g_j ((1 - a) H_j[p0] + a H_j[p1]): a weighted sum of two rows per reference with
  g_j > 0 (2 or 3 on a layout's sheet), made in one compiled pass (engine/blend/compiled.py,
  with the q16 codes in the same pass when asked), instead of the 2N source rows, about five
  dense correction rows and the scattered entries of the others, with no per-node work beyond
  the walk to the leaf. The result equals ``HybridBlender.blend`` to float32 rounding (a few
  1e-7 m on a body of 1.75 m), not bit for bit.

Every row is computed on its own, with the same calls whatever else is in the batch, into a row
that starts on a 64-byte boundary: a batch of K gives the bytes of K calls of one row each.
"""

from __future__ import annotations

import numpy as np

from engine.blend.compiled import combine_rows, encode_q16, hybrid_terms
from engine.blend.hybrid import HybridBlender
from engine.blend.linear import LinearBlender, blend_rows
from engine.blend.phase import phase_of_sample, phase_samples

ALIGN = 16  # float32 values: rows start on 64-byte boundaries


def aligned_rows(K, m):
    """(K, m) float32 array (uninitialised) whose rows are contiguous and start on 64-byte
    boundaries (the row stride is padded to a multiple of 16 values)."""
    stride = -(-m // ALIGN) * ALIGN
    buffer = np.empty(K * stride + ALIGN, dtype=np.float32)
    start = (-buffer.ctypes.data % (4 * ALIGN)) // 4
    return buffer[start:start + K * stride].reshape(K, stride)[:, :m]


class ManyBlender:
    """Blends of K weight vectors, each at its own phase, in one call.

    Parameters
    ----------
    blender : LinearBlender or HybridBlender

    ``rows = many.blend(W, phases)``: (K, 3 n) float32 flat vertices (x, y, z per vertex), each
    row C-contiguous (the array's row stride is padded).
    """

    def __init__(self, blender):
        if not isinstance(blender, (HybridBlender, LinearBlender)):
            raise TypeError(f"ManyBlender blends linear or hybrid blenders, not {type(blender).__name__}")
        self.blender = blender
        self.hybrid = isinstance(blender, HybridBlender)
        self.n_phases, self.n_vertices, self.cyclic = blender.n_phases, blender.n_vertices, blender.cyclic
        if self.hybrid:
            tree = blender.tree
            self._references = tree.references
            self._tree = tree.children, tree.split, tree.cells  # (hybrid_terms' arrays)
            # (R, P, 3n) float32 hybrid blends per reference (untouched pages cost no memory: only
            # the references used fill theirs, on first use)
            self._stack = np.empty((len(self._references), self.n_phases, 3 * self.n_vertices), dtype=np.float32)
            self._made = [False] * len(self._references)  # a reference's rows are made on first use
            self._unmade = len(self._references)

    def reference_rows(self, r):
        """(P, 3 n) float32: the hybrid blend at reference ``r`` at every phase sample."""
        rows = self._stack[r]
        if not self._made[r]:
            P = self.n_phases
            for p in range(P):
                self.blender.blend(self._references[r], phase_of_sample(p, P, self.cyclic), out=rows[p].reshape(-1, 3))
            self._made[r] = True
            self._unmade -= 1
        return rows

    def blend(self, weights, phases, codes=None):
        """(K, 3 n) float32 blends of ``weights`` (K, N) non-negative, not all zero per row, at
        ``phases`` (K,) in [0, 1]; with ``codes`` = (scale, offset), (3 n,) float32 each, the
        q16 codes instead: (K, 3 n) uint16 ``clip(v * scale + offset, 0, 65535)`` truncated
        (``server.codecs.Quantiser``'s steps on the float32 rows: the same bytes)."""
        W = np.asarray(weights, dtype=np.float64)
        if W.ndim != 2 or len(W) != len(phases):
            raise ValueError(f"expected (K, N) weights and K phases, got {W.shape} and {len(phases)}")
        m = 3 * self.n_vertices
        if self.hybrid:  # the terms, then one compiled pass per row over them (engine/blend/compiled.py)
            lam = W / np.add.reduce(W, axis=1, keepdims=True)  # (W.sum's numbers)
            terms = hybrid_terms(lam, np.array(phases, dtype=np.float64), *self._tree,
                                 self.n_phases, self.cyclic)
            if self._unmade:
                for r in set(terms[0].tolist()):
                    self.reference_rows(r)
            out = aligned_rows(len(W), m) if codes is None else np.empty((len(W), m), dtype="<u2")
            return combine_rows(self._stack, *terms, out, codes)
        out = aligned_rows(len(W), m)
        flat = self.blender._flat
        for w, phase, row in zip(W, phases, out):
            p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
            blend_rows(flat, w / w.sum(), p0, p1, a, row)  # as LinearBlender.blend
        if codes is None:
            return out
        encoded = np.empty((len(W), m), dtype="<u2")
        for row, code in zip(out, encoded):
            encode_q16(row, *codes, out=code)
        return encoded
