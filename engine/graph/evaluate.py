"""Measuring transitions: smoothness, root continuity, foot sliding, latency and search time,
for the search and for the baselines (``baselines``) on the same random requests.

Definitions (docs/evaluation.md, "Motion graph"):

- smoothness: the largest per-vertex step between consecutive frames during a transition (from
  the frame before the blend starts to the frame it ends), divided by the largest step within
  the two nodes' own motion at the same weights and frame rate (1.0 = as smooth as captured);
- pop (a second measure, since 2026-11-25): the same for the per-vertex acceleration, the change
  of a vertex's step between consecutive steps (|x[f+1] - 2 x[f] + x[f-1]|), from the step into
  the blend to the step out of it: a blend that is short or starts abruptly kinks the motion
  without a larger step;
- root: the largest root step during the transition divided by the largest in the half second
  before and after it or in either node's own motion at the same weights (1 or less: no step
  larger than the motion around it); the heading's largest step in degrees;
- foot sliding: per step, of a foot's vertices on the ground (less than ``contact`` above the
  rest mesh's lowest point) in both frames, the horizontal travel of the one that moved least
  (the point the foot pivots on; ``clock.foot_slide``), summed over the transition, the worse foot;
- latency: seconds from the request to the frame the target is fully entered;
- leg offset (what holding the feet costs, ``engine.graph.feet``): per frame, the largest
  horizontal distance of a foot from where the motion puts it, over every frame played;
- leg distortion (how the legs carry it): per frame, against the same frame played without
  holding the feet, the largest relative change of a thigh's or shin's length (hip-knee and
  knee-ankle ring centroids, ``engine.graph.legs``) and of the length of an edge of the legs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from engine.graph.clock import NodeClock, foot_slide, foot_vertices, move, place
from engine.graph.legs import LegRig
from engine.graph.player import GraphPlayer


@dataclass
class Request:
    time: float
    node: str
    params: dict


def random_requests(graph, count, *, seed=0, spacing=(2.0, 4.0)):
    """``count`` requests of random nodes at random parameters, ``spacing`` seconds apart."""
    rng = np.random.default_rng(seed)
    out, t = [], 1.0
    for _ in range(count):
        node = graph.nodes[int(rng.integers(len(graph.nodes)))]
        pmap = node.space.parameter_map
        params = {} if pmap is None else {n: float(rng.uniform(lo, hi)) for n, (lo, hi) in
                                          zip(pmap.names, pmap.domain())}
        out.append(Request(round(t, 4), node.name, params))
        t += float(rng.uniform(*spacing))
    return out


class _Timed:
    """Wraps a search and times every call."""

    def __init__(self, search):
        self.inner, self.options, self.seconds = search, search.options, []

    def search(self, *args, **kwargs):
        t0 = time.perf_counter()
        result = self.inner.search(*args, **kwargs)
        self.seconds.append(time.perf_counter() - t0)
        return result


class _LegDistortion:
    """Per frame, how much the held legs differ from the same frame without holding."""

    def __init__(self, graph):
        rest = np.asarray(graph.nodes[0].space.container["rest"])
        self.rig = LegRig(rest, foot_vertices(rest))
        faces = np.asarray(graph.nodes[0].space.faces)
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        legs = np.isin(edges, self.rig.index).all(axis=1)
        self.edges = np.unique(np.sort(edges[legs], axis=1), axis=0)

    def __call__(self, shown, plain):
        """(segment change, edge change): the largest relative length changes, 0 = none."""
        segments = float(np.abs(self.rig.segments(shown) / self.rig.segments(plain) - 1.0).max())
        a, b = self.edges[:, 0], self.edges[:, 1]
        edges = np.linalg.norm(shown[a] - shown[b], axis=1) / np.maximum(np.linalg.norm(plain[a] - plain[b], axis=1),
                                                                          1e-9)
        return segments, float(np.abs(edges - 1.0).max())


def play_requests(graph, search, requests, *, fps=30.0, start="walk", params=None, mode="linear", tail=3.0,
                  legs=False):
    """Play ``requests`` (sorted by time) and keep every frame.

    With ``legs``, a second player plays the same requests without holding the feet, and every
    frame in which a foot is held is compared with its twin (``_LegDistortion``).

    Returns
    -------
    frames : dict of arrays   vertices (F, n, 3) float32, root (F, 3), heading (F,), node (F,) str,
                              held (F,) the largest leg offset holding a foot (m); with ``legs``,
                              segments (F,) and edges (F,) the legs' largest relative length changes
    transitions : list of dict  request frame, leave frame, enter frame, source, target, weights, plan
    search_seconds : list of float
    """
    timed = _Timed(search)
    player = GraphPlayer(graph, node=start, params=params, mode=mode, search=timed)
    twin = GraphPlayer(graph, node=start, params=params, mode=mode, search=search, foot_lock=False) if legs else None
    measure = _LegDistortion(graph) if legs else None
    distortion = []
    dt = 1.0 / fps
    end = (requests[-1].time if requests else 0.0) + tail
    pending = list(requests)
    vertices, root, heading, nodes, held, transitions, open_ = [], [], [], [], [], [], {}
    asked = None
    for k in range(int(round(end * fps)) + 1):
        while pending and pending[0].time <= k * dt + 1e-9:
            r = pending.pop(0)
            player.request(r.node, r.params)
            if twin is not None:
                twin.request(r.node, r.params)
            asked = k
        frame = player.step(dt) if k else player.frame()
        if twin is not None:
            plain = twin.step(dt, placed=False) if k else twin.frame(placed=False)
            distortion.append(measure(player.frame(placed=False).vertices, plain.vertices))
        for event in frame.events:
            if event.startswith("leave"):
                plan, source_weights = player.left
                open_ = {"request": asked, "leave": k, "source": plan.source, "target": plan.target,
                         "source_weights": source_weights, "target_weights": plan.target_weights,
                         "dissimilarity": plan.dissimilarity, "length": plan.length}
                asked = None  # a later transition without a request of its own is a one-shot's return
            elif event.startswith("enter") and open_:
                open_["enter"] = k
                transitions.append(open_)
                open_ = {}
        vertices.append(frame.vertices.copy())
        root.append(frame.root_position)
        heading.append(frame.heading)
        nodes.append(frame.node)
        held.append(float(np.hypot(*player.pins.offsets.T).max()))
    out = {"vertices": np.stack(vertices), "root": np.stack(root), "heading": np.array(heading),
           "node": np.array(nodes), "held": np.array(held)}
    if legs:
        out["segments"], out["edges"] = (np.array(x) for x in zip(*distortion))
    return out, transitions, timed.seconds


def own_motion_step(graph, node, weights, fps, *, offsets=4, pop=False):
    """The largest per-vertex step and the largest root step between consecutive frames of
    ``node`` played alone at ``weights`` for one cycle (or its whole clip), metres. The root's is
    the largest over ``offsets`` start phases a fraction of a frame apart (a transition enters a
    node at any phase, so its frames may fall anywhere in the cycle). With ``pop``, also the
    largest per-vertex acceleration (change of step between consecutive steps, m per frame)."""
    n = graph.node(node)
    clock = NodeClock(n.space, weights, 0.0)
    position, heading = np.zeros(3), 0.0
    previous, largest, step, accel = None, 0.0, None, 0.0
    count = int(np.ceil(clock.duration * fps)) + 1
    for _ in range(count):
        V = place(clock.mesh("linear"), position, heading)
        if previous is not None:
            largest = max(largest, float(np.linalg.norm(V - previous, axis=1).max()))
            if step is not None:
                accel = max(accel, float(np.linalg.norm(V - previous - step, axis=1).max()))
            step = V - previous
        previous = V
        position, heading = move(position, heading, *clock.advance(1.0 / fps))
    root = 0.0
    for k in range(offsets):
        clock = NodeClock(n.space, weights, 0.0)
        clock.advance(k / offsets / fps)
        position, heading = np.zeros(3), 0.0
        for _ in range(count):
            moved, heading = move(position, heading, *clock.advance(1.0 / fps))
            root = max(root, float(np.linalg.norm(moved - position)))
            position = moved
    return (largest, root, accel) if pop else (largest, root)


def transition_measures(graph, frames, transitions, *, fps, contact=0.01):
    """Per transition: smoothness, root ratios, foot slide (m), latency (s), seam (m)."""
    rest = np.asarray(graph.nodes[0].space.container["rest"])
    feet = foot_vertices(rest)
    ground = float(rest[:, 1].min())
    V, root, heading = frames["vertices"], frames["root"], frames["heading"]
    cache, out = {}, []
    for t in transitions:
        a, b = t["leave"] - 1, t["enter"]
        if a < 1 or b + 1 >= len(V):
            continue
        keys = [(t["source"], np.asarray(t["source_weights"], dtype=float).tobytes()),  # the exact weights
                (t["target"], np.asarray(t["target_weights"], dtype=float).tobytes())]
        for key, w in zip(keys, (t["source_weights"], t["target_weights"])):
            if key not in cache:
                cache[key] = own_motion_step(graph, key[0], w, fps, pop=True)
        reference = max(cache[keys[0]][0], cache[keys[1]][0])
        root_reference = max(cache[keys[0]][1], cache[keys[1]][1])
        steps = np.linalg.norm(np.diff(V[a:b + 1], axis=0), axis=2).max(axis=1)
        pop_reference = max(cache[keys[0]][2], cache[keys[1]][2], 1e-9)
        pops = np.linalg.norm(np.diff(V[a - 1:b + 2], n=2, axis=0), axis=2).max(axis=1)
        root_steps = np.linalg.norm(np.diff(root, axis=0), axis=1)
        turn_steps = np.abs(np.diff(heading))
        around = np.r_[max(0, a - int(fps / 2)):a, b + 1:min(len(root_steps), b + 1 + int(fps / 2))]
        slide = max(sum(foot_slide(V[f - 1][foot], V[f][foot], ground + contact)[0] for f in range(a + 1, b + 1))
                    for foot in feet)
        out.append({
            "source": t["source"], "target": t["target"], "smoothness": float(steps.max() / reference),
            "pop": float(pops.max() / pop_reference),
            "root_ratio": float(root_steps[a:b].max() / max(root_steps[around].max() if len(around) else 0.0,
                                                            root_reference, 1e-3 / fps)),
            "turn_step_deg": float(np.degrees(turn_steps[a:b].max())),
            "foot_slide_m": slide, "latency_s": (t["enter"] - t["request"]) / fps if t["request"] is not None else None,
            "seam_m": t["dissimilarity"], "length_s": t["length"]})
    return out


def summarise(measures, search_seconds, held=None, legs=None):
    """Medians and tails of ``transition_measures`` and search times (ms); with ``held`` (the
    frames' leg offsets, m), their 95th percentile and largest (cm) and the share of frames held;
    with ``legs`` ((segments, edges) per frame, ``play_requests``), over the frames held, the 95th
    percentile and the largest relative change of a leg segment's and of a leg edge's length (%)."""
    def pick(key):
        return np.array([m[key] for m in measures if m[key] is not None], dtype=float)

    def pct(values, q):
        return float(np.percentile(values, q)) if len(values) else None

    s, lat, slide, rootr, seam, pop = (pick("smoothness"), pick("latency_s"), pick("foot_slide_m"),
                                       pick("root_ratio"), pick("seam_m"), pick("pop"))
    ms = np.asarray(search_seconds) * 1e3
    return {"transitions": len(measures),
            "smoothness_p50": pct(s, 50), "smoothness_p95": pct(s, 95),
            "pop_p50": pct(pop, 50), "pop_p95": pct(pop, 95),
            "latency_p50_s": pct(lat, 50), "latency_p95_s": pct(lat, 95),
            "foot_slide_p50_cm": None if not len(slide) else pct(slide, 50) * 100,
            "foot_slide_p95_cm": None if not len(slide) else pct(slide, 95) * 100,
            "root_ratio_max": None if not len(rootr) else float(rootr.max()),
            "seam_p50_mm": None if not len(seam) else pct(seam, 50) * 1000,
            "search_p50_ms": pct(ms, 50), "search_p99_ms": pct(ms, 99), "searches": int(len(ms)),
            **({} if held is None or not len(held) else {
                "leg_offset_p95_cm": pct(held, 95) * 100, "leg_offset_max_cm": float(np.max(held)) * 100,
                "frames_held": float(np.mean(np.asarray(held) > 0))}),
            **({} if legs is None or held is None or not np.any(np.asarray(held) > 0) else {
                f"leg_{name}_change_{tag}_pct": float(f(np.asarray(values)[np.asarray(held) > 0])) * 100
                for name, values in zip(("segment", "edge"), legs)
                for tag, f in (("p95", lambda x: np.percentile(x, 95)), ("max", np.max))})}


def evaluate_strategies(graph, requests, *, fps=30.0, options=None, start=None):
    """The same ``requests`` played with the search (``options``: SearchOptions), an immediate
    cut and a 0.3 s crossfade (``baselines``), all with the same player; per strategy
    (measures, search seconds, frames' leg offsets, (segments, edges) the frames' leg distortion)."""
    from engine.graph.baselines import Crossfade, ImmediateCut
    from engine.graph.search import TransitionSearch

    start = start or next(n.name for n in graph.nodes if n.cyclic)
    out = {}
    for name, strategy in (("search", TransitionSearch(graph, options)), ("cut", ImmediateCut(graph)),
                           ("crossfade", Crossfade(graph))):
        frames, transitions, seconds = play_requests(graph, strategy, requests, fps=fps, start=start, legs=True)
        out[name] = (transition_measures(graph, frames, transitions, fps=fps), seconds, frames["held"],
                     (frames["segments"], frames["edges"]))
    return out
