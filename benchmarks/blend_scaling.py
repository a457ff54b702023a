"""Blend speed and memory against mesh resolution (issue: table I targets at 3k, 20k, 50k vertices).

For each body resolution: generate a slow walk (0.8 m/s) and a jog (2.8 m/s) cycle, build a
two-source motion space at epsilon = 5 mm, and time linear, hybrid and exact non-linear blending
on one core at random weights and phases. Prints a table and writes JSON.

    .venv/bin/python benchmarks/blend_scaling.py [--vertices 3000 20000 50000] [--out results.json]
    .venv/bin/python benchmarks/blend_scaling.py --tiny --out /tmp/blend_scaling.json   # a few seconds

``--tiny`` (the test suite's smoke run): 1,000 vertices, gaits at 15 fps, 200 linear and hybrid
calls and 10 non-linear calls; ``--out`` is required with it.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from _tiny import parse_arguments
from engine.bench import blend_requests, blend_speed, single_core
from engine.motion_space import MotionSpace, SourceClip, build_motion_space
from engine.synthetic import animate, build_body, gait


TINY = {"vertices": [1000], "fps": 15.0, "calls": 200, "nonlinear_calls": 10}


def run_one(n_vertices, workdir, calls=2000, nonlinear_calls=40, fps=30.0):
    started = time.perf_counter()
    body = build_body(n_vertices)
    clips = []
    for name, speed in (("walk_slow", 0.8), ("jog", 2.8)):
        motion = gait(body.skeleton, speed, fps=fps, cycles=1.1, start_phase=0.0)
        clips.append(SourceClip(name, animate(body, motion), motion.fps, True, motion.frames_per_cycle))
    generate_s = time.perf_counter() - started
    path = Path(workdir) / f"walk_jog_{n_vertices}.mspace"
    report = build_motion_space(path, clips, body.F, name=f"walk_jog_{n_vertices}", epsilon=0.005, rest=body.V)
    space = MotionSpace.open(path)
    row = {"vertices": len(body.V), "tets": report["n_tets"], "phases": report["n_phases"],
           "generate_s": round(generate_s, 1), "build_s": report["timings"], "modes": {}}
    with single_core():
        for mode, count in (("linear", calls), ("hybrid", calls), ("nonlinear", nonlinear_calls)):
            blender = space.blender(mode)
            out = np.empty((space.n_vertices, 3), dtype=np.float32 if mode != "nonlinear" else np.float64)
            requests = blend_requests(2, count, seed=1)
            blender.blend(*requests[0], out=out)
            row["modes"][mode] = blend_speed(blender, requests, out=out)
    hybrid = report["hybrid"]
    row["hybrid"] = {"references": hybrid["references"], "max_test_error_mm": hybrid["max_test_error"] * 1000,
                     "correction_share_of_sources": hybrid["correction_bytes"] / hybrid["source_bytes"],
                     "correction_mb": hybrid["correction_bytes"] / 1e6, "source_mb": hybrid["source_bytes"] / 1e6}
    space.close()
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, nargs="+", default=[3000, 20000, 50000])
    parser.add_argument("--fps", type=float, default=30.0, help="frame rate of the generated gaits")
    parser.add_argument("--calls", type=int, default=2000, help="linear and hybrid blend calls per size")
    parser.add_argument("--nonlinear-calls", type=int, default=40, help="non-linear blend calls per size")
    parser.add_argument("--tiny", action="store_true",
                        help="smoke run: 1,000 vertices, 15 fps, 200 and 10 calls; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/blend_scaling.json)")
    args = parse_arguments(parser, argv, TINY)
    out = args.out or Path("benchmarks/results/blend_scaling.json")
    rows = []
    with tempfile.TemporaryDirectory() as workdir:
        for n in args.vertices:
            row = run_one(n, workdir, calls=args.calls, nonlinear_calls=args.nonlinear_calls, fps=args.fps)
            rows.append(row)
            m = row["modes"]
            print(f"{row['vertices']:>6} vertices {row['tets']:>6} tets | linear {m['linear']['frames_per_second']:>8.0f}/s "
                  f"hybrid {m['hybrid']['frames_per_second']:>7.0f}/s (median {m['hybrid']['median_us']:.1f} us) "
                  f"non-linear {m['nonlinear']['frames_per_second']:>5.0f}/s | corrections "
                  f"{100 * row['hybrid']['correction_share_of_sources']:.1f}% of sources, "
                  f"{row['hybrid']['references']} refs, max test error {row['hybrid']['max_test_error_mm']:.2f} mm | "
                  f"build {row['build_s']['total_s']:.0f} s", flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
