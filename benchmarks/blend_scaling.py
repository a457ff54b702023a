"""Blend speed and memory against mesh resolution (issue: table I targets at 3k, 20k, 50k vertices).

For each body resolution: generate a slow walk (0.8 m/s) and a jog (2.8 m/s) cycle, build a
two-source speed space at epsilon = 5 mm, and time linear, hybrid and exact non-linear blending
on one core (BLAS/OpenMP pinned to one thread) at random weights and phases, and the player's
per-frame path (``Player.step``) at settled and at moving parameters; and checks the hybrid
against the non-linear blend over a dense sampling of the weight simplex (``--dense`` weights, 4x
denser than the build's test weights, at every phase sample). Prints a table and writes JSON. Frames/s are given by wall time and by this thread's CPU time (what the core does when a
loaded machine does not take it away; the load average is recorded with the figures).

    .venv/bin/python benchmarks/blend_scaling.py [--vertices 3000 20000 50000] [--out results.json]
    .venv/bin/python benchmarks/blend_scaling.py --tiny --out /tmp/blend_scaling.json   # a few seconds

``--tiny`` (the test suite's smoke run): 1,000 vertices, gaits at 15 fps, 200 linear and hybrid
calls, 10 non-linear calls, 100 player steps and 9 weights for the dense check; ``--out`` is
required with it.
"""

from __future__ import annotations

import os

# One core: BLAS and OpenMP pools get one thread before numpy is imported (and threadpoolctl
# holds them there while timing).
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_variable] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from _tiny import parse_arguments  # noqa: E402
from engine.bench import blend_requests, blend_speed, player_speed, single_core  # noqa: E402
from engine.blend import phase_of_sample  # noqa: E402
from engine.motion_space import MotionSpace, SourceClip, build_motion_space  # noqa: E402
from engine.parameters import Layout  # noqa: E402
from engine.player import Player  # noqa: E402
from engine.synthetic import animate, build_body, gait  # noqa: E402


TINY = {"vertices": [1000], "fps": 15.0, "calls": 200, "nonlinear_calls": 10, "steps": 100, "dense": 9}


def _player_speeds(space, mode, steps):
    """Player.step frames/s at settled parameters (phase tables) and while steered (a new
    speed every half second, so the weights move and every frame blends)."""
    out = np.empty((space.n_vertices, 3), dtype=np.float32)
    lo, hi = space.parameter_map.domain()[0]
    settled = Player(space, mode=mode, smoothing=0.0, params={"speed": 0.5 * (lo + hi)})
    for _ in range(10):
        settled.step(1 / 60, out=out)
    steered = Player(space, mode=mode, smoothing=0.25, params={"speed": lo})
    steered.set_params({"speed": hi})
    result = {"settled": player_speed(settled, steps, out=out)}
    chunks = []
    for k in range(max(1, steps // 30)):
        steered.set_params({"speed": hi if k % 2 else lo})
        chunks.append(player_speed(steered, 30, out=out))
    result["steered"] = {"median_us": float(np.median([c["median_us"] for c in chunks])),
                         "frames_per_second": float(30 * len(chunks) / sum(30 / c["frames_per_second"]
                                                                            for c in chunks)),
                         "steps": 30 * len(chunks)}
    return result


def dense_hybrid_error(space, count):
    """Largest hybrid - non-linear distance (m) over ``count`` weights evenly along the two-source
    simplex (the whole of it) at every phase sample, and the weight where it is largest."""
    hybrid, nonlinear = space.blender("hybrid"), space.blender("nonlinear")
    worst = (0.0, None)
    for u in np.linspace(0.0, 1.0, count):
        w = np.array([1.0 - u, u])
        for p in range(space.n_phases):
            phase = phase_of_sample(p, space.n_phases, space.cyclic)
            error = float(np.linalg.norm(hybrid.blend(w, phase) - nonlinear.blend(w, phase), axis=1).max())
            worst = max(worst, (error, float(u)), key=lambda x: x[0])
    return worst


def run_one(n_vertices, workdir, calls=2000, nonlinear_calls=40, fps=30.0, steps=600, dense=129):
    started = time.perf_counter()
    body = build_body(n_vertices)
    clips = []
    for name, speed in (("walk_slow", 0.8), ("jog", 2.8)):
        motion = gait(body.skeleton, speed, fps=fps, cycles=1.1, start_phase=0.0)
        clips.append(SourceClip(name, animate(body, motion), motion.fps, True, motion.frames_per_cycle))
    generate_s = time.perf_counter() - started
    path = Path(workdir) / f"walk_jog_{n_vertices}.mspace"
    report = build_motion_space(path, clips, body.F, name=f"walk_jog_{n_vertices}", epsilon=0.005, rest=body.V,
                                parameters={"layout": Layout("chain", 2, chain=(0, 1)), "names": ["speed"]})
    space = MotionSpace.open(path)
    row = {"vertices": len(body.V), "tets": report["n_tets"], "phases": report["n_phases"],
           "generate_s": round(generate_s, 1), "build_s": report["timings"], "threads": 1,
           "load_average": os.getloadavg()[0], "modes": {}, "player": {}}
    with single_core():
        for mode, count in (("linear", calls), ("hybrid", calls), ("nonlinear", nonlinear_calls)):
            blender = space.blender(mode)
            out = np.empty((space.n_vertices, 3), dtype=np.float32 if mode != "nonlinear" else np.float64)
            requests = blend_requests(2, count, seed=1)
            blender.blend(*requests[0], out=out)
            row["modes"][mode] = blend_speed(blender, requests, out=out)
        for mode in ("linear", "hybrid", "nonlinear"):
            row["player"][mode] = _player_speeds(space, mode, steps if mode != "nonlinear" else max(30, steps // 10))
    row["load_average_after"] = os.getloadavg()[0]
    hybrid = report["hybrid"]
    dense_error, dense_at = dense_hybrid_error(space, dense)
    row["hybrid"] = {"references": hybrid["references"], "max_test_error_mm": hybrid["max_test_error"] * 1000,
                     "dense_weights": dense, "dense_max_error_mm": dense_error * 1000, "dense_worst_weight": dense_at,
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
    parser.add_argument("--dense", type=int, default=129,
                        help="weights along the simplex for the hybrid's dense error check (every phase)")
    parser.add_argument("--steps", type=int, default=600,
                        help="player steps per mode (non-linear: a tenth, at least 30)")
    parser.add_argument("--tiny", action="store_true",
                        help="smoke run: 1,000 vertices, 15 fps, 200 and 10 calls, 100 steps; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/blend_scaling.json)")
    args = parse_arguments(parser, argv, TINY)
    out = args.out or Path("benchmarks/results/blend_scaling.json")
    rows = []
    with tempfile.TemporaryDirectory() as workdir:
        for n in args.vertices:
            row = run_one(n, workdir, calls=args.calls, nonlinear_calls=args.nonlinear_calls, fps=args.fps,
                          steps=args.steps, dense=args.dense)
            rows.append(row)
            m, pl = row["modes"], row["player"]
            print(f"{row['vertices']:>6} vertices {row['tets']:>6} tets, one core (1 BLAS/OpenMP thread), load average "
                  f"{row['load_average']:.1f}", flush=True)
            for mode in ("linear", "hybrid", "nonlinear"):
                print(f"  {mode:<10} blend {m[mode]['frames_per_second']:>8.0f}/s wall, "
                      f"{m[mode]['cpu_frames_per_second']:>8.0f}/s CPU time, median {m[mode]['median_us']:>7.1f} us | "
                      f"player.step settled {pl[mode]['settled']['frames_per_second']:>7.0f}/s, "
                      f"steered {pl[mode]['steered']['frames_per_second']:>7.0f}/s", flush=True)
            hybrid = row["hybrid"]
            print(f"  corrections {100 * hybrid['correction_share_of_sources']:.1f}% of sources, "
                  f"{hybrid['references']} refs, max test error {hybrid['max_test_error_mm']:.2f} mm | "
                  f"build {row['build_s']['total_s']:.0f} s", flush=True)
            print(f"  hybrid - non-linear over a dense sampling of the weight simplex ({hybrid['dense_weights']} "
                  f"weights x {row['phases']} phases): max {hybrid['dense_max_error_mm']:.2f} mm "
                  f"(epsilon 5 mm)", flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
