"""High-level parameters of a motion space: measured on blends, inverted to blend weights.

Paper section 4.3: w = h^-1(p) from a discrete sampling of the weight space and the parameters
measured on each blend. Here the weights come from a *layout*, a low-dimensional sheet through
the weight simplex with coordinates u in [0, 1]^d (d = 1 or 2):

- ``chain``: sources ordered along one parameter (slow walk, walk, jog, run); u moves along
  the chain, blending neighbours;
- ``grid``: four corner sources of a 2-D parameter (jump height x distance); bilinear;
- ``fan``: speed x direction (the paper's fig. 8): a speed chain of straight gaits blended with
  a left and a right turn; u = (speed along the chain, direction from right (0) to left (1)).

The parameters of the blend at each u on a grid are measured on the blended motion itself
(``measure_parameters``); ``ParameterMap.solve(p)`` inverts by Gauss-Newton on the interpolated
map starting from the nearest sample, and clamps an unreachable request to the nearest reachable
parameters, saying so.
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field

import numpy as np

from engine import measures

MEASURES = {
    "speed": "m/s", "turn_rate": "deg/s", "jump_height": "m", "jump_distance": "m", "reach_height": "m",
}


@dataclass(frozen=True)
class Layout:
    """A sheet of blend weights with coordinates u in [0, 1]^dims.

    Attributes
    ----------
    kind : "chain", "grid" or "fan"
    n_sources : int
    chain : tuple of int     sources in parameter order (chain, and the fan's speed chain)
    corners : tuple of int   grid: sources at u = (0, 0), (1, 0), (0, 1), (1, 1)
    left, right : int        fan: the turning sources
    """

    kind: str
    n_sources: int
    chain: tuple = ()
    corners: tuple = ()
    left: int = -1
    right: int = -1

    def __post_init__(self):
        used = {"chain": self.chain, "grid": self.corners, "fan": self.chain + (self.left, self.right)}
        if self.kind not in used:
            raise ValueError(f"unknown layout {self.kind!r}; choose chain, grid or fan")
        sources = used[self.kind]
        if self.kind == "chain" and len(self.chain) < 2:
            raise ValueError("a chain layout needs at least 2 sources")
        if self.kind == "grid" and len(self.corners) != 4:
            raise ValueError("a grid layout needs exactly 4 corner sources")
        if self.kind == "fan" and (len(self.chain) < 1 or self.left < 0 or self.right < 0):
            raise ValueError("a fan layout needs a speed chain and a left and a right turn")
        if len(set(sources)) != len(sources) or any(not 0 <= s < self.n_sources for s in sources):
            raise ValueError(f"layout {self.kind}: sources must be distinct indices below {self.n_sources}")

    @property
    def dims(self):
        return 1 if self.kind == "chain" else 2

    def _chain_weights(self, u, chain, w, share=1.0):
        """Add ``share`` of the chain's weights at u in [0, 1] into the list w."""
        if len(chain) == 1:
            w[chain[0]] += share
            return
        x = min(max(u, 0.0), 1.0) * (len(chain) - 1)
        i = min(int(x), len(chain) - 2)
        a = x - i
        w[chain[i]] += share * (1.0 - a)
        w[chain[i + 1]] += share * a

    def weights(self, u):
        """(N,) blend weights (summing to 1) at sheet coordinates u (dims,).

        Plain Python on the one or two coordinates: the player asks every frame."""
        u = [min(max(float(x), 0.0), 1.0) for x in (u if isinstance(u, list) else np.atleast_1d(u).tolist())]
        w = [0.0] * self.n_sources
        if self.kind == "chain":
            self._chain_weights(u[0], self.chain, w)
        elif self.kind == "grid":
            a, b = u
            for corner, coefficient in zip(self.corners, ((1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b)):
                w[corner] += coefficient
        else:
            d = 2.0 * u[1] - 1.0  # direction: -1 right, +1 left
            self._chain_weights(u[0], self.chain, w, 1.0 - abs(d))
            w[self.left] += max(d, 0.0)
            w[self.right] += max(-d, 0.0)
        return np.array(w)

    def to_dict(self):
        return {"kind": self.kind, "n_sources": self.n_sources, "chain": list(self.chain),
                "corners": list(self.corners), "left": self.left, "right": self.right}

    @classmethod
    def from_dict(cls, d):
        return cls(kind=d["kind"], n_sources=d["n_sources"], chain=tuple(d.get("chain", ())),
                   corners=tuple(d.get("corners", ())), left=d.get("left", -1), right=d.get("right", -1))


@dataclass(frozen=True)
class RootTrack:
    """Blendable root motion of a space's sources on the phase grid.

    durations : (N,) seconds; root_rate : (P, N, 3) displacement per unit phase in the root frame;
    turn_rate : (P, N) heading change per unit phase (rad); cyclic : bool
    """

    durations: np.ndarray
    root_rate: np.ndarray
    turn_rate: np.ndarray
    cyclic: bool

    def duration(self, w):
        """Seconds of the blend (weights normalised): sum_i w_i T_i."""
        w = np.asarray(w, dtype=float)
        return float(w @ self.durations / w.sum())

    def rates(self, w):
        """(P, 3) displacement and (P,) turn per unit phase of the blend."""
        w = np.asarray(w, dtype=float) / np.sum(w)
        return np.einsum("pnc,n->pc", self.root_rate, w), self.turn_rate @ w

    def after(self, w, seconds):
        """Root after ``seconds`` at constant weights w, starting at the origin facing +Z.

        Returns position (3,) (y = 0), heading (rad) and the phase reached. Cyclic tracks repeat
        the cycle: n whole cycles compose one rigid step n times, a geometric series in the
        complex plane (z + i x turns by e^{i theta}); one-shot clips stop at their end.
        """
        duration = self.duration(w)
        position, heading = self.integrate(w)
        grid = np.linspace(0.0, 1.0, len(heading))
        cycles, phase = divmod(seconds / duration, 1.0) if self.cyclic else (0.0, min(seconds / duration, 1.0))
        step, turn = position[-1], heading[-1]
        spin = complex(math.cos(turn), math.sin(turn))
        one = complex(step[2], step[0])
        whole = one * cycles if abs(turn) < 1e-12 else one * (1 - spin ** cycles) / (1 - spin)
        h = cycles * turn
        partial = complex(np.interp(phase, grid, position[:, 2]), np.interp(phase, grid, position[:, 0]))
        end = whole + complex(math.cos(h), math.sin(h)) * partial
        return np.array([end.imag, 0.0, end.real]), h + float(np.interp(phase, grid, heading)), phase

    def integrate(self, w, samples_per_step=4):
        """Root path of one cycle (or clip) of the blend: positions (S, 3) and headings (S,) at
        phases 0 .. 1, integrating the blended rates with the heading (midpoint rule)."""
        step, turn = self.rates(w)
        P = len(step)
        phases = np.linspace(0.0, 1.0, P * samples_per_step + 1)
        grid = np.arange(P + 1) / P if self.cyclic else np.linspace(0.0, 1.0, P)
        closed_step = np.concatenate([step, step[:1]]) if self.cyclic else step
        closed_turn = np.concatenate([turn, turn[:1]]) if self.cyclic else turn
        d_phase = np.diff(phases)
        middle = 0.5 * (phases[1:] + phases[:-1])
        s = np.stack([np.interp(middle, grid, closed_step[:, c]) for c in range(3)], axis=1)
        t = np.interp(middle, grid, closed_turn)
        heading = np.concatenate([[0.0], np.cumsum(t * d_phase)])
        h_mid = 0.5 * (heading[1:] + heading[:-1])
        world = np.stack([s[:, 0] * np.cos(h_mid) + s[:, 2] * np.sin(h_mid), s[:, 1],
                          -s[:, 0] * np.sin(h_mid) + s[:, 2] * np.cos(h_mid)], axis=1) * d_phase[:, None]
        position = np.concatenate([np.zeros((1, 3)), np.cumsum(world, axis=0)])
        return position, heading


def measure_parameters(names, w, track, blend_phases, *, faces=None, effector=None):
    """Parameters of the blend with weights ``w``, measured on the blended motion itself.

    Parameters
    ----------
    names : sequence of str          among MEASURES
    w : (N,) float array
    track : RootTrack
    blend_phases : callable(w) -> (P, n, 3)   the blended root-local frames on the phase grid
    faces : (m, 3) int array         for the centre of mass (jump height)
    effector : (h,) int array        hand vertices (reach height)

    Returns
    -------
    (len(names),) float array in MEASURES units

    Notes
    -----
    Speed and turn rate: the root's path length and heading change per cycle over the blended
    duration; jump distance: the horizontal root displacement over the clip; jump height: the
    centre of mass's peak rise (vertical motion stays in the meshes); reach height: the
    effector's height at its farthest from its start (``engine.measures``).
    """
    out = []
    frames = None
    T = track.duration(w)
    for name in names:
        if name in ("speed", "turn_rate", "jump_distance"):
            step, turn = track.rates(w)
            if name == "speed":
                out.append(float(np.linalg.norm(step.mean(axis=0)[[0, 2]]) / T))
            elif name == "turn_rate":
                out.append(float(np.degrees(turn.mean() / T)))
            else:
                position, _ = track.integrate(w)
                out.append(float(np.linalg.norm(position[-1, [0, 2]] - position[0, [0, 2]])))
        elif name in ("jump_height", "reach_height"):
            if frames is None:
                frames = np.asarray(blend_phases(w), dtype=np.float64)
            if name == "jump_height":
                out.append(measures.jump_height(measures.centre_of_mass(frames, faces)))
            else:
                out.append(measures.reach_height(frames, effector))
        else:
            raise ValueError(f"unknown parameter measure {name!r}; choose one of {', '.join(MEASURES)}")
    return np.array(out)


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
        self._ranges_list = self.ranges.tolist()
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
        """``_gauss_newton`` for two parameters on a two-dimensional sheet, unrolled: the
        Gauss-Newton step of a square Jacobian is the Newton step J^-1 r. The player's hot path.
        Returns None where the Jacobian is singular (the general solver takes over)."""
        values, last = self._values_list, self._last
        s0, s1 = self._ranges_list
        q0, q1 = p
        x0, x1 = u
        norm = None
        for _ in range(21):
            x = min(max(x0, 0.0), 1.0) * last
            y = min(max(x1, 0.0), 1.0) * last
            i, j = min(int(x), last - 1), min(int(y), last - 1)
            a, b = x - i, y - j
            row0, row1 = values[i], values[i + 1]
            (c00, d00), (c10, d10), (c01, d01), (c11, d11) = row0[j], row1[j], row0[j + 1], row1[j + 1]
            wa, wb = 1.0 - a, 1.0 - b
            at0 = wa * wb * c00 + a * wb * c10 + wa * b * c01 + a * b * c11
            at1 = wa * wb * d00 + a * wb * d10 + wa * b * d01 + a * b * d11
            r0, r1 = (at0 - q0) / s0, (at1 - q1) / s1
            norm_here = math.sqrt(r0 * r0 + r1 * r1)
            if norm is not None:
                if norm_here >= norm:  # no longer improving: keep the last point
                    break
            u, at, norm = [x0, x1], [at0, at1], norm_here
            if norm < 1e-9:
                break
            j00, j01 = last * (wb * (c10 - c00) + b * (c11 - c01)), last * (wa * (c01 - c00) + a * (c11 - c10))
            j10, j11 = last * (wb * (d10 - d00) + b * (d11 - d01)), last * (wa * (d01 - d00) + a * (d11 - d10))
            det = j00 * j11 - j01 * j10
            if abs(det) <= 1e-12 * max(abs(j00 * j11), abs(j01 * j10), 1e-30):
                return None
            e0, e1 = at0 - q0, at1 - q1
            x0 = min(max(u[0] - (j11 * e0 - j01 * e1) / det, 0.0), 1.0)
            x1 = min(max(u[1] - (j00 * e1 - j10 * e0) / det, 0.0), 1.0)
        return u, at

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
        if not all(math.isfinite(x) for x in p_list):
            raise ValueError(f"parameters must be finite, got {p_list}")
        if start is None:
            distance = np.linalg.norm((self._dense_p - p) / self.ranges, axis=1)
            u_list = self._dense_u[int(np.argmin(distance))].astype(float).tolist()
        else:
            u_list = np.asarray(start, dtype=float).reshape(self.layout.dims).tolist()
            u_list = [min(max(x, 0.0), 1.0) for x in u_list]
        u_list, realised_list = self._gauss_newton(p_list, u_list)
        u = np.array(u_list)
        realised = np.array(realised_list)
        clamped = any(abs(r - q) > tolerance * s for r, q, s in zip(realised_list, p_list, self._ranges_list))
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


def accuracy_report(space, blend_mode="hybrid", per_axis=None):
    """Realised vs requested parameters over the reachable domain of a space's parameter map.

    Requests on a regular grid of each parameter's domain (per_axis values per axis, default
    41 for one parameter, 9 x 9 for two) that the map says are reachable are solved for blend
    weights; the parameters are then measured again on the blend itself (``measure_parameters``
    on ``blend_mode`` blends), not read back from the map.

    Returns
    -------
    dict with, per parameter, max and mean |realised - requested| in units and in % of the
    parameter's range, the number of requests and how many were unreachable.
    """
    from engine.blend.phase import phase_of_sample

    pmap = space.parameter_map
    if pmap is None:
        raise ValueError(f"{space.name}: the space has no parameter map")
    blender = space.blender(blend_mode)
    P = space.n_phases

    def blend_phases(w):
        return np.stack([blender.blend(w, phase_of_sample(p, P, space.cyclic)) for p in range(P)])

    faces = np.asarray(space.faces, dtype=np.int64)
    per_axis = per_axis or (41 if len(pmap.names) == 1 else 9)
    axes = [np.linspace(lo, hi, per_axis) for lo, hi in pmap.domain()]
    requests = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
    errors, unreachable = [], 0
    for p in requests:
        solution = pmap.solve(p)
        if solution.clamped:
            unreachable += 1
            continue
        realised = measure_parameters(pmap.names, solution.weights, space.root_track, blend_phases, faces=faces,
                                      effector=space.effector)
        errors.append(np.abs(realised - p))
    errors = np.array(errors).reshape(-1, len(pmap.names))
    result = {"space": space.name, "blend_mode": blend_mode, "requests": int(len(requests)),
              "unreachable": unreachable, "parameters": {}}
    for k, (name, unit) in enumerate(zip(pmap.names, pmap.units)):
        lo, hi = pmap.domain()[k]
        span = max(hi - lo, 1e-12)
        result["parameters"][name] = {
            "unit": unit, "domain": [lo, hi],
            "max_error": float(errors[:, k].max()) if len(errors) else None,
            "mean_error": float(errors[:, k].mean()) if len(errors) else None,
            "max_error_percent_of_range": float(100 * errors[:, k].max() / span) if len(errors) else None,
            "mean_error_percent_of_range": float(100 * errors[:, k].mean() / span) if len(errors) else None}
    return result
