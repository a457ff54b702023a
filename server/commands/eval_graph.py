"""Transitions of a motion graph against two baselines, on the same random requests.

Plays ``--requests`` random requests (a random node at random parameters every 2-4 s, from the
first cyclic node, at ``--fps``) per seed of ``--seeds`` with the transition search, an
immediate cut and a 0.3 s crossfade started at the request, all with the same player, and
reports per strategy over every seed's transitions: smoothness (1.0 = as smooth as captured) and
pop (the same for per-vertex acceleration),
latency from request to entering the target, foot sliding on the ground, root continuity
(1 or less: no root step larger than the motion around it), the seam's dissimilarity, the
search's time, and what holding the feet costs (the legs' offsets, and how much the legs'
thighs, shins and edges change length against the same frames played without holding). Definitions:
docs/evaluation.md, "Motion graph". Example:

    morphspace eval-graph data/spaces/demo.mgraph --seeds 0,1,2,3 --json
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from engine.graph import GraphError, MotionGraph, SearchOptions
from engine.graph.evaluate import evaluate_strategies, random_requests, summarise


def _seeds(text):
    try:
        seeds = [int(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(f"--seeds: expected integers from 0 separated by commas, got {text!r}") from None
    if any(seed < 0 for seed in seeds):
        raise ValueError(f"--seeds: seeds are integers from 0, got {text!r}")
    twice = next((seed for seed in seeds if seeds.count(seed) > 1), None)
    if twice is not None:   # the same requests twice would count twice
        raise ValueError(f"--seeds: seed {twice} is given twice, got {text!r}")
    return seeds


def add_arguments(parser):
    parser.add_argument("graph", type=Path, help="a .mgraph file (morphspace build-graph)")
    parser.add_argument("--requests", type=int, default=60, help="random requests per seed (default 60)")
    parser.add_argument("--seeds", default="0", help="seeds of the requests, comma-separated (default 0)")
    parser.add_argument("--fps", type=float, default=30.0, help="frames per second played (default 30)")
    parser.add_argument("--latency-weight", type=float, help="the search's (default: SearchOptions')")
    parser.add_argument("--candidates", type=int, help="transitions the search plays to predict their "
                        "smoothness and foot drift (default: SearchOptions'; 0: by seam and latency alone)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")


def run(args):
    if args.requests < 1:
        raise ValueError(f"--requests must be at least 1, got {args.requests}")
    if not (math.isfinite(args.fps) and args.fps > 0):
        raise ValueError(f"--fps must be a finite positive number of frames per second, got {args.fps:g}")
    if args.latency_weight is not None and not (math.isfinite(args.latency_weight) and args.latency_weight >= 0):
        raise ValueError(f"--latency-weight must be a number from 0 (cost per second of latency), "
                         f"got {args.latency_weight:g}")
    if args.candidates is not None and not 0 <= args.candidates <= 1000:
        raise ValueError(f"--candidates must be an integer from 0 to 1000, got {args.candidates}")
    seeds = _seeds(args.seeds)
    try:
        graph = MotionGraph.open(args.graph)
    except GraphError as exc:
        raise ValueError(str(exc)) from None
    chosen = {key: value for key, value in (("latency_weight", args.latency_weight),
                                                ("candidates", args.candidates)) if value is not None}
    try:
        options = SearchOptions(**chosen)
    except ValueError as exc:
        raise ValueError(f"--latency-weight / --candidates: {exc}") from None
    pooled = {}
    with graph:
        for seed in seeds:
            requests = random_requests(graph, args.requests, seed=seed)
            for name, (measures, seconds, held, legs) in evaluate_strategies(graph, requests, fps=args.fps,
                                                                              options=options).items():
                entry = pooled.setdefault(name, ([], [], [], [], []))
                entry[0].extend(measures)
                entry[1].extend(seconds)
                entry[2].extend(held.tolist())
                entry[3].extend(legs[0].tolist())
                entry[4].extend(legs[1].tolist())
        report = {"graph": graph.name, "path": str(args.graph), "vertices": int(graph.metadata["n_vertices"]),
                  "requests_per_seed": args.requests, "seeds": seeds, "fps": args.fps,
                  "latency_weight": options.latency_weight, "candidates": options.candidates,
                  "load_average": os.getloadavg()[0],
                  "strategies": {name: summarise(m, s, np.asarray(h), (np.asarray(g), np.asarray(e)))
                                 for name, (m, s, h, g, e) in pooled.items()}}
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{report['graph']} ({report['vertices']} vertices): {args.requests} random requests x seeds "
          f"{','.join(map(str, seeds))} at {args.fps:g} frames/s; search latency weight {options.latency_weight:g}, "
          f"candidates {options.candidates}")

    def f(x, spec=".2f"):
        return "-" if x is None else format(x, spec)

    def pair(s, first, second, spec=".1f"):   # two figures of a strategy, "first / second"
        return f(s.get(first), spec) + " / " + f(s.get(second), spec)
    print(f"{'strategy':<10} {'n':>4} {'smooth p50':>10} {'p95':>5} {'pop p50':>7} {'p95':>5} {'latency p50':>11} "
          f"{'p95':>5} {'slide p50/p95 cm':>16} {'root max':>8} {'seam p50 mm':>11} {'held %':>6} "
          f"{'leg p95/max cm':>14} {'leg length p95/max %':>20} {'leg edge p95/max %':>18}")
    for name, s in report["strategies"].items():
        held = s.get("frames_held")
        print(f"{name:<10} {s['transitions']:>4} {f(s['smoothness_p50']):>10} {f(s['smoothness_p95']):>5} "
              f"{f(s['pop_p50']):>7} {f(s['pop_p95']):>5} {f(s['latency_p50_s']):>11} {f(s['latency_p95_s']):>5} "
              f"{pair(s, 'foot_slide_p50_cm', 'foot_slide_p95_cm', '.2f'):>16} "
              f"{f(s['root_ratio_max']):>8} {f(s['seam_p50_mm'], '.1f'):>11} "
              f"{f(None if held is None else 100 * held, '.0f'):>6} "
              f"{pair(s, 'leg_offset_p95_cm', 'leg_offset_max_cm'):>14} "
              f"{pair(s, 'leg_segment_change_p95_pct', 'leg_segment_change_max_pct'):>20} "
              f"{pair(s, 'leg_edge_change_p95_pct', 'leg_edge_change_max_pct'):>18}")
    search = report["strategies"]["search"]
    print(f"search time median {search['search_p50_ms']:.3f} ms, p99 {search['search_p99_ms']:.3f} ms "
          f"({search['searches']} searches, wall clock, load average {report['load_average']:.1f})")
    return 0
