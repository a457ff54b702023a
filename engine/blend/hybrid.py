"""Hybrid blending: linear blending plus precomputed non-linear corrections (paper eq. 3).

M(t, w) = M_L(t, w) + sum_j g_j(w) D_NL(t, w_j), where the w_j are the reference weights at the
vertices of the simplex cell containing w, g_j are w's barycentric coordinates there and
D_NL(t, w_j) = M_NL(t, w_j) - M_L(t, w_j). The references and corrections are built by
:mod:`engine.blend.hybrid_build` (bisection of the weight simplex); this module blends with them.

Storage is hierarchical and sparse. When a cell is split at the midpoint m of its edge (a, b),
only the part of D_NL(m) that interpolating the edge does not predict is stored:
delta_m = D_NL(m) - (D(a) + D(b)) / 2, per phase sample, only where |delta_m| exceeds a
threshold, quantised to 8 bits per component with one scale per reference and phase. For a
weight vector w the correction is then the sum over the split nodes on w's path down the tree of
phi_m(w) delta_m with phi_m = 2 min(lambda_a, lambda_b) (the hat function of m), which equals the
nodal interpolation of eq. 3 in w's leaf.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.blas import saxpy

from engine.blend.linear import blend_rows
from engine.blend.phase import phase_samples


def hybrid_layout(corrections, n_vertices, dense_above=None, dense_budget=64 << 20):
    """The arrays HybridBlender adds corrections from, beside the corrections themselves.

    corrections : Corrections;  n_vertices : int
    dense_above : int or None   rows listing more vertices than this are also kept dense
                                (default n / 60); dense_budget : int, bytes of dense rows at most
    Returns
    layout : dict   ``flat_index`` (3 E,) intp: the flat (x, y, z) indices of every entry;
                    ``dense_keys`` (K,) int64 (reference, phase) rows kept dense, the largest
                    first, and ``dense_rows`` (K, 3 n) float32 their scaled corrections
    """
    above = n_vertices // 60 if dense_above is None else dense_above
    v = np.asarray(corrections.vertex).astype(np.intp)
    flat_index = (3 * v[:, None] + np.arange(3)).ravel()
    pointer = np.asarray(corrections.pointer, dtype=np.int64)
    counts = np.diff(pointer)
    order = np.argsort(-counts, kind="stable")[:dense_budget // (12 * n_vertices)]
    keys = order[counts[order] > above]
    value = np.asarray(corrections.value).reshape(-1)
    rows = np.zeros((len(keys), 3 * n_vertices), dtype=np.float32)
    for row, k in zip(rows, keys):
        s, e = pointer[k], pointer[k + 1]
        row[flat_index[3 * s:3 * e]] = value[3 * s:3 * e] * np.float32(corrections.scale[k])
    return {"flat_index": flat_index, "dense_keys": keys.astype(np.int64), "dense_rows": rows}


class HybridBlender:
    """Real-time hybrid blends of N sources on a phase grid.

    ``blender = HybridBlender(sources, tree, corrections, cyclic)``;
    ``blender.blend(weights, phase, out)`` is the hot path, close to linear-blend cost.

    Parameters
    ----------
    sources : (P, N, n, 3) float32 array   sources on the phase grid (phase-major layout)
    tree : SimplexTree
    corrections : Corrections
    cyclic : bool
    dense_above : int or None   (reference, phase) corrections listing more vertices than this
                                are also kept dense: adding a dense row is one contiguous BLAS
                                pass (saxpy), cheaper than scattering that many entries
                                (default n / 60)
    dense_budget : int          bytes of dense rows at most (the largest corrections first)
    """

    def __init__(self, sources, tree, corrections, cyclic, *, dense_above=None, dense_budget=64 << 20,
                 layout=None):
        self.sources = sources
        self.n_phases, self.n_sources, self.n_vertices = sources.shape[:3]
        self._flat = np.ascontiguousarray(sources, dtype=np.float32).reshape(self.n_phases, self.n_sources, -1)
        self.cyclic = bool(cyclic)
        self.tree = tree
        self.corrections = corrections
        # The tree walk in plain Python lists (fast scalar access on the hot path).
        self._children = tree.children.tolist()
        self._split = tree.split.tolist()
        self._split_ref = tree.split_references().tolist()
        self._pointer = corrections.pointer.tolist()
        self._value = corrections.value.reshape(-1)
        self._scale = corrections.scale.tolist()
        self._buffer = np.empty(self.n_vertices * 3, dtype=np.float32)
        # Flat (x, y, z) indices of every correction entry (a row scatters into a flat buffer)
        # and the dense rows. ``layout``: hybrid_layout's arrays made beforehand, e.g. mapped
        # from a file several processes share (engine/motion_space/derived.py); only read.
        if layout is None:
            layout = hybrid_layout(corrections, self.n_vertices, dense_above, dense_budget)
        self._flat_index = layout["flat_index"]
        self._dense = dict(zip(layout["dense_keys"].tolist(), layout["dense_rows"]))

    def _add(self, flat, r, p, coefficient):
        k = r * self.n_phases + p
        row = self._dense.get(k)
        if row is not None:
            saxpy(row, flat, a=coefficient)  # in place: one pass over the row
            return
        s, e = self._pointer[k], self._pointer[k + 1]
        if e > s:
            # a (reference, phase) entry lists each vertex once, so plain fancy-index adding is
            # exact (and much faster than np.add.at)
            flat[self._flat_index[3 * s:3 * e]] += self._value[3 * s:3 * e] * np.float32(coefficient * self._scale[k])

    def blend(self, weights, phase, out=None):
        """Blended vertices (n, 3) float32 at ``weights`` (N,) and ``phase`` in [0, 1]."""
        w = np.asarray(weights, dtype=np.float64)
        lam = w / w.sum()
        p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
        flat = self._buffer if out is None else out.reshape(-1)
        if flat.dtype != np.float32 or not flat.flags.c_contiguous:
            raise ValueError("out must be a C-contiguous float32 (n, 3) array")
        blend_rows(self._flat, lam, p0, p1, a, flat)
        node, children, split = 0, self._children, self._split
        lam = lam.tolist()
        while children[node][0] >= 0:
            i, j = split[node]
            li, lj = lam[i], lam[j]
            phi = 2.0 * min(li, lj)
            if phi > 0.0:
                r = self._split_ref[node]
                if a != 1.0:
                    self._add(flat, r, p0, phi * (1.0 - a))
                if a != 0.0:
                    self._add(flat, r, p1, phi * a)
            if li >= lj:
                lam[i], lam[j] = li - lj, 2.0 * lj
                node = children[node][0]
            else:
                lam[j], lam[i] = lj - li, 2.0 * li
                node = children[node][1]
        V = flat.reshape(-1, 3)
        return V if out is not None else V.copy()
