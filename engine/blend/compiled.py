"""The stream's per-frame row arithmetic, compiled (numba): one pass per frame instead of one
numpy pass (and temporary) per operation.

- :func:`interpolate_at`: K frames of a phase table at their phases, ``rows[p0] + a * (rows[p1]
  - rows[p0])`` each (the samples found in the pass), cast to the output's type (float32, or
  uint16 codes from a table held in codec units): the same float32 operations as the numpy
  formulation (``PhaseTable.rows_at``), so the same bytes.
- :func:`combine_rows`: K frames that are each a weighted sum of a few rows of a stack (a hybrid
  frame: its simplex leaf's reference blends at the two phase samples around its phase), summed
  in float32 in the order given, and optionally quantised in the same pass (``q = clip(v *
  scale + offset, 0, 65535)`` truncated to uint16: ``server.codecs.Quantiser``'s float32
  steps). Worked in blocks of a few thousand values, so the partial sums stay in the first-level
  cache; a frame of four or six terms (two or three references) sums all of them in one pass
  over a block (the same operations in the same order; 35-40% less time than a pass per term).
- :func:`hybrid_terms`: the terms of K hybrid frames for ``combine_rows`` (the walk down the
  simplex tree to each frame's leaf and its phase samples), the arithmetic of the Python it
  replaced (engine/blend/many.py), so the same coefficients.
- :func:`encode_q16`: one frame's q16 codes (the same float32 steps), for frames blended one at
  a time (motion graphs, the non-linear mode).

Compiled on first use (a second or two) and cached on disk (:func:`engine.jit.compiled`);
:func:`warm_up` compiles them ahead (a server does so before it serves).
"""

from __future__ import annotations

import numpy as np

from engine.jit import compiled

BLOCK = 2048  # float32 values of partial sums kept in cache at a time (8 KB)


@compiled
def _interpolate_at(rows, phases, cyclic, out):  # pragma: no cover (compiled; tested through interpolate_at)
    P = rows.shape[0]
    K, m = out.shape
    for k in range(K):
        phase = phases[k]
        if cyclic:  # engine.blend.phase.phase_samples
            x = (phase % 1.0) * P
            p0 = int(x) % P
            p1 = (p0 + 1) % P
            a = x - int(x)
        else:
            x = min(max(phase, 0.0), 1.0) * (P - 1)
            p0 = min(int(x), P - 2)
            p1 = p0 + 1
            a = x - p0
        ak = np.float32(a)
        r = rows[p0]
        r1 = rows[p1]
        o = out[k]
        for i in range(m):
            o[i] = (r1[i] - r[i]) * ak + r[i]


def interpolate_at(rows, phases, cyclic, out):
    """K frames of a phase table at K phases: ``rows[p0] + a * (rows[p1] - rows[p0])`` each, cast
    to ``out``'s type, in float32, with each frame's samples p0, p1 and fraction a (rounded to
    float32) as ``engine.blend.phase.phase_samples`` gives them, found in the same pass. The
    difference is taken in the pass (the float32 subtraction a table of stored differences would
    hold: the same bytes), so a table is its rows alone: 32 phases of 3,000 vertices are 1.15 MB,
    which stays in a core's second-level cache where rows and differences would not.

    rows : (P, m) float32 C-contiguous;  phases : (K,) float64;  cyclic : bool;
    out : (K, m) float32 or uint16 (rows contiguous). Returns ``out``.
    """
    _interpolate_at(rows, phases, cyclic, out)
    return out


@compiled
def _combine_rows(stack, ref, phase, coef, starts, scale, offset, encode, out_f32, out_u16):  # pragma: no cover
    K = len(starts) - 1
    m = stack.shape[2]
    scratch = np.empty(BLOCK, dtype=np.float32)
    for k in range(K):
        s, e = starts[k], starts[k + 1]
        for b0 in range(0, m, BLOCK):
            n = min(BLOCK, m - b0)
            partial = scratch[:n]  # (slices: the loops below vectorise)
            if e - s == 6:  # a hybrid frame's usual shape (three references, two samples each):
                # every term in one pass, the partial sums in registers (the same sums in the
                # same order as the general loop below, in fewer passes over the block)
                r0, r1, r2 = stack[ref[s], phase[s], b0:b0 + n], stack[ref[s + 1], phase[s + 1], b0:b0 + n], \
                    stack[ref[s + 2], phase[s + 2], b0:b0 + n]
                r3, r4, r5 = stack[ref[s + 3], phase[s + 3], b0:b0 + n], stack[ref[s + 4], phase[s + 4], b0:b0 + n], \
                    stack[ref[s + 5], phase[s + 5], b0:b0 + n]
                c0, c1, c2, c3, c4, c5 = coef[s], coef[s + 1], coef[s + 2], coef[s + 3], coef[s + 4], coef[s + 5]
                for i in range(n):
                    v = r0[i] * c0
                    v = r1[i] * c1 + v
                    v = r2[i] * c2 + v
                    v = r3[i] * c3 + v
                    v = r4[i] * c4 + v
                    partial[i] = r5[i] * c5 + v
            elif e - s == 4:  # (two references)
                r0, r1 = stack[ref[s], phase[s], b0:b0 + n], stack[ref[s + 1], phase[s + 1], b0:b0 + n]
                r2, r3 = stack[ref[s + 2], phase[s + 2], b0:b0 + n], stack[ref[s + 3], phase[s + 3], b0:b0 + n]
                c0, c1, c2, c3 = coef[s], coef[s + 1], coef[s + 2], coef[s + 3]
                for i in range(n):
                    v = r0[i] * c0
                    v = r1[i] * c1 + v
                    v = r2[i] * c2 + v
                    partial[i] = r3[i] * c3 + v
            elif s == e:
                partial[:] = 0.0
            else:
                row = stack[ref[s], phase[s], b0:b0 + n]
                c = coef[s]
                for i in range(n):
                    partial[i] = row[i] * c
                for t in range(s + 1, e):
                    row = stack[ref[t], phase[t], b0:b0 + n]
                    c = coef[t]
                    for i in range(n):
                        partial[i] = row[i] * c + partial[i]
            if encode:
                codes = out_u16[k, b0:b0 + n]
                sc, of = scale[b0:b0 + n], offset[b0:b0 + n]
                for i in range(n):
                    q = partial[i] * sc[i] + of[i]
                    codes[i] = np.uint16(min(max(q, np.float32(0.0)), np.float32(65535.0)))
            else:
                values = out_f32[k, b0:b0 + n]
                for i in range(n):
                    values[i] = partial[i]


def combine_rows(stack, ref, phase, coef, starts, out, codes=None):
    """K frames, frame k the float32 sum over t in [starts[k], starts[k + 1]) of
    ``coef[t] * stack[ref[t], phase[t]]`` (the first term a product, each later one added, in
    that order), written to ``out`` (K, m) float32; with ``codes`` = (scale, offset), (m,)
    float32 each, ``out`` is (K, m) uint16 and gets ``clip(v * scale + offset, 0, 65535)``
    truncated (the q16 codes). Returns ``out``.

    stack : (R, P, m) float32 C-contiguous;  ref, phase : (T,) int64;  coef : (T,) float32;
    starts : (K + 1,) int64.
    """
    if codes is None:
        _combine_rows(stack, ref, phase, coef, starts, _NO_CODES, _NO_CODES, False, out, _NO_U16)
    else:
        _combine_rows(stack, ref, phase, coef, starts, codes[0], codes[1], True, _NO_F32, out)
    return out


@compiled
def _hybrid_terms(lam, phases, children, split, cells, n_phases, cyclic, ref, sample, coef, starts):  # pragma: no cover
    K, N = lam.shape
    t = 0
    for k in range(K):
        g = lam[k]
        node = 0
        while children[node, 0] >= 0:  # down to w's leaf, g turned into its barycentric coordinates
            i, j = split[node, 0], split[node, 1]
            li, lj = g[i], g[j]
            if li >= lj:
                g[i], g[j] = li - lj, 2.0 * lj
                node = children[node, 0]
            else:
                g[j], g[i] = lj - li, 2.0 * li
                node = children[node, 1]
        phase = phases[k]
        if cyclic:  # engine.blend.phase.phase_samples
            x = (phase % 1.0) * n_phases
            p0 = int(x) % n_phases
            p1, a = (p0 + 1) % n_phases, x - int(x)
        else:
            x = min(max(phase, 0.0), 1.0) * (n_phases - 1)
            p0 = min(int(x), n_phases - 2)
            p1, a = p0 + 1, x - p0
        for c in range(N):
            gc = g[c]
            if gc <= 0.0:
                continue
            c0, c1 = gc * (1.0 - a), gc * a
            if c0 != 0.0:
                ref[t], sample[t], coef[t] = cells[node, c], p0, c0
                t += 1
            if c1 != 0.0:
                ref[t], sample[t], coef[t] = cells[node, c], p1, c1
                t += 1
        starts[k + 1] = t


def hybrid_terms(lam, phases, children, split, cells, n_phases, cyclic):
    """The terms of K hybrid frames for :func:`combine_rows`: frame k is sum_j g_j ((1 - a)
    H_j[p0] + a H_j[p1]) over the references j of its simplex leaf with g_j > 0 (terms of zero
    coefficient left out), in the leaf's order, p0 before p1 (engine/blend/many.py).

    lam : (K, N) float64 C-contiguous   normalised weights (overwritten with the barycentric
                                        coordinates in each row's leaf)
    phases : (K,) float64;  children, split, cells : (C, 2), (C, 2), (C, N) int64 (the tree's)
    Returns (ref, sample, coef, starts): (T,) int64, (T,) int64, (T,) float32 (the float64
    products rounded), (K + 1,) int64.
    """
    K, N = lam.shape
    ref, sample = np.empty(2 * K * N, dtype=np.int64), np.empty(2 * K * N, dtype=np.int64)
    coef, starts = np.empty(2 * K * N, dtype=np.float32), np.zeros(K + 1, dtype=np.int64)
    _hybrid_terms(lam, phases, children, split, cells, n_phases, cyclic, ref, sample, coef, starts)
    T = starts[K]
    return ref[:T], sample[:T], coef[:T], starts


# the output (and codes) ``_combine_rows`` is not given: fixed types, never read or written
_NO_CODES, _NO_F32, _NO_U16 = np.empty(0, np.float32), np.empty((1, 1), np.float32), np.empty((1, 1), np.uint16)


@compiled
def _encode_q16(values, scale, offset, out):  # pragma: no cover (compiled; tested through encode_q16)
    for i in range(values.shape[0]):
        q = values[i] * scale[i] + offset[i]
        out[i] = np.uint16(min(max(q, np.float32(0.0)), np.float32(65535.0)))


def encode_q16(values, scale, offset, out=None):
    """(m,) uint16 ``clip(values * scale + offset, 0, 65535)`` truncated, in float32 (the q16
    codes of flat vertices: ``server.codecs.Quantiser``), in one pass.

    values, scale, offset : (m,) float32 C-contiguous; ``out``: (m,) uint16 to write, else a new
    array. Returns it.
    """
    if out is None:
        out = np.empty(values.shape[0], dtype="<u2")
    _encode_q16(values, scale, offset, out)
    return out


def warm_up():
    """Compile (or load from numba's cache) the stream's compiled loops for the types it uses:
    every kernel here, and the parameter map's Newton solve."""
    from engine.parameters.parameter_map import warm_up as warm_up_solve

    warm_up_solve()
    rows = np.zeros((2, 4), dtype=np.float32)
    for dtype in ("<f4", "<u2"):
        for cyclic in (True, False):
            interpolate_at(rows, np.zeros(1), cyclic, np.empty((1, 4), dtype=dtype))
    stack = np.zeros((1, 2, 4), dtype=np.float32)
    terms = np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64), np.ones(1, dtype=np.float32)
    starts = np.array([0, 1], dtype=np.int64)
    # ManyBlender's rows: padded, so not C-contiguous (numpy calls a single row contiguous: two)
    padded = np.empty((2, 16), dtype=np.float32)[:, :4]
    combine_rows(stack, *terms, np.array([0, 1, 1], dtype=np.int64), padded)
    combine_rows(stack, *terms, starts, np.empty((1, 4), dtype=np.float32))
    codes = np.ones(4, dtype=np.float32), np.zeros(4, dtype=np.float32)
    combine_rows(stack, *terms, starts, np.empty((1, 4), dtype=np.uint16), codes)
    encode_q16(np.zeros(4, dtype=np.float32), *codes)
    nodes = np.array([[-1, -1]], dtype=np.int64)
    hybrid_terms(np.ones((1, 2)), np.zeros(1), nodes, nodes, np.zeros((1, 2), dtype=np.int64), 2, True)


__all__ = ["combine_rows", "encode_q16", "hybrid_terms", "interpolate_at", "warm_up"]
