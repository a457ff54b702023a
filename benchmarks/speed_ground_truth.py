"""Blends at a requested in-between speed against the generator's true gait at that speed.

Builds (or opens) a two-source speed space (slow walk 0.8 m/s, jog 2.8 m/s, from the demo
captures), asks its parameter map for the weights of each requested speed, and compares the
linear, hybrid and non-linear blends with the synthetic generator's own gait at that speed, put
on the space's phase grid exactly like the sources. Reports per-vertex mean and max error (mm),
edge-length and volume errors, and linear / non-linear ratios.

    .venv/bin/python benchmarks/speed_ground_truth.py [--space data/spaces/speed.mspace]
    .venv/bin/python benchmarks/speed_ground_truth.py --tiny --out /tmp/speed_ground_truth.json

``--tiny`` (the test suite's smoke run) needs neither the captures nor a built space: it builds a
speed space from the generator's own gaits (1,000 vertices, 15 fps, no re-meshing or noise) in a
temporary directory and compares one speed, 1.8 m/s; ``--out`` is required with it.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from engine import evaluation
from engine.evaluation import ground_truth
from engine.mesh_io.dataset import read_capture_manifest
from engine.motion_space import MotionSpace
from engine.synthetic import build_body, gait

from _tiny import TINY_FPS, build_tiny_speed_space, parse_arguments


def compare_speeds(space, body, speeds, fps):
    """One row per speed: the weights the parameter map gives and each blend's errors against the
    generator's gait at that speed (``fps``: the truth's frame rate)."""
    cache = evaluation.BlendCache(space)
    faces = np.asarray(space.faces, dtype=np.int64)
    edges = ground_truth.mesh_edges(faces)
    rows = []
    for speed in speeds:
        solution = space.parameter_map.solve([speed])
        truth = evaluation.true_samples(space, body, gait(body.skeleton, speed, cycles=2.0, fps=fps))
        row = {"speed": speed, "weights": solution.weights.round(4).tolist(), "clamped": solution.clamped}
        for method in ("linear", "hybrid", "nonlinear"):
            row[method] = ground_truth.truth_errors(cache.blend(method, solution.weights), truth, faces, edges)
        row["ratio_mean"] = row["linear"]["mean_mm"] / row["nonlinear"]["mean_mm"]
        row["ratio_volume"] = row["linear"]["volume_error_percent"] / row["nonlinear"]["volume_error_percent"]
        row["ratio_edge"] = row["linear"]["edge_error_percent"] / row["nonlinear"]["edge_error_percent"]
        rows.append(row)
        print(f"speed {speed:.2f} m/s, weights {row['weights']}: " + "; ".join(
            f"{m} mean {row[m]['mean_mm']:.1f} mm max {row[m]['max_mm']:.0f} mm edge {row[m]['edge_error_percent']:.2f}% "
            f"volume {row[m]['volume_error_percent']:.2f}%" for m in ("linear", "hybrid", "nonlinear"))
            + f" | linear/non-linear: mean {row['ratio_mean']:.2f}, edge {row['ratio_edge']:.2f}, "
              f"volume {row['ratio_volume']:.2f}", flush=True)
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--space", type=Path, default=Path("data/spaces/speed.mspace"))
    parser.add_argument("--captures", type=Path, default=Path("data/captures/demo"))
    parser.add_argument("--speeds", type=float, nargs="+", default=[1.3, 1.8, 2.3])
    parser.add_argument("--tiny", action="store_true",
                        help="smoke run on a speed space built from the generator (1,000 vertices, 15 fps) at 1.8 "
                             "m/s; ignores --space and --captures; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/speed_ground_truth.json)")
    args = parse_arguments(parser, argv, {"speeds": [1.8]})
    if args.tiny:
        with tempfile.TemporaryDirectory(prefix="morphspace-bench-") as workdir:
            path = Path(workdir) / "speed.mspace"
            body = build_tiny_speed_space(path)
            with MotionSpace.open(path) as space:
                rows = compare_speeds(space, body, args.speeds, TINY_FPS)
    else:
        if not args.space.exists():
            subprocess.run([sys.executable, "-m", "server.cli", "build", "specs/demo/speed.toml", "--out",
                            str(args.space)], check=True)
        manifest = read_capture_manifest(args.captures)
        body = build_body(int(manifest["body"]["vertices"]), float(manifest["body"]["height"]))
        with MotionSpace.open(args.space) as space:
            rows = compare_speeds(space, body, args.speeds, 30.0)
    out = args.out or Path("benchmarks/results/speed_ground_truth.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
