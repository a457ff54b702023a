"""Phase tables: blending at fixed weights reduced to one interpolation per frame.

Linear and hybrid blends are linear in phase between the phase samples: at weights w,

    M(t, w) = B[p0] + a (B[p1] - B[p0]),    B[p] = sum_i w_i S_i[p] + sum_j phi_j(w) D_j[p]

(``phase_samples`` gives p0, p1, a). So once a weight vector has been asked for a few times, its
table B (P, n, 3) is built (P blends) and every later frame at those weights costs one
multiply-add of two rows. This is exact (float32 rounding), not a cache of approximations.
A player whose parameters have settled, or many viewers at the same parameters, hit the table;
moving weights fall through to the blender. At most ``capacity`` tables are kept (each is
P x n x 3 float32: 1.15 MB for 32 phases of 3,000 vertices; the differences between samples are
taken as a frame is made, not stored); a new one
replaces the least recently used only if that one has been idle for ``idle`` seconds, so more
recurring weights than tables (hundreds of viewers at different settings) never thrash: the
tables serve the first ``capacity`` of them and the rest blend as if there were none.

A table can also be held in affine coordinates ``scale * B + offset`` (``PhaseTable.scaled``):
a quantising encoder then reads its integers straight off the interpolated rows, and a server
interpolates the rows of many clients in one gather (``PhaseTable.rows_at``).
"""

from __future__ import annotations

import time
from collections import OrderedDict

import numpy as np

from engine.blend.compiled import interpolate_at
from engine.blend.phase import phase_of_sample, phase_samples


class PhaseTable:
    """The blends at every phase sample for one weight vector.

    Parameters
    ----------
    rows : (P, n, 3) float32   blends at the phase samples
    cyclic : bool              the last sample runs on to the first (else it is the end)

    Attributes
    ----------
    rows : (P, n * 3) float32   B[p]; a frame between samples p0 and p1 is B[p0] + a (B[p1] - B[p0]),
                                the difference taken when the frame is made (none stored)
    """

    def __init__(self, rows, cyclic):
        P = len(rows)
        self.n_phases, self.cyclic = P, bool(cyclic)
        self.n_vertices = rows.shape[1]
        self.rows = np.ascontiguousarray(rows, dtype=np.float32).reshape(P, -1)
        self._scaled = {}

    def at(self, phase, out=None):
        """(n, 3) float32 vertices at ``phase`` in [0, 1]: the row ``rows_at`` gives (the same
        float32 steps, one compiled pass)."""
        V = np.empty((self.n_vertices, 3), dtype=np.float32) if out is None else out
        if V.dtype == np.float32 and V.flags.c_contiguous:
            interpolate_at(self.rows, np.array([phase], dtype=np.float64), self.cyclic, V.reshape(1, -1))
        else:
            V[...] = self.rows_at([phase])[0].reshape(V.shape)
        return V

    def rows_at(self, phases, out=None):
        """(K, n * 3) float32 rows at K phases: every client of a table in one gather.

        ``phases`` : (K,) floats in [0, 1]. Rows are flat (x, y, z per vertex).
        """
        samples = [phase_samples(t, self.n_phases, self.cyclic) for t in phases]
        p0 = np.fromiter((s[0] for s in samples), dtype=np.intp, count=len(samples))
        p1 = np.fromiter((s[1] for s in samples), dtype=np.intp, count=len(samples))
        a = np.fromiter((s[2] for s in samples), dtype=np.float32, count=len(samples))
        R = np.take(self.rows, p1, axis=0, out=out)
        R -= self.rows[p0]
        R *= a[:, None]
        R += self.rows[p0]
        return R

    def rows_cast(self, phases, dtype):
        """(K, n * 3) ``dtype`` rows at K phases: ``rows_at(phases).astype(dtype)``, the same
        numbers, each row made in one compiled pass, its phase sample found there too
        (engine/blend/compiled.py; a q16 table's rows cast to "<u2" are the encoded frames)."""
        return interpolate_at(self.rows, np.array(phases, dtype=np.float64), self.cyclic,
                              np.empty((len(phases), self.rows.shape[1]), dtype=dtype))

    def scaled(self, scale, offset, lo=None, hi=None, key=None):
        """This table in the affine coordinates ``scale * B + offset`` (per axis), clipped to
        [lo, hi] when given; built once per (scale, offset, lo, hi) and kept with the table.

        scale, offset : (3,) float   per-axis
        key : hashable or None       names (scale, offset, lo, hi) for a caller asking every
                                     frame (default: made from the values)
        Interpolating the scaled rows equals scaling the interpolated blend (to float32
        rounding), and stays within [lo, hi] (the rows are clipped before differencing).
        """
        if key is None:
            key = (np.asarray(scale, dtype=np.float32).tobytes(), np.asarray(offset, dtype=np.float32).tobytes(),
                   lo, hi)
        table = self._scaled.get(key)
        if table is None:
            scale = np.asarray(scale, dtype=np.float32).reshape(3)
            offset = np.asarray(offset, dtype=np.float32).reshape(3)
            rows = self.rows.reshape(self.n_phases, -1, 3) * scale + offset
            if lo is not None or hi is not None:
                np.clip(rows, lo, hi, out=rows)
            table = self._scaled[key] = PhaseTable(rows, self.cyclic)
        return table


def weights_key(weights):
    """The bytes naming a weight vector (N,) among a PhaseTableBlender's tables."""
    return np.asarray(weights, dtype=np.float64).tobytes()


class PhaseTableBlender:
    """Wraps a linear or hybrid blender (``blend(weights, phase, out=None)``) with phase tables.

    Parameters
    ----------
    blender : LinearBlender or HybridBlender   must be linear in phase between samples
    n_phases : int; cyclic : bool
    capacity : int    tables kept
    after : int       requests at the same weights before a table is built
    idle : float      seconds without a request before a table may be replaced
    clock : callable  seconds (default time.monotonic)
    """

    def __init__(self, blender, n_phases, cyclic, *, capacity=32, after=3, idle=1.0, clock=time.monotonic):
        self.blender = blender
        self.n_phases, self.cyclic = int(n_phases), bool(cyclic)
        self.capacity, self.after, self.idle = int(capacity), int(after), float(idle)
        self.clock = clock
        self._tables = OrderedDict()   # weights key -> [PhaseTable, last request time]
        self._seen = OrderedDict()
        self.hits = self.misses = self.builds = 0

    def table(self, weights):
        """(P, n, 3) float32 blends at every phase sample for ``weights`` (each blended in place
        into its row: no per-sample copies, no stacking)."""
        n_vertices = self.blender.n_vertices
        rows = np.empty((self.n_phases, n_vertices, 3), dtype=np.float32)
        for p in range(self.n_phases):
            self.blender.blend(weights, phase_of_sample(p, self.n_phases, self.cyclic), out=rows[p])
        return rows

    def lookup(self, weights, key=None):
        """The PhaseTable for ``weights``, or None while they have not recurred ``after`` times.

        Counts as a request: the table is built on the ``after``-th request at the same weights.
        ``key``: ``weights_key(weights)``, for a caller that keeps it while the weights stay.
        """
        if key is None:
            key = weights_key(weights)
        now = self.clock()
        entry = self._tables.get(key)
        if entry is not None:
            self._tables.move_to_end(key)
            entry[1] = now
            self.hits += 1
            return entry[0]
        count = self._seen.pop(key, 0) + 1
        full = len(self._tables) >= self.capacity
        if count < self.after or (full and now - next(iter(self._tables.values()))[1] < self.idle):
            self._seen[key] = min(count, self.after)
            while len(self._seen) > 4 * self.capacity:
                self._seen.popitem(last=False)
            self.misses += 1
            return None
        if full:
            self._tables.popitem(last=False)
        table = PhaseTable(self.table(weights), self.cyclic)
        self._tables[key] = [table, now]
        self.builds += 1
        self.hits += 1
        return table

    def blend(self, weights, phase, out=None):
        """Blended vertices (n, 3) float32, as the wrapped blender gives them."""
        table = self.lookup(weights)
        if table is None:
            V = self.blender.blend(np.asarray(weights, dtype=np.float64), phase, out=out)
            return V if out is not None else np.asarray(V, dtype=np.float32)
        return table.at(phase, out=out)
