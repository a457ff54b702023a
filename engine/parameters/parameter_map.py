"""Parameter maps (paper section 4.3): parameters measured on a sampling of a layout's sheet,
inverted to blend weights by Gauss-Newton on the interpolated map, clamped when unreachable."""

from __future__ import annotations

import math

from dataclasses import dataclass, field

import numpy as np

from engine.jit import compiled
from engine.parameters.layout import MEASURES, Layout

FAR = 100.0  # requests further than this many ranges outside the domain are solved from that bound


@dataclass
class Solution:
    """A parameter request turned into blend weights."""

    weights: np.ndarray      # (N,)
    u: np.ndarray            # (dims,) sheet coordinates
    requested: np.ndarray    # (k,) what was asked
    realised: np.ndarray     # (k,) what the blend at u does (interpolated from the measurements)
    clamped: bool            # the request was outside the reachable domain
    message: str = ""


@dataclass
class ParameterMap:
    """Blend weights for high-level parameters, and back.

    Attributes
    ----------
    layout : Layout
    names, units : list of str
    grid : (G,) or (G, G) sample coordinates per axis: ``axes`` list of (G,) arrays
    values : (G, k) or (G, G, k) measured parameters at the grid samples
    """

    layout: Layout
    names: list
    units: list
    axes: list
    values: np.ndarray
    ranges: np.ndarray = field(init=False)

    def __post_init__(self):
        flat = self.values.reshape(-1, len(self.names))
        self.ranges = np.maximum(flat.max(axis=0) - flat.min(axis=0), 1e-9)
        self._values_list = np.asarray(self.values, dtype=float).tolist()
        # an array of the compiled solve's own (writable, C order: a space's mapped, read-only
        # values would be another type to numba, compiled again at the first stream)
        self._values_array = np.array(self.values, dtype=np.float64, order="C")
        self._ranges_list = self.ranges.tolist()
        # requests are solved from within FAR ranges of the domain: further out, squared distances
        # lose the differences that tell the nearest reachable point (1e16 m/s became the slowest)
        self._solve_bounds = [(lo - FAR * r, hi + FAR * r) for lo, hi, r in
                              zip(flat.min(axis=0).tolist(), flat.max(axis=0).tolist(), self._ranges_list)]
        self._last = len(self.axes[0]) - 1
        self._dense_u, self._dense_p = self._dense()

    @classmethod
    def sample(cls, layout, names, measure_at, resolution=None, progress=None):
        """Measure ``measure_at(w) -> (k,)`` on a regular grid of the layout's coordinates."""
        resolution = resolution or (21 if layout.dims == 1 else 11)
        axis = np.linspace(0.0, 1.0, resolution)
        if layout.dims == 1:
            values = np.array([measure_at(layout.weights([a])) for a in axis])
            if progress:
                progress(resolution, resolution)
        else:
            values = np.empty((resolution, resolution, len(names)))
            for i, a in enumerate(axis):
                for j, b in enumerate(axis):
                    values[i, j] = measure_at(layout.weights([a, b]))
                if progress:
                    progress((i + 1) * resolution, resolution * resolution)
        units = [MEASURES[n] for n in names]
        return cls(layout=layout, names=list(names), units=units, axes=[axis] * layout.dims, values=values)

    def at(self, u):
        """(k,) parameters at sheet coordinates u by (bi)linear interpolation of the samples."""
        u = np.clip(np.atleast_1d(np.asarray(u, dtype=float)), 0.0, 1.0)
        if self.layout.dims == 1:
            axis = self.axes[0]
            return np.array([np.interp(u[0], axis, self.values[:, c]) for c in range(len(self.names))])
        axis = self.axes[0]
        G = len(axis)
        x = u * (G - 1)
        i = np.minimum(np.floor(x).astype(int), G - 2)
        a = x - i
        v = self.values
        return ((1 - a[0]) * (1 - a[1]) * v[i[0], i[1]] + a[0] * (1 - a[1]) * v[i[0] + 1, i[1]]
                + (1 - a[0]) * a[1] * v[i[0], i[1] + 1] + a[0] * a[1] * v[i[0] + 1, i[1] + 1])

    def _jacobian(self, u, h=1e-4):
        """(k, dims) derivative of ``at`` by central differences (one-sided at the edges)."""
        columns = []
        for k in range(len(u)):
            lo, hi = u.copy(), u.copy()
            lo[k], hi[k] = max(u[k] - h, 0.0), min(u[k] + h, 1.0)
            columns.append((self.at(hi) - self.at(lo)) / (hi[k] - lo[k]))
        return np.stack(columns, axis=1)

    def _cell(self, u):
        """Parameters (k,) and their derivatives (k rows of dims) at u, on u's grid cell.

        Plain Python floats: the player solves every frame, and for one or two sheet
        coordinates this is several times faster than numpy calls.
        """
        values, last = self._values_list, self._last
        if len(u) == 1:
            x = min(max(u[0], 0.0), 1.0) * last
            i = min(int(x), last - 1)
            a = x - i
            v0, v1 = values[i], values[i + 1]
            return ([p0 + a * (p1 - p0) for p0, p1 in zip(v0, v1)],
                    [[last * (p1 - p0)] for p0, p1 in zip(v0, v1)])
        x = min(max(u[0], 0.0), 1.0) * last
        y = min(max(u[1], 0.0), 1.0) * last
        i, j = min(int(x), last - 1), min(int(y), last - 1)
        a, b = x - i, y - j
        v00, v10, v01, v11 = values[i][j], values[i + 1][j], values[i][j + 1], values[i + 1][j + 1]
        at, jac = [], []
        for c00, c10, c01, c11 in zip(v00, v10, v01, v11):
            at.append((1 - a) * (1 - b) * c00 + a * (1 - b) * c10 + (1 - a) * b * c01 + a * b * c11)
            jac.append([last * ((1 - b) * (c10 - c00) + b * (c11 - c01)),
                        last * ((1 - a) * (c01 - c00) + a * (c11 - c10))])
        return at, jac

    def _newton_square(self, p, u):
        """``_gauss_newton`` for two parameters on a two-dimensional sheet: the Gauss-Newton step
        of a square Jacobian is the Newton step J^-1 r. The player's hot path, compiled
        (:func:`_newton_square_compiled`). Returns None where the Jacobian is singular (the
        general solver takes over)."""
        ok, x0, x1, at0, at1 = _newton_square_compiled(self._values_array, self._last, self._ranges_list[0],
                                                       self._ranges_list[1], p[0], p[1], u[0], u[1])
        return ([x0, x1], [at0, at1]) if ok else None

    def _gauss_newton(self, p, u):
        """Sheet coordinates u (list) minimising |(at(u) - p) / ranges|, from ``u``, projected
        onto the unit square; stops when a step no longer reduces the residual. Returns u and
        the parameters there (list)."""
        if len(u) == 2 and len(p) == 2:
            solved = self._newton_square(p, u)
            if solved is not None:
                return solved
        return self._gauss_newton_general(p, u)

    def _gauss_newton_general(self, p, u):
        scale = self._ranges_list
        at, jac = self._cell(u)
        at_u = at
        r = [(q - t) / s for q, t, s in zip(at, p, scale)]
        norm = math.sqrt(sum(x * x for x in r))
        for _ in range(20):
            if norm < 1e-9:
                break
            J = [[d / s for d in row] for row, s in zip(jac, scale)]
            if len(u) == 1:
                jtj = sum(row[0] * row[0] for row in J)
                if jtj <= 1e-30:
                    break
                step = [-sum(row[0] * x for row, x in zip(J, r)) / jtj]
            else:
                a = sum(row[0] * row[0] for row in J)
                b = sum(row[0] * row[1] for row in J)
                d = sum(row[1] * row[1] for row in J)
                g0 = sum(row[0] * x for row, x in zip(J, r))
                g1 = sum(row[1] * x for row, x in zip(J, r))
                det = a * d - b * b
                if abs(det) <= 1e-12 * max(a * d, 1e-30):
                    # rank-deficient: the least-squares step of smallest norm
                    step = np.linalg.lstsq(np.array(J), -np.array(r), rcond=None)[0].tolist()
                else:
                    step = [-(d * g0 - b * g1) / det, -(a * g1 - b * g0) / det]
            u_next = [min(max(x + s, 0.0), 1.0) for x, s in zip(u, step)]
            at, jac_next = self._cell(u_next)
            r_next = [(q - t) / s for q, t, s in zip(at, p, scale)]
            norm_next = math.sqrt(sum(x * x for x in r_next))
            if norm_next >= norm:
                break
            u, r, norm, jac, at_u = u_next, r_next, norm_next, jac_next, at
        return u, at_u

    def _dense(self):
        steps = 401 if self.layout.dims == 1 else 81
        line = np.linspace(0.0, 1.0, steps)
        if self.layout.dims == 1:
            U = line[:, None]
        else:
            U = np.stack(np.meshgrid(line, line, indexing="ij"), axis=-1).reshape(-1, 2)
        return U, np.array([self.at(u) for u in U])

    def domain(self):
        """Per parameter (min, max) over the sampled sheet."""
        flat = self.values.reshape(-1, len(self.names))
        return [(float(lo), float(hi)) for lo, hi in zip(flat.min(axis=0), flat.max(axis=0))]

    def solve(self, requested, tolerance=0.005, start=None):
        """Blend weights realising the requested parameters, clamped to the reachable domain.

        Parameters
        ----------
        requested : (k,) float array   in the map's units, in ``names`` order
        tolerance : float              relative (to each parameter's range) error accepted as reached
        start : (dims,) float array or None   sheet coordinates to start from (a previous
                                       solution nearby); by default the nearest dense sample

        Returns
        -------
        Solution
        """
        p = np.array(requested, dtype=float)
        if p.shape != (len(self.names),):
            raise ValueError(f"expected {len(self.names)} parameters ({', '.join(self.names)}), got {p.shape}")
        p_list = p.tolist()
        for x in p_list:
            if not math.isfinite(x):
                raise ValueError(f"parameters must be finite, got {p_list}")
        # far outside the domain: solved from the bound along that parameter
        p_list = [min(max(x, lo), hi) for x, (lo, hi) in zip(p_list, self._solve_bounds)]
        if start is None:
            nearest = _nearest_scaled(self._dense_p, np.array(p_list), self.ranges)  # argmin |(dense - p) / ranges|, compiled
            u_list = self._dense_u[nearest].astype(float).tolist()
        else:
            u_list = np.asarray(start, dtype=float).reshape(self.layout.dims).tolist()
        return self._solved(p, p_list, u_list, tolerance)

    def solve_near(self, requested, start):
        """``solve(requested, start=start)`` for a caller stepping the parameters continuously
        (the player, every frame), without the checks and conversions: ``requested`` (k,)
        float64 array of finite numbers (kept as the Solution's ``requested``, not copied: do not
        change it afterwards), ``start`` the previous Solution's ``u``."""
        p_list = [min(max(x, lo), hi) for x, (lo, hi) in zip(requested.tolist(), self._solve_bounds)]
        return self._solved(requested, p_list, start.tolist(), 0.005)

    def _solved(self, p, p_list, u_list, tolerance):
        """The Solution for request ``p`` (array; ``p_list`` its values clamped to the solve's
        bounds) from sheet coordinates ``u_list``."""
        u_list = [min(max(x, 0.0), 1.0) for x in u_list]
        u_list, realised_list = self._gauss_newton(p_list, u_list)
        u = np.array(u_list)
        realised = np.array(realised_list)
        clamped = False
        for r, q, s in zip(realised_list, p.tolist(), self._ranges_list):
            if abs(r - q) > tolerance * s:
                clamped = True
                break
        message = ""
        if clamped:
            parts = [f"{n} {q:g} {unit} -> {r:.3g}" for n, q, r, unit in zip(self.names, p, realised, self.units)]
            message = "outside the reachable domain, clamped: " + ", ".join(parts)
        return Solution(weights=self.layout.weights(u_list), u=u, requested=p, realised=realised, clamped=clamped,
                        message=message)

    def to_arrays(self):
        return {"parameter_values": self.values, "parameter_axis": self.axes[0]}

    def to_metadata(self):
        return {"layout": self.layout.to_dict(), "names": self.names, "units": self.units,
                "domain": self.domain()}

    @classmethod
    def from_stored(cls, metadata, values, axis):
        layout = Layout.from_dict(metadata["layout"])
        return cls(layout=layout, names=list(metadata["names"]), units=list(metadata["units"]),
                   axes=[np.asarray(axis)] * layout.dims, values=np.asarray(values))


@compiled
def _newton_square_compiled(values, last, s0, s1, q0, q1, x0, x1):  # pragma: no cover (compiled)
    """Newton's method on the bilinear interpolation of ``values`` (G, G, 2) for the two
    parameters (q0, q1) (ranges s0, s1), from sheet coordinates (x0, x1), projected onto the unit
    square; at most 21 evaluations, stopping when a step no longer reduces the scaled residual.
    Returns (ok, u0, u1, at0, at1): ok False where the Jacobian is singular."""
    u0, u1, at0, at1, norm = x0, x1, 0.0, 0.0, 0.0
    for it in range(21):
        x = min(max(x0, 0.0), 1.0) * last
        y = min(max(x1, 0.0), 1.0) * last
        i, j = min(int(x), last - 1), min(int(y), last - 1)
        a, b = x - i, y - j
        c00, d00 = values[i, j, 0], values[i, j, 1]
        c10, d10 = values[i + 1, j, 0], values[i + 1, j, 1]
        c01, d01 = values[i, j + 1, 0], values[i, j + 1, 1]
        c11, d11 = values[i + 1, j + 1, 0], values[i + 1, j + 1, 1]
        wa, wb = 1.0 - a, 1.0 - b
        here0 = wa * wb * c00 + a * wb * c10 + wa * b * c01 + a * b * c11
        here1 = wa * wb * d00 + a * wb * d10 + wa * b * d01 + a * b * d11
        r0, r1 = (here0 - q0) / s0, (here1 - q1) / s1
        norm_here = math.sqrt(r0 * r0 + r1 * r1)
        if it > 0 and norm_here >= norm:  # no longer improving: keep the last point
            break
        u0, u1, at0, at1, norm = x0, x1, here0, here1, norm_here
        if norm < 1e-9:
            break
        j00, j01 = last * (wb * (c10 - c00) + b * (c11 - c01)), last * (wa * (c01 - c00) + a * (c11 - c10))
        j10, j11 = last * (wb * (d10 - d00) + b * (d11 - d01)), last * (wa * (d01 - d00) + a * (d11 - d10))
        det = j00 * j11 - j01 * j10
        if abs(det) <= 1e-12 * max(abs(j00 * j11), abs(j01 * j10), 1e-30):
            return False, u0, u1, at0, at1
        e0, e1 = here0 - q0, here1 - q1
        x0 = min(max(u0 - (j11 * e0 - j01 * e1) / det, 0.0), 1.0)
        x1 = min(max(u1 - (j00 * e1 - j10 * e0) / det, 0.0), 1.0)
    return True, u0, u1, at0, at1


@compiled
def _nearest_scaled(points, p, ranges):  # pragma: no cover (compiled)
    """The index of the row of ``points`` (N, k) nearest ``p`` (k,) in units of ``ranges`` (k,):
    ``argmin(norm((points - p) / ranges, axis=1))`` with numpy's operations in numpy's order
    (the first of equals), one pass, no temporaries."""
    best, index = np.inf, 0
    for i in range(points.shape[0]):
        total = 0.0
        for c in range(points.shape[1]):
            d = (points[i, c] - p[c]) / ranges[c]
            total += d * d
        distance = math.sqrt(total)
        if distance < best:
            best, index = distance, i
    return index


def warm_up():
    """Compile (or load from numba's cache) the parameter solve's loops."""
    _newton_square_compiled(np.zeros((2, 2, 2)), 1, 1.0, 1.0, 0.0, 0.0, 0.5, 0.5)
    _nearest_scaled(np.zeros((2, 2)), np.zeros(2), np.ones(2))
