"""Shape similarity and tree timings for many frames (issue target: 1,500 frames, matrix <= 30 s, tree <= 1 s).

Reads every unstructured frame of a capture dataset and repeats them, each repeat turned about
the vertical axis by a random angle and moved, until there are N frames (re-meshed captures of
3,000 vertices); then times the shape histograms, the dissimilarity matrix (chunked, worker
processes), the temporal filter and the similarity tree. Prints one JSON object (with the load
average, since the machine may be shared) and with --out appends it to a JSON list.

    .venv/bin/python benchmarks/similarity_scaling.py data/captures/demo --frames 1500 [--workers 2] \
        [--out benchmarks/results/similarity_scaling.json]
    .venv/bin/python benchmarks/similarity_scaling.py --tiny --out /tmp/similarity_scaling.json

``--tiny`` (the test suite's smoke run) needs no dataset: its frames are one gait cycle of the
generator's 1,000-vertex body at 15 fps, repeated turned and moved up to 60 frames, on one
worker; ``--out`` is required with it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from _tiny import parse_arguments
from engine.align.similarity import dissimilarity_matrix, frame_histograms, temporal_filter
from engine.align.similarity_tree import similarity_tree
from engine.mesh_io import read_frames
from engine.mesh_io.dataset import read_capture_manifest
from engine.rotations import rot_y
from engine.synthetic import animate, build_body, gait

TINY = {"frames": 60, "workers": 1}


def dataset_frames(dataset):
    """Every unstructured frame of a capture dataset: list of (V, F)."""
    manifest = read_capture_manifest(dataset)
    frames = []
    for entry in manifest["sequences"]:
        folder = dataset / "sequences" / entry["name"] / "unstructured"
        frames.extend((m.vertices, m.faces) for m in read_frames(folder))
    return frames


def tiny_frames():
    """The --tiny run's frames: one walk cycle (1.3 m/s) of the 1,000-vertex body at 15 fps: list of (V, F)."""
    body = build_body(1000)
    return [(V, body.F) for V in animate(body, gait(body.skeleton, 1.3, fps=15.0, cycles=1.0))]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path, nargs="?", help="capture dataset (not with --tiny)")
    parser.add_argument("--frames", type=int, default=1500)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tiny", action="store_true",
                        help="smoke run without a dataset: 60 frames of a generated walk, one worker; needs --out")
    parser.add_argument("--out", type=Path, help="append the result to this JSON list")
    args = parse_arguments(parser, argv, TINY)
    if args.tiny:
        base = tiny_frames()
    elif args.dataset is None:
        parser.error("give a capture dataset (or --tiny)")
    else:
        base = dataset_frames(args.dataset)
    rng = np.random.default_rng(args.seed)
    frames = []
    while len(frames) < args.frames:
        turn = rot_y(rng.uniform(-np.pi, np.pi)) if frames else np.eye(3)
        shift = rng.uniform(-2.0, 2.0, 3) * [1, 0, 1] if frames else np.zeros(3)
        frames.extend((V @ turn.T + shift, F) for V, F in base[:args.frames - len(frames)])
    lengths = [len(frames)]
    load_before = os.getloadavg()[0]
    timings = {}
    started = time.perf_counter()
    H, radius = frame_histograms(frames, workers=args.workers)
    timings["histograms_s"] = time.perf_counter() - started
    started = time.perf_counter()
    D, yaw = dissimilarity_matrix(H, workers=args.workers)
    timings["matrix_s"] = time.perf_counter() - started
    started = time.perf_counter()
    filtered = temporal_filter(D, lengths, 2)
    timings["filter_s"] = time.perf_counter() - started
    started = time.perf_counter()
    tree = similarity_tree(filtered)
    timings["tree_s"] = time.perf_counter() - started
    timings["similarity_total_s"] = timings["histograms_s"] + timings["matrix_s"] + timings["filter_s"]
    record = {"frames": len(frames), "vertices_mean": round(float(np.mean([len(V) for V, _ in frames])), 1),
              "workers": args.workers, **{k: round(v, 3) for k, v in timings.items()},
              "tree_depth": int(tree.depth.max()), "components": int(tree.components),
              "cpus": os.cpu_count(), "load_average_1min_before": round(load_before, 2),
              "machine": platform.machine(), "date": time.strftime("%Y-%m-%d %H:%M")}
    print(json.dumps(record))
    if args.out is not None:
        records = json.loads(args.out.read_text()) if args.out.is_file() else []
        records.append(record)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(records, indent=2) + "\n")


if __name__ == "__main__":
    main()
