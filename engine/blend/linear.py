"""Linear vertex blending of sources on a phase grid: M_L(t, w) = sum_i w_i M_i(t) / sum_i w_i."""

from __future__ import annotations

import numpy as np

from engine.blend.phase import phase_samples


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
        self._flat = sources.reshape(self.n_phases, self.n_sources, -1)
        self.cyclic = bool(cyclic)

    def blend(self, weights, phase, out=None):
        """Blended vertices (n, 3) float32 at ``weights`` (N,) and ``phase`` in [0, 1]."""
        w = np.asarray(weights, dtype=np.float64)
        c = (w / w.sum()).astype(np.float32)
        p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
        flat = np.empty(self.n_vertices * 3, dtype=np.float32) if out is None else out.reshape(-1)
        np.dot(c * np.float32(1.0 - a), self._flat[p0], out=flat)
        flat += np.dot(c * np.float32(a), self._flat[p1])
        return flat.reshape(-1, 3)

    def blend_all_phases(self, weights):
        """(P, n, 3) float64 linear blend at every phase sample."""
        w = np.asarray(weights, dtype=np.float64)
        return np.einsum("i,pinc->pnc", w / w.sum(), self.sources, dtype=np.float64)
