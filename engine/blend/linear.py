"""Linear vertex blending of sources on a phase grid: M_L(t, w) = sum_i w_i M_i(t) / sum_i w_i."""

from __future__ import annotations

import numpy as np
from scipy.linalg.blas import sgemv

from engine.blend.phase import phase_samples


def blend_rows(flat_sources, coefficients, p0, p1, a, out):
    """Linear blend between phase samples into ``out``, one pass over the sources' rows.

    Parameters
    ----------
    flat_sources : (P, N, m) float32 C-contiguous array   each source's frame as one row
    coefficients : (N,) float array                       normalised weights
    p0, p1, a : int, int, float                           as ``phase_samples`` gives them
    out : (m,) float32 array                              written and returned

    Notes
    -----
    Neighbouring samples (p1 = p0 + 1) are adjacent in memory, so both are one (2N, m)
    matrix and the blend one BLAS product with the 2N coefficients (1 - a) c, a c; the
    wrap of a cyclic grid (p1 = 0) adds the second sample in place (gemv with beta = 1).
    """
    c = np.asarray(coefficients, dtype=np.float32)
    if p1 == p0 + 1:
        both = flat_sources[p0:p0 + 2].reshape(2 * flat_sources.shape[1], -1)
        return np.dot(np.concatenate([c * np.float32(1.0 - a), c * np.float32(a)]), both, out=out)
    np.dot(c * np.float32(1.0 - a), flat_sources[p0], out=out)
    if a != 0.0:
        result = sgemv(a, flat_sources[p1].T, c, beta=1.0, y=out, overwrite_y=1)
        if result is not out:  # only when out is not a contiguous float32 array
            out[...] = result
    return out


class LinearBlender:
    """Linear blends of N sources on a phase grid, interpolating between phase samples.

    Parameters
    ----------
    sources : (P, N, n, 3) float32 array   phase-major
    cyclic : bool
    """

    def __init__(self, sources, cyclic):
        self.sources = sources
        self.n_phases, self.n_sources, self.n_vertices = sources.shape[:3]
        self._flat = np.ascontiguousarray(sources, dtype=np.float32).reshape(self.n_phases, self.n_sources, -1)
        self.cyclic = bool(cyclic)

    def blend(self, weights, phase, out=None):
        """Blended vertices (n, 3) float32 at ``weights`` (N,) and ``phase`` in [0, 1]."""
        w = np.asarray(weights, dtype=np.float64)
        p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
        flat = np.empty(self.n_vertices * 3, dtype=np.float32) if out is None else out.reshape(-1)
        return blend_rows(self._flat, w / w.sum(), p0, p1, a, flat).reshape(-1, 3)

    def blend_all_phases(self, weights):
        """(P, n, 3) float64 linear blend at every phase sample."""
        w = np.asarray(weights, dtype=np.float64)
        return np.einsum("i,pinc->pnc", w / w.sum(), self.sources, dtype=np.float64)
