"""Benchmark a motion space's blend modes on one core.

Prints frames per second (by wall time and by the thread's CPU time, which a loaded machine does
not take away; median and 95th-percentile time per frame) for linear, hybrid and exact non-linear
blending at random weights and phases between grid samples, and the memory figures:
sources, hybrid corrections (and their share of the sources), non-linear data. Example:

    morphspace bench data/spaces/walk_jog.mspace --json
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from engine.bench import blend_requests, blend_speed, single_core
from engine.motion_space import MotionSpace

MAX_CALLS, MAX_NONLINEAR_CALLS = 1_000_000, 100_000


def add_arguments(parser):
    parser.add_argument("space", type=Path, help="a .mspace file")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    parser.add_argument("--calls", type=int, default=3000,
                        help=f"blend calls for linear and hybrid, 10 to {MAX_CALLS:,} (default 3000)")
    parser.add_argument("--nonlinear-calls", type=int, default=100,
                        help=f"calls for non-linear, 5 to {MAX_NONLINEAR_CALLS:,} (default 100)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random weights and phases (default 0)")


def run(args):
    if not 10 <= args.calls <= MAX_CALLS:
        raise ValueError(f"--calls must be between 10 and {MAX_CALLS}, got {args.calls}")
    if not 5 <= args.nonlinear_calls <= MAX_NONLINEAR_CALLS:
        raise ValueError(f"--nonlinear-calls must be between 5 and {MAX_NONLINEAR_CALLS}, got {args.nonlinear_calls}")
    if args.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
    space = MotionSpace.open(args.space)
    meta = space.metadata
    results = {"space": str(args.space), "name": space.name, "vertices": space.n_vertices,
               "sources": space.n_sources, "phases": space.n_phases, "tets": meta["n_tets"],
               "epsilon_mm": meta["epsilon"] * 1000, "modes": {}}
    out32 = np.empty((space.n_vertices, 3), dtype=np.float32)
    out64 = np.empty((space.n_vertices, 3), dtype=np.float64)
    with single_core():
        for mode, calls, out in (("linear", args.calls, out32), ("hybrid", args.calls, out32),
                                 ("nonlinear", args.nonlinear_calls, out64)):
            blender = space.blender(mode)
            requests = blend_requests(space.n_sources, calls, seed=args.seed)
            blender.blend(*requests[0], out=out)  # warm up (page in the mapped arrays)
            results["modes"][mode] = blend_speed(blender, requests, out=out)
    c = space.container
    source_bytes = c.nbytes("sources")
    correction_bytes = sum(c.nbytes(n) for n in c.names if n.startswith("corrections_"))
    nonlinear_bytes = sum(c.nbytes(n) for n in c.names if n.startswith("nl_") or n.startswith("tet"))
    results["memory"] = {
        "file_bytes": os.path.getsize(args.space), "source_bytes": source_bytes,
        "correction_bytes": correction_bytes, "correction_share_of_sources": correction_bytes / source_bytes,
        "nonlinear_bytes": nonlinear_bytes, "hybrid_references": meta["hybrid"]["references"]}
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"{space.name}: {space.n_vertices} vertices, {space.n_sources} sources x {space.n_phases} phases, "
          f"{meta['n_tets']} tets, one core")
    print(f"  {'mode':<10} {'frames/s':>10} {'CPU fr/s':>10} {'median us':>10} {'p95 us':>10}")
    for mode, r in results["modes"].items():
        print(f"  {mode:<10} {r['frames_per_second']:>10.0f} {r['cpu_frames_per_second']:>10.0f} "
              f"{r['median_us']:>10.1f} {r['p95_us']:>10.1f}")
    m = results["memory"]
    print(f"  sources {m['source_bytes'] / 1e6:.2f} MB, hybrid corrections {m['correction_bytes'] / 1e6:.2f} MB "
          f"({100 * m['correction_share_of_sources']:.1f}% of the sources, {m['hybrid_references']} references, "
          f"epsilon {results['epsilon_mm']:g} mm), non-linear data {m['nonlinear_bytes'] / 1e6:.1f} MB")
    return 0
