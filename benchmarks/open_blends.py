"""Capped volume of 50/50 blends of open studio frames (issue 12 target: non-linear within 2%).

A studio capture (``morphspace synth --preset studio`` or ``studio-tiny``) gives every frame in
the template's topology as ground truth (``truth.npz`` ``template_positions``: the dressed body,
closed). For each sequence one pair of frames is taken, a quarter and three quarters through it,
and the holes the studio's cameras leave (``engine.synthetic.studio.reconstruct.camera_holes``:
soles on the ground, a patch on top of the head, random occlusions) are cut from the template
topology where the first frame has them; both frames keep the same faces, as frames aligned to
an open root do. The pair is blended 50/50 non-linearly (tetrahedra of the template's A-pose
with the same holes, capped) and linearly, and the capped volume of each blend
(``engine.holes.capped_volume``) is compared with the mean of the two inputs'. Prints a row per
pair and the median and largest changes; writes JSON.

    .venv/bin/python benchmarks/open_blends.py --dataset /tmp/studio-full --out results.json
    .venv/bin/python benchmarks/open_blends.py --tiny --out /tmp/open_blends.json   # a few seconds

Sequences in millimetres or Z up are converted to metres, Y up first (their ``meta.json``).
``--tiny`` (the test suite's smoke run): no dataset needed; it generates ``studio-tiny``'s walk
(ground truth only, no reconstructions or previews) into a temporary directory.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _tiny import parse_arguments
from engine.blend import FrameDecomposer, NonlinearBlender, VolumetricEmbedding, decompose_frames
from engine.holes import boundary_loops, capped_volume
from engine.mesh_io import read_mesh
from engine.mesh_io.dataset import load_capture_truth, read_capture_manifest
from engine.mesh_io.units import to_metres_y_up
from engine.surface import vertex_normals
from engine.synthetic.studio.reconstruct import StudioCamera, camera_holes

TARGET_PERCENT = 2.0
TINY = {"only": ["walk"]}


def open_pair(template, faces, A, B, *, head, seed):
    """The template topology with the holes the cameras leave on frame A, for A, B and the rest.

    Returns (faces, A, B, rest, dropped): faces renumbered onto the vertices still used."""
    normal = vertex_normals(A, faces)
    drop = camera_holes(A, faces, camera=StudioCamera(), seed=seed, head_top=A[head], head_up=normal[head])
    kept = faces[~drop]
    used = np.unique(kept)
    index = np.full(len(A), -1)
    index[used] = np.arange(len(used))
    return index[kept], A[used], B[used], template[used], int(drop.sum())


def blend_pair(faces, A, B, rest):
    """(non-linear, linear) 50/50 blends of A and B (same topology), tetrahedra from ``rest``."""
    embedding = VolumetricEmbedding.from_surface(rest, faces)
    frames = np.stack([A, B]).astype(np.float32)
    q, s, d = decompose_frames(FrameDecomposer(embedding), frames)
    nonlinear = NonlinearBlender(embedding, q, s, d, frames).blend_frames(np.array([0.5, 0.5]), np.array([0, 1]))
    return nonlinear, 0.5 * (A + B)


def run(dataset, only=None):
    manifest = read_capture_manifest(dataset)
    template = read_mesh(Path(dataset) / "template" / "body.obj")
    faces = np.asarray(template.faces, dtype=np.int64)
    body = manifest["body"].get("parts", {}).get("body", len(template.vertices))
    head = int(np.argmax(template.vertices[:body, 1]))  # the top of the head in the A-pose
    rows = []
    for index, sequence in enumerate(manifest["sequences"]):
        if only and sequence["name"] not in only:
            continue
        started = time.perf_counter()
        truth = load_capture_truth(dataset, sequence["name"])
        frames = to_metres_y_up(truth["template_positions"], sequence.get("units", "m"), sequence.get("up", "+Y"))
        a, b = len(frames) // 4, (3 * len(frames)) // 4
        F, A, B, rest, dropped = open_pair(template.vertices, faces, frames[a], frames[b], head=head, seed=index)
        nonlinear, linear = blend_pair(F, A, B, rest)
        inputs = [capped_volume(A, F), capped_volume(B, F)]
        mean = 0.5 * sum(inputs)
        rows.append({"sequence": sequence["name"], "frames": [a, b], "vertices": int(len(A)),
                     "faces_dropped": dropped, "holes": len(boundary_loops(F)),
                     "input_volumes_l": [1000 * v for v in inputs],
                     "nonlinear_change_percent": 100 * (capped_volume(nonlinear, F) / mean - 1),
                     "linear_change_percent": 100 * (capped_volume(linear, F) / mean - 1),
                     "seconds": time.perf_counter() - started})
        r = rows[-1]
        print(f"{r['sequence']:<14} frames {a:>3}+{b:<3} {r['vertices']:>6} vertices, {r['holes']:>2} holes "
              f"({dropped} faces) | inputs {r['input_volumes_l'][0]:.2f} / {r['input_volumes_l'][1]:.2f} L | "
              f"non-linear {r['nonlinear_change_percent']:+6.2f}%  linear {r['linear_change_percent']:+6.2f}%", flush=True)
    if not rows:
        raise SystemExit(f"{dataset}: no sequence to blend (--only {' '.join(only or [])})")
    summary = {}
    for method in ("nonlinear", "linear"):
        change = np.abs([r[f"{method}_change_percent"] for r in rows])
        summary[method] = {"median_abs_percent": float(np.median(change)), "max_abs_percent": float(change.max()),
                           "within_target": int(np.sum(change <= TARGET_PERCENT)), "pairs": len(rows)}
    for method, label in (("nonlinear", "non-linear"), ("linear", "linear")):
        s = summary[method]
        print(f"{label}: |capped volume change| median {s['median_abs_percent']:.2f}%, max {s['max_abs_percent']:.2f}% "
              f"({s['within_target']} of {s['pairs']} pairs within {TARGET_PERCENT:g}%)")
    return {"dataset": str(dataset), "target_percent": TARGET_PERCENT, "pairs": rows, "summary": summary}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, help="a studio capture dataset (morphspace synth --preset studio)")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="these sequences only")
    parser.add_argument("--tiny", action="store_true", help="smoke run: studio-tiny's walk, generated; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/open_blends.json)")
    args = parse_arguments(parser, argv, TINY)
    out = args.out or Path("benchmarks/results/open_blends.json")
    if args.tiny:
        from server.cli import main as morphspace  # the generator's dataset writer

        with tempfile.TemporaryDirectory() as work:
            dataset = Path(work) / "studio-tiny"
            code = morphspace(["synth", "--preset", "studio-tiny", "--out", str(dataset), "--only", *args.only,
                               "--no-unstructured", "--no-previews", "--workers", "1"])
            if code:
                raise SystemExit(code)
            result = run(dataset, args.only)
    else:
        if args.dataset is None:
            parser.error("--dataset is required (or --tiny)")
        result = run(args.dataset, args.only)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
