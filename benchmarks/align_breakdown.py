"""Where an alignment's error lies, and whether the per-frame confidence finds the bad frames.

Runs ``engine.align.align_captures`` (the whole pipeline, one process) on a slice of a sequence
with ground truth and splits the correspondence error (``engine.align.breakdown``): per part of
the body (a studio body's skirt and sleeves), with each part's share of the error tail (the
vertex-frames over the overall 95th percentile) and the 95th percentile without it; per depth in
the tree; the worst frames; and the precision and recall of the confidence's flag against frames
whose mean error is truly over 2% and 3% of the model size. ``--picture`` draws every frame's
mean error per part, the flagged frames marked.

    .venv/bin/python benchmarks/align_breakdown.py /tmp/studio-full --sequence strikes --start 130 --frames 60 \\
        [--option patch_coupling=1.0] [--tail-relative 0.25] [--method sequential] [--picture /tmp/b.png] [--save /tmp/b.npz] \\
        [--out result.json]
    .venv/bin/python benchmarks/align_breakdown.py --tiny --out /tmp/align_breakdown.json

``--tiny`` (the test suite's smoke run) needs no dataset: 6 frames of the generator's 1,000-vertex
run at 15 fps, small alignment settings, one part; ``--out`` is required with it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

from _tiny import emit, parse_arguments
from align_speed import load_frames

TINY = {"start": 0, "frames": 6, "every": 2, "options": ["patches=8", "levels=2"]}


def parse_options(pairs):
    """``NAME=VALUE`` pairs -> AlignmentOptions (values as JSON: numbers, lists; tuples for lists)."""
    from dataclasses import fields, replace

    from engine.align import AlignmentOptions

    options = AlignmentOptions()
    known = {f.name for f in fields(AlignmentOptions)}
    changes = {}
    for pair in pairs or []:
        name, sep, value = pair.partition("=")
        if not sep or name not in known:
            raise SystemExit(f"--option {pair!r}: expected NAME=VALUE with NAME one of AlignmentOptions' fields")
        parsed = json.loads(value)
        changes[name] = tuple(parsed) if isinstance(parsed, list) else parsed
    if "levels" in changes:  # per-level settings follow the level count
        levels = int(changes["levels"])
        changes.setdefault("rounds", options.rounds[:levels])
        changes.setdefault("stiffness", options.stiffness[:levels])
    return replace(options, **changes), changes


def part_counts(dataset, tiny):
    """The template's parts (name -> vertex count) from a studio manifest, or None."""
    if tiny or dataset is None:
        return None
    parts = json.loads((Path(dataset) / "manifest.json").read_text()).get("body", {}).get("parts")
    return parts if isinstance(parts, dict) and parts else None


def picture(path, errors, root, labels, names, confidence, size, title):
    """Every frame's mean error per part (% of the model size); flagged frames marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    E = 100.0 * errors / size
    frames = np.arange(len(E))
    fig, ax = plt.subplots(figsize=(10, 4), dpi=100)
    ax.plot(frames, E.mean(axis=1), color="black", lw=2, label="all")
    for k, name in enumerate(names):
        mine = labels == k
        if mine.any():
            ax.plot(frames, E[:, mine].mean(axis=1), lw=1, label=name)
    flagged = np.flatnonzero(confidence < 0.5)
    ax.scatter(flagged, np.full(len(flagged), -0.15), marker="|", color="red", s=80, label="flagged")
    ax.axvline(root, color="grey", ls=":", lw=1)
    ax.axhline(3.0, color="red", ls="--", lw=0.8)
    ax.set_xlabel("frame of the slice (dotted: root)")
    ax.set_ylabel("mean error, % of model size")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, ncol=3, loc="upper left")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", nargs="?", help="a dataset with ground truth (morphspace synth)")
    parser.add_argument("--sequence", default="strikes")
    parser.add_argument("--start", type=int, default=130, help="first frame of the slice (default 130)")
    parser.add_argument("--frames", type=int, default=60, help="frames in the slice (default 60)")
    parser.add_argument("--every", type=int, default=1, help="take every N-th frame from --start (default 1: "
                        "a dense slice; 14 on a 25 fps take puts the frames 0.56 s apart)")
    parser.add_argument("--method", choices=("tree", "sequential"), default="tree")
    parser.add_argument("--root", type=int, default=None,
                        help="the root, a frame of the slice counted from 0 (default: the tree's choice)")
    parser.add_argument("--option", dest="options", action="append", default=None, metavar="NAME=VALUE",
                        help="an AlignmentOptions field (repeatable), e.g. patch_coupling=1.0")
    parser.add_argument("--picture", type=Path, help="draw the per-frame, per-part errors here (PNG)")
    parser.add_argument("--save", type=Path, help="write the per-frame figures here (.npz: mean error in %% of "
                        "the model size, residual, residual_max, distortion, distortion_tail, confidence, "
                        "repaired, depth, parent)")
    parser.add_argument("--tail-relative", type=float, default=None, metavar="SHARE",
                        help="the confidence's tail scale grows by this share of the capture's floor "
                             "(engine.align.repair.TAIL_RELATIVE, default 0)")
    parser.add_argument("--tiny", action="store_true", help="the test suite's smoke run (no dataset)")
    parser.add_argument("--out", type=Path, help="write the JSON here too")
    args = parse_arguments(parser, argv, TINY)
    if not args.tiny and args.dataset is None:
        parser.error("a dataset is needed (or --tiny)")
    if args.frames < 2:
        parser.error("--frames must be at least 2")
    if args.every < 1:
        parser.error("--every must be at least 1")
    import numpy as np

    from engine.align import align_captures, score_alignment
    from engine.align.breakdown import error_breakdown, part_labels

    options, changes = parse_options(args.options)
    if args.tail_relative is not None:
        import engine.align.repair

        engine.align.repair.TAIL_RELATIVE = args.tail_relative
        changes = {**changes, "tail_relative": args.tail_relative}
    frames, truth, faces, size = load_frames(args.dataset, args.sequence, args.start, args.frames, args.tiny,
                                           args.every)
    parts = part_counts(args.dataset, args.tiny)
    load_before = os.getloadavg()
    cpu_started = time.process_time()
    run = align_captures(frames, np.array([len(frames)]), method=args.method, workers=1, options=options,
                         root=args.root)
    cpu = time.process_time() - cpu_started
    aligned = run.aligned
    root = int(aligned.root)
    errors, _ = score_alignment(aligned.vertices, root, aligned.root_vertices, truth, faces, size)
    if parts:
        labels, names = part_labels(aligned.root_vertices, truth[root], faces, parts), list(parts)
    else:
        labels, names = np.zeros(len(aligned.root_vertices), dtype=np.int64), ["all"]
    breakdown = error_breakdown(errors, root, size, labels=labels, names=names, depth=run.tree.depth,
                                confidence=aligned.confidence)
    n = len(frames)
    record = {"dataset": "tiny" if args.tiny else str(args.dataset), "sequence": "run" if args.tiny else args.sequence,
              "start": args.start, "every": args.every, "frames": n, "method": args.method, "options": changes,
              "root": root, "root_trial": run.root_trial,
              "depth_mean": round(float(run.tree.depth.mean()), 2), "depth_max": int(run.tree.depth.max()),
              "cpu_seconds_per_frame": round(cpu / n, 3), "repaired": int(np.sum(aligned.repaired)),
              "colour_cues": bool(run.colour_cues), **breakdown,
              "load_average_before": [round(x, 2) for x in load_before],
              "load_average_after": [round(x, 2) for x in os.getloadavg()], "python": platform.python_version()}
    spacing = f", one in {args.every}" if args.every > 1 else ""
    print(f"{n} frames of {record['sequence']} from {args.start}{spacing}, {args.method}, root {root} (depth mean "
          f"{record['depth_mean']}, max {record['depth_max']}), options {changes or 'default'}: mean "
          f"{breakdown['mean_pct']:.2f}%, p95 {breakdown['p95_pct']:.2f}% of the model size; "
          f"{cpu / n:.2f} CPU s per frame", flush=True)
    for name, p in breakdown.get("per_part", {}).items():
        print(f"  {name:<10} {p['share_of_vertices']:>6.1%} of the vertices, mean {p['mean_pct']:.2f}%, p95 "
              f"{p['p95_pct']:.2f}%, {p['share_of_tail']:.1%} of the tail; p95 without it "
              + (f"{p['p95_without_pct']:.2f}%" if p["p95_without_pct"] is not None else "n/a"))
    for row in breakdown.get("per_depth", []):
        print(f"  depth {row['depths']:<6} {row['frames']:>4} frames: mean {row['mean_pct']:.2f}%, "
              f"p95 {row['p95_pct']:.2f}%")
    for key, c in breakdown["confidence"].items():
        print(f"  flag vs frames {key.replace('_', ' ')}: {c['flagged']} flagged, {c['bad']} bad, "
              f"{c['flagged_bad']} both (precision {c['precision']}, recall {c['recall']})")
    if args.picture is not None:
        last = args.start + (n - 1) * args.every
        title = (f"{record['sequence']} frames {args.start}-{last}{spacing}, {args.method}, "
                 f"options {changes or 'default'}: mean {breakdown['mean_pct']:.2f}%, p95 {breakdown['p95_pct']:.2f}%")
        picture(args.picture, errors, root, labels, names, aligned.confidence, size, title)
        print(f"wrote {args.picture}")
    if args.save is not None:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        np.savez(args.save, frame_mean_pct=100.0 * errors.mean(axis=1) / size, residual=aligned.residual,
                 residual_max=aligned.residual_max, distortion=aligned.distortion,
                 distortion_tail=aligned.distortion_tail, confidence=aligned.confidence, repaired=aligned.repaired,
                 depth=run.tree.depth, parent=run.tree.parent, root=root, labels=labels,
                 part_mean_pct=np.stack([100.0 * errors[:, labels == k].mean(axis=1) / size if np.any(labels == k)
                                         else np.zeros(n) for k in range(len(names))], axis=1))
        print(f"wrote {args.save}")
    emit(record, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
