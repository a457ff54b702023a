"""Phase tables: blending at fixed weights reduced to one interpolation per frame.

Linear and hybrid blends are linear in phase between the phase samples: at weights w,

    M(t, w) = (1 - a) B[p0] + a B[p1],    B[p] = sum_i w_i S_i[p] + sum_j phi_j(w) D_j[p]

(``phase_samples`` gives p0, p1, a). So once a weight vector has been asked for a few times, its
table B (P, n, 3) is built (P blends) and every later frame at those weights costs one
interpolation of two rows. This is exact (float32 rounding), not a cache of approximations.
A player whose parameters have settled, or many viewers at the same parameters, hit the table;
moving weights fall through to the blender. Tables are kept least-recently-used, up to
``capacity`` (each is P x n x 3 float32: 1.2 MB for 32 phases of 3,000 vertices).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from engine.blend.phase import phase_of_sample, phase_samples


class PhaseTableBlender:
    """Wraps a linear or hybrid blender (``blend(weights, phase, out=None)``) with phase tables.

    Parameters
    ----------
    blender : LinearBlender or HybridBlender   must be linear in phase between samples
    n_phases : int; cyclic : bool
    capacity : int    tables kept
    after : int       requests at the same weights before a table is built
    """

    def __init__(self, blender, n_phases, cyclic, *, capacity=32, after=3):
        self.blender = blender
        self.n_phases, self.cyclic = int(n_phases), bool(cyclic)
        self.capacity, self.after = int(capacity), int(after)
        self._tables = OrderedDict()
        self._seen = OrderedDict()
        self.hits = self.misses = self.builds = 0

    def table(self, weights):
        """(P, n, 3) float32 blends at every phase sample for ``weights``."""
        return np.stack([self.blender.blend(weights, phase_of_sample(p, self.n_phases, self.cyclic))
                         for p in range(self.n_phases)]).astype(np.float32, copy=False)

    def blend(self, weights, phase, out=None):
        """Blended vertices (n, 3) float32, as the wrapped blender gives them."""
        w = np.asarray(weights, dtype=np.float64)
        key = w.tobytes()
        table = self._tables.get(key)
        if table is None:
            count = self._seen.pop(key, 0) + 1
            if count < self.after:
                self._seen[key] = count
                while len(self._seen) > 4 * self.capacity:
                    self._seen.popitem(last=False)
                self.misses += 1
                V = self.blender.blend(w, phase, out=out)
                return V if out is not None else np.asarray(V, dtype=np.float32)
            table = self._tables[key] = self.table(w)
            self.builds += 1
            while len(self._tables) > self.capacity:
                self._tables.popitem(last=False)
        else:
            self._tables.move_to_end(key)
        self.hits += 1
        p0, p1, a = phase_samples(phase, self.n_phases, self.cyclic)
        V = np.empty(table.shape[1:], dtype=np.float32) if out is None else out
        np.multiply(table[p0], np.float32(1.0 - a), out=V)
        V += np.float32(a) * table[p1]
        return V
