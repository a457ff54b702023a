"""Run-time transition search: when to leave the current node, where to enter the target and
over how long, from the edge's precomputed dissimilarity table.

Notes
-----
Casas et al., 4D Parametric Motion Graphs (I3D 2012), section 4: the transition minimises a
cost that adds the shape-and-motion dissimilarity at the seam to a latency cost. Here the cost
of leaving at phase sample j of the source (or now), entering at phase sample e of the target
and blending over L seconds is

    D[j, e] / model_size * (reference_length / L)  +  latency_weight * (wait_j + L)

where D is the RMS difference of the two windows (``features``), so a longer blend spreads a
larger difference over more frames, and wait_j is the time until the source reaches phase j at
its current weights. Both weights are looked up at the edge table's nearest parameter sample.
A few candidates (per blend length, the cheapest by that cost plus ``smooth_weight`` times the
largest step the two motions alone take over the blend there, ``terms.own_windows``; and the
cheapest by that cost alone, the plan without predictions) are then played over a few vertices
(``terms.predict``) and the one taken is the cheapest by

    cost  +  smooth_weight * smoothness  +  foot_weight * drift / model_size

where smoothness is the predicted largest per-vertex step across the blend over the two nodes'
own largest (as ``evaluate`` measures it) and drift how far the legs will carry a foot held on
the ground (a landing's feet side by side blended into a stride): so among transitions about as
good by seam and latency, the one timed where the motions are slow and their feet agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.graph.build import GraphError
from engine.graph.terms import node_profile, own_windows, predict, tracked_vertices


@dataclass(frozen=True)
class SearchOptions:
    """latency_weight : cost per second of latency (1 = a second costs as much as a seam one
    model size apart over the reference length); lengths : transition lengths tried (s);
    reference_length : s; max_entry : latest phase a one-shot target may be entered at; min_exit :
    earliest phase a one-shot source may be left at (so a reach or a jump, whose first frames match
    the stand they came from, is performed before its return is blended in); candidates : about how
    many transitions are played to predict their smoothness and foot drift (as many per blend
    length, and the cheapest by seam and latency; 0: none, the seam and latency cost alone);
    smooth_weight : cost per unit of predicted smoothness ratio;
    foot_weight : cost of a foot carried by its leg, per model size; foot_reach : the drift (in
    model sizes; 0.08: 14 cm on the demo body, about where the legs' cap shortens it) beyond which
    a held foot is predicted to slide, costing ``slide_factor`` times more."""

    latency_weight: float = 0.5
    lengths: tuple = (0.15, 0.25, 0.35, 0.5, 0.7)
    reference_length: float = 0.3
    max_entry: float = 0.35
    min_exit: float = 0.65
    candidates: int = 5
    smooth_weight: float = 1.0
    foot_weight: float = 4.0
    foot_reach: float = 0.08
    slide_factor: float = 5.0

    def __post_init__(self):
        if not (self.latency_weight >= 0 and len(self.lengths) > 0 and all(0 < x <= 5 for x in self.lengths)
                and self.reference_length > 0 and 0 <= self.max_entry <= 1 and 0 <= self.min_exit <= 1
                and 0 <= self.candidates <= 1000 and self.smooth_weight >= 0 and self.foot_weight >= 0
                and self.foot_reach >= 0 and self.slide_factor >= 0):
            raise ValueError(f"search options out of range: {self}")


@dataclass
class Transition:
    """A planned transition.

    source, target : str        node names
    leave_in : float            seconds from the request until the blend starts
    leave_phase : float         the source's phase then
    enter_phase : float         the target's phase when the blend starts
    length : float              seconds of blending
    dissimilarity : float       the windows' RMS difference at the seam (m)
    cost : float
    target_weights : (N,) float
    smoothness : float or None  the predicted smoothness ratio (``terms.predict``; None: not predicted)
    foot_drift : float or None  the predicted distance a held foot is carried (m)
    """

    source: str
    target: str
    leave_in: float
    leave_phase: float
    enter_phase: float
    length: float
    dissimilarity: float
    cost: float
    target_weights: np.ndarray
    smoothness: float | None = None
    foot_drift: float | None = None

    @property
    def latency(self):
        """Seconds from the request until the target is fully entered."""
        return self.leave_in + self.length


class TransitionSearch:
    """Finds transitions on a loaded MotionGraph (cheap: a few array operations per search)."""

    def __init__(self, graph, options=None):
        self.graph = graph
        self.options = options or SearchOptions()
        self._lengths = np.asarray(self.options.lengths, dtype=float)
        self._spread = self.options.reference_length / self._lengths / graph.model_size
        self._profiles = None
        if self.options.candidates > 0:  # the nodes' tables, once per graph (shared by every search on it)
            first = graph.nodes[0]
            tracked = first.cached("tracked vertices", lambda: tracked_vertices(graph))
            self._profiles = {n.name: n.cached("profile", lambda n=n: node_profile(n, tracked)) for n in graph.nodes}
            key = ("own windows", tuple(self.options.lengths))
            self._own = {n.name: n.cached(key, lambda n=n: own_windows(self._profiles[n.name], n.samples.phases,
                                                                      self._lengths)) for n in graph.nodes}

    def _cheapest(self, cost):
        """Flat indices of the ``candidates`` cheapest finite entries of ``cost`` (rows, entries,
        lengths), as many of each length (a long blend's seam is cheaper by the cost, a short one
        may be smoother)."""
        per = -(-self.options.candidates // cost.shape[2])
        flat = cost.reshape(-1, cost.shape[2])  # (rows x entries, lengths)
        out = []
        for k in range(cost.shape[2]):
            column = flat[:, k]
            n = min(per, len(column))
            index = np.argpartition(column, n - 1)[:n] if n < len(column) else np.arange(len(column))
            index = index[np.isfinite(column[index])]
            out.append(index * cost.shape[2] + k)
        return np.concatenate(out)

    def search(self, source, weights, phase, target, target_weights, *, budget=None, latency_weight=None,
               finish_by=None, early=False):
        """The cheapest transition from ``source`` (at ``weights``, ``phase``) to ``target``.

        Parameters
        ----------
        source, target : str
        weights, target_weights : (N,) float arrays
        phase : float
        budget : float or None          the transition must be complete within this many seconds
                                        (if nothing fits, the quickest one is taken)
        latency_weight : float or None  overrides the options'
        finish_by : float or None       seconds: the blend must end by then (a one-shot's end)
        early : bool                    a one-shot source may also be left before ``min_exit``,
                                        where the seam is no worse than the best from ``min_exit``
                                        on (a stop left for a walk while it still walks; a jump is
                                        not left in the air)

        Returns
        -------
        Transition
        """
        try:
            table = self.graph.edges[(source, target)]
        except KeyError:
            raise GraphError(f"graph {self.graph.name!r} has no edge {source} -> {target}; from {source}: "
                             f"{', '.join(self.graph.successors(source)) or 'none'}") from None
        a, b = self.graph.node(source), self.graph.node(target)
        ka, kb = a.sample_of(weights), b.sample_of(target_weights)
        D = table[ka, :, kb, :]  # (MA, MB)
        duration = a.space.root_track.duration(weights)
        phases = a.samples.phases
        earliest = self.options.min_exit
        late = np.ones(len(phases) + 1, dtype=bool)  # rows left no earlier than min_exit: (now, samples)
        if a.cyclic:
            waits = ((phases - phase) % 1.0) * duration
            x = (phase % 1.0) * len(phases)
            j0 = int(x) % len(phases)
            j1, f = (j0 + 1) % len(phases), x - int(x)
        else:
            ahead = phases >= phase - 1e-9  # no going back
            late = np.concatenate([[phase >= earliest - 1e-9], ahead & (phases >= earliest - 1e-9)])
            waits = np.where(ahead if early else late[1:], (phases - phase) * duration, np.nan)
            x = min(max(phase, 0.0), 1.0) * (len(phases) - 1)
            j0 = min(int(x), len(phases) - 2)
            j1, f = j0 + 1, x - j0
        now = (1 - f) * D[j0] + f * D[j1]  # leaving at once: the current phase's row
        waits = np.concatenate([[0.0 if a.cyclic or early or late[0] else np.nan], waits])
        rows = np.where(np.isnan(waits)[:, None], np.inf, np.vstack([now[None], D]))
        waits = np.nan_to_num(waits, nan=0.0)
        leave = np.concatenate([[phase], phases])
        entries = b.samples.phases
        if not b.cyclic:
            rows = np.where(entries[None, :] <= self.options.max_entry + 1e-9, rows, np.inf)
        if early and not a.cyclic:  # before min_exit only where the seam is as good as from it on
            best_late = rows[late].min() if late.any() else np.inf
            rows = np.where(late[:, None] | (rows <= best_late), rows, np.inf)
        weight = self.options.latency_weight if latency_weight is None else float(latency_weight)
        total = waits[:, None] + self._lengths[None, :]  # (rows, lengths)
        cost = rows[:, :, None] * self._spread[None, None, :] + weight * total[:, None, :]
        finite = np.isfinite(cost)
        allowed = finite.copy()
        if finish_by is not None:
            allowed &= (total <= finish_by + 1e-9)[:, None, :]
            if not allowed.any():  # nothing ends in time: the quickest, the best seam among them
                quickest = np.where(finite, total[:, None, :], np.inf).min()
                allowed = finite & (total <= quickest + 1e-9)[:, None, :]
        if budget is not None:
            fits = allowed & (total <= budget + 1e-9)[:, None, :]
            if fits.any():
                allowed = fits
            else:  # nothing fits: the quickest transition, the best seam among the quickest
                quickest = np.where(allowed, total[:, None, :], np.inf).min()
                allowed &= (total <= quickest + 1e-9)[:, None, :]
        if not allowed.any():
            allowed = finite
        masked = np.where(allowed, cost, np.inf).ravel()
        smooth = drift = None
        if self._profiles is None:
            flat = int(np.argmin(masked))
        else:  # the cheapest few, played: the best by seam, latency, smoothness and feet
            pa, pb = self._profiles[source], self._profiles[target]
            own_a = self._own[source][ka]  # (MA, lengths): what the motions alone step, timed there
            own_a = np.vstack([own_a[j0 if f < 0.5 else j1][None], own_a])
            own = np.maximum(own_a[:, None, :], self._own[target][kb][None, :, :]) / max(pa.largest[ka],
                                                                                        pb.largest[kb], 1e-9)
            best = self._cheapest(masked.reshape(cost.shape) + self.options.smooth_weight * own)
            best = np.unique(np.append(best, np.argmin(masked)))  # and the cheapest by seam and latency alone
            j, e, k = np.unravel_index(best, cost.shape)
            phase_a = np.where(j == 0, phase, leave[j]) % 1.0 if a.cyclic else np.minimum(leave[j], 1.0)
            smooth, drift = predict(pa, ka, phase_a, pb, kb, entries[e], self._lengths[k])
            size = self.graph.model_size
            beyond = np.maximum(drift - self.options.foot_reach * size, 0.0)  # where the foot would slide
            total = (masked[best] + self.options.smooth_weight * smooth
                     + self.options.foot_weight / size * (drift + self.options.slide_factor * beyond))
            pick = int(np.argmin(total))
            flat, smooth, drift = int(best[pick]), float(smooth[pick]), float(drift[pick])
        j, e, k = np.unravel_index(flat, cost.shape)
        return Transition(source=source, target=target, leave_in=float(waits[j]), leave_phase=float(leave[j] % 1.0
                          if a.cyclic else leave[j]), enter_phase=float(entries[e]), length=float(self._lengths[k]),
                          dissimilarity=float(rows[j, e]), cost=float(cost[j, e, k]),
                          target_weights=np.asarray(target_weights, dtype=float), smoothness=smooth, foot_drift=drift)
