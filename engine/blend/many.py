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
  sum_j g_j ((1 - a) H_j[p0] + a H_j[p1]): two contiguous row passes per reference with g_j > 0
  (2 or 3 on a layout's sheet), instead of the 2N source rows, about five dense correction rows
  and the scattered entries of the others, with no per-node work beyond the walk to the leaf.
  The result equals ``HybridBlender.blend`` to float32 rounding (a few 1e-7 m on a body of
  1.75 m), not bit for bit.

Every row is computed on its own, with the same calls whatever else is in the batch, into a row
that starts on a 64-byte boundary: a batch of K gives the bytes of K calls of one row each.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.blas import saxpy

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
            self._cells = tree.cells.tolist()
            self._children, self._split = blender._children, blender._split
            self._rows = [None] * len(self._references)  # reference -> (P, 3n) hybrid blends, made on first use

    def reference_rows(self, r):
        """(P, 3 n) float32: the hybrid blend at reference ``r`` at every phase sample."""
        rows = self._rows[r]
        if rows is None:
            P = self.n_phases
            rows = np.empty((P, 3 * self.n_vertices), dtype=np.float32)
            for p in range(P):
                self.blender.blend(self._references[r], phase_of_sample(p, P, self.cyclic), out=rows[p].reshape(-1, 3))
            self._rows[r] = rows
        return rows

    def _leaf(self, lam):
        """w's leaf and its barycentric coordinates there (``lam`` normalised weights, a list,
        turned into them)."""
        node, children, split = 0, self._children, self._split
        while children[node][0] >= 0:
            i, j = split[node]
            li, lj = lam[i], lam[j]
            if li >= lj:
                lam[i], lam[j] = li - lj, 2.0 * lj
                node = children[node][0]
            else:
                lam[j], lam[i] = lj - li, 2.0 * li
                node = children[node][1]
        return node

    def _hybrid_row(self, lam, phase, out):
        p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
        first = True
        made = self._rows
        for g, r in zip(lam, self._cells[self._leaf(lam)]):
            if g <= 0.0:
                continue
            rows = made[r]
            if rows is None:
                rows = self.reference_rows(r)
            for p, c in ((p0, g * (1.0 - a)), (p1, g * a)):
                if c == 0.0:
                    continue
                if first:  # c x, as 0 + c x would give
                    np.multiply(rows[p], np.float32(c), out=out)
                    first = False
                else:
                    saxpy(rows[p], out, a=c)  # in place, one pass
        if first:  # (weights never all zero: unreachable)
            out[...] = 0.0

    def blend(self, weights, phases):
        """(K, 3 n) float32 blends of ``weights`` (K, N) non-negative, not all zero per row, at
        ``phases`` (K,) in [0, 1]."""
        W = np.asarray(weights, dtype=np.float64)
        if W.ndim != 2 or len(W) != len(phases):
            raise ValueError(f"expected (K, N) weights and K phases, got {W.shape} and {len(phases)}")
        out = aligned_rows(len(W), 3 * self.n_vertices)
        if self.hybrid:
            for lam, phase, row in zip((W / W.sum(axis=1, keepdims=True)).tolist(), phases, out):
                self._hybrid_row(lam, phase, row)
        else:
            flat = self.blender._flat
            for w, phase, row in zip(W, phases, out):
                p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
                blend_rows(flat, w / w.sum(), p0, p1, a, row)  # as LinearBlender.blend
        return out
