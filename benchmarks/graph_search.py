"""Motion graph transitions (issue 14): search time, and the search against two baselines.

1. Search time: ``--searches`` transition searches from random states (a node, a weight sample,
   a phase) to random successors at random parameters, one at a time on one core; median and
   99th percentile of the wall time and of the thread's CPU time.
2. The same ``--requests`` random requests (a random node at random parameters every 2-4 s)
   played at ``--fps`` by the graph player with the search, an immediate cut and a fixed 0.3 s
   crossfade (engine.graph.baselines); per strategy the medians and tails of smoothness, latency,
   foot sliding, root continuity and the seam's dissimilarity (engine.graph.evaluate).
3. The generator's true continuous performance (walk, stop, jump, start, walk: the ``performance``
   sequence of ``--captures``, the demo captures by default; with ``--tiny`` one generated for the
   tiny body): the graph asked to play the same script with each strategy, its frames compared
   with the true ones (engine.graph.performance: mean per-vertex distance per frame, at the same
   time and with 0.5 s of timing slack, and where the character ends).

    .venv/bin/python benchmarks/graph_search.py --graph data/spaces/demo.mgraph [--requests 40]
    .venv/bin/python benchmarks/graph_search.py --tiny --out /tmp/graph_search.json   # ~30 s
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from _tiny import parse_arguments
from engine.graph import MotionGraph, SearchOptions, TransitionSearch
from engine.graph.baselines import Crossfade, ImmediateCut
from engine.graph.evaluate import play_requests, random_requests, summarise, transition_measures
from engine.graph.performance import performance_distance, performance_requests, summarise_distance


def search_times(graph, search, count, seed):
    """(wall seconds, thread CPU seconds) per search from random states to random successors
    (CPU time leaves out the time the process waited for a core on a busy host)."""
    rng = np.random.default_rng(seed)
    sources = [n for n in graph.nodes if graph.successors(n.name)]
    seconds, cpu = [], []
    for _ in range(count):
        a = sources[int(rng.integers(len(sources)))]
        targets = graph.successors(a.name)
        b = graph.node(targets[int(rng.integers(len(targets)))])
        w = a.samples.weights[int(rng.integers(len(a.samples.weights)))]
        wb = b.samples.weights[int(rng.integers(len(b.samples.weights)))]
        phase = float(rng.uniform(0, 1))
        started, started_cpu = time.perf_counter(), time.thread_time()
        search.search(a.name, w, phase, b.name, wb)
        cpu.append(time.thread_time() - started_cpu)
        seconds.append(time.perf_counter() - started)
    return seconds, cpu


def true_performance(captures, tiny, fps):
    """The true continuous performance: {vertices (T, n, 3), root (T, 3), events, speed, jump:
    the jump node's parameters as the true jump was made}, or None when there is none."""
    if tiny:
        from engine.synthetic import animate, build_body
        from engine.synthetic.transitions import performance

        body = build_body(1000)  # the tiny spaces' body
        motion = performance(body.skeleton, 1.2, 0.45, 0.6, fps=fps)  # the tiny graph's higher jump, exactly
        return {"vertices": animate(body, motion), "root": motion.root_position, "events": motion.events,
                "speed": 1.2, "jump": {"jump_height": "max"}}
    if captures is None or not (Path(captures) / "sequences" / "performance").is_dir():
        return None
    from engine.mesh_io.dataset import load_capture_truth

    meta = json.loads((Path(captures) / "sequences" / "performance" / "meta.json").read_text())
    truth = load_capture_truth(captures, "performance")
    if meta["fps"] != fps:
        raise SystemExit(f"the performance is at {meta['fps']} frames/s; run with --fps {meta['fps']}")
    asked = meta["requested"]
    return {"vertices": truth["template_positions"], "root": truth["root_position"], "events": meta["events"],
            "speed": asked["speed"], "jump": {"jump_height": asked["height"], "jump_distance": asked["distance"]}}


def compare_performance(graph, strategies, truth, fps):
    """Per strategy: the graph playing the true performance's script, against it."""
    walk, jump = graph.node("walk"), graph.node("jump")
    walk_params = {"turn_rate": 0.0} if "turn_rate" in walk.parameters else {}
    jump_params = {}
    for name, value in truth["jump"].items():
        if name in jump.parameters:  # "max": the top of the range (a source, exactly)
            index = jump.parameters.index(name)
            jump_params[name] = float(jump.space.parameter_map.domain()[index][1]) if value == "max" else value
    speed, events = truth["speed"], truth["events"]
    requests = performance_requests(events, fps, speed=speed, jump_params=jump_params, walk_params=walk_params)
    tail = (len(truth["vertices"]) - 1) / fps - requests[-1].time
    out = {"speed": speed, "jump": jump_params, "true_frames": int(len(truth["vertices"])), "strategies": {}}
    for name, strategy in strategies:
        frames, _, _ = play_requests(graph, strategy, requests, fps=fps, start="walk",
                                     params={"speed": speed, **walk_params}, tail=tail)
        distance = performance_distance(frames["vertices"], truth["vertices"], fps=fps, root=frames["root"],
                                        true_root=truth["root"])
        out["strategies"][name] = summarise_distance(distance, graph.model_size)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", type=Path, default=Path("data/spaces/demo.mgraph"))
    parser.add_argument("--searches", type=int, default=5000)
    parser.add_argument("--requests", type=int, default=40)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--latency-weight", type=float, help="the search's (default: SearchOptions')")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--captures", type=Path, default=Path("data/captures/demo"),
                        help="a capture dataset with the true 'performance' sequence (skipped if absent)")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/graph_search.json)")
    parser.add_argument("--tiny", action="store_true", help="the tiny graph (engine.graph.tiny) built in a "
                        "temporary directory, 500 searches, 6 requests (needs --out)")
    args = parse_arguments(parser, argv, {"searches": 500, "requests": 6})
    out = args.out or Path(__file__).parent / "results" / "graph_search.json"
    with tempfile.TemporaryDirectory() as scratch:
        path = args.graph
        if args.tiny:
            from engine.graph.tiny import build_tiny_graph, build_tiny_spaces

            build_tiny_spaces(scratch)
            path = Path(scratch) / "tiny.mgraph"
            build_tiny_graph(scratch, path)
        with MotionGraph.open(path) as graph:
            options = SearchOptions() if args.latency_weight is None else SearchOptions(
                latency_weight=args.latency_weight)
            search = TransitionSearch(graph, options)
            seconds, cpu = search_times(graph, search, args.searches, args.seed)
            ms, cpu_ms = np.asarray(seconds) * 1e3, np.asarray(cpu) * 1e3
            result = {"graph": graph.name, "vertices": graph.metadata["n_vertices"],
                      "nodes": [n.name for n in graph.nodes], "latency_weight": options.latency_weight,
                      "search_ms": {"median": float(np.median(ms)), "p99": float(np.percentile(ms, 99)),
                                    "max": float(ms.max()), "count": len(ms)},
                      "search_cpu_ms": {"median": float(np.median(cpu_ms)), "p99": float(np.percentile(cpu_ms, 99)),
                                        "max": float(cpu_ms.max())},
                      "fps": args.fps, "requests": args.requests, "load_average": os.getloadavg()[0],
                      "strategies": {}}
            requests = random_requests(graph, args.requests, seed=args.seed)
            start = next(n.name for n in graph.nodes if n.cyclic)
            strategies = (("search", search), ("cut", ImmediateCut(graph)), ("crossfade", Crossfade(graph)))
            for name, strategy in strategies:
                frames, transitions, searched = play_requests(graph, strategy, requests, fps=args.fps, start=start)
                measures = transition_measures(graph, frames, transitions, fps=args.fps)
                result["strategies"][name] = summarise(measures, searched, frames["held"])
            truth = true_performance(args.captures, args.tiny, args.fps)
            result["performance"] = None if truth is None else compare_performance(graph, strategies, truth, args.fps)
    print(f"{result['graph']} ({result['vertices']} vertices): search median {result['search_ms']['median']:.3f} ms, "
          f"p99 {result['search_ms']['p99']:.3f} ms over {len(seconds)} searches (load average "
          f"{result['load_average']:.1f}); CPU time median {result['search_cpu_ms']['median']:.3f} ms, "
          f"p99 {result['search_cpu_ms']['p99']:.3f} ms")
    print(f"{'strategy':<10} {'n':>3} {'smooth p50':>10} {'p95':>6} {'latency p50':>11} {'p95':>6} "
          f"{'slide p50 cm':>12} {'p95':>6} {'root max':>8} {'seam p50 mm':>11} {'leg p95/max cm':>14}")
    for name, s in result["strategies"].items():
        def f(x, spec=".2f"):
            return "-" if x is None else format(x, spec)
        print(f"{name:<10} {s['transitions']:>3} {f(s['smoothness_p50']):>10} {f(s['smoothness_p95']):>6} "
              f"{f(s['latency_p50_s']):>11} {f(s['latency_p95_s']):>6} {f(s['foot_slide_p50_cm']):>12} "
              f"{f(s['foot_slide_p95_cm']):>6} {f(s['root_ratio_max']):>8} {f(s['seam_p50_mm'], '.1f'):>11} "
              f"{f(s['leg_offset_p95_cm'], '.1f') + ' / ' + f(s['leg_offset_max_cm'], '.1f'):>14}")
    if result["performance"] is not None:
        print(f"against the true performance ({result['performance']['true_frames']} frames): mean per-vertex "
              "distance per frame, mm (p50 / p95), at the same time and with 0.5 s of slack, in the world and "
              "the pose alone (roots made to coincide); where it ends (m)")
        for name, s in result["performance"]["strategies"].items():
            cells = "   ".join(f"{key} {s[key]['p50_mm']:6.1f} / {s[key]['p95_mm']:6.1f}"
                               for key in ("aligned", "slack", "pose_aligned", "pose_slack"))
            print(f"{name:<10} {cells}   end {s['end_offset_m']:.3f}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
