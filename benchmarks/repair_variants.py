"""What the repair of low-confidence frames buys, for what it costs: one alignment, several repairs.

Aligns a slice of a sequence with ground truth once along the tree without the repair
(``engine.align.align_captures(repair=False)``: the race's root, colour cues as by default), then
runs ``engine.align.repair_alignment`` on copies of that alignment, one per variant
``STRATEGY@BUDGET`` or ``STRATEGY@BUDGET:YIELD`` (``root_first`` or ``together``; the budget in
pairwise alignments per frame; YIELD the ``min_yield`` below which a phase stops, by default
``engine.align.repair.MIN_YIELD``, 0 never),
and scores each against the truth: mean and 95th percentile of the correspondence error, frames
over 3% of the model size, frames repaired and still flagged, the alignments spent and the wall
seconds. Every variant starts from the same alignment, so the differences are the repair's alone.

    .venv/bin/python benchmarks/repair_variants.py /tmp/studio-full --sequence dance --every 2 \\
        --variants none,together@0.5,root_first@0.1,root_first@0.25,root_first@0.5 --workers 2 --out result.json
    .venv/bin/python benchmarks/repair_variants.py /tmp/studio-full --sequence all --every 3 \
        --variants none,root_first@0.25:0,root_first@0.25 --workers 2 --out result.json
    .venv/bin/python benchmarks/repair_variants.py --tiny --out /tmp/repair_variants.json

``--sequence`` names one sequence, several (``walk,dance``) or ``all`` of the dataset's; their
slices (``--start``, ``--frames``, ``--every``, each sequence alike) are aligned together.

``--tiny`` (the test suite's smoke run) needs no dataset: 8 frames of the generator's 1,000-vertex
run at 15 fps, small alignment settings, one worker; ``--out`` is required with it.
"""

from __future__ import annotations

import argparse
import copy
import os
import platform
import sys
import time
from pathlib import Path

from _tiny import emit, parse_arguments
from align_breakdown import parse_options
from align_speed import load_frames

TINY = {"start": 0, "frames": 8, "every": 1, "options": ["patches=8", "levels=2"], "workers": 1,
        "variants": "none,together@0.5,root_first@0.25,root_first@0.25:0,root_first@0"}


def parse_variants(text):
    """"none,root_first@0.25,root_first@0.25:0,..." -> [(label, strategy or None, budget, min_yield or None)]."""
    variants = []
    for label in [v.strip() for v in text.split(",") if v.strip()]:
        if label == "none":
            variants.append((label, None, 0.0, None))
            continue
        strategy, sep, rest = label.partition("@")
        if strategy not in ("root_first", "together") or not sep:
            raise SystemExit(f"--variants {label!r}: expected none or STRATEGY@BUDGET[:YIELD], STRATEGY root_first "
                             "or together")
        budget, colon, least = rest.partition(":")
        variants.append((label, strategy, non_negative(label, "budget", budget),
                         non_negative(label, "yield", least) if colon else None))
    if not variants:
        raise SystemExit("--variants: name at least one")
    return variants


def non_negative(label, name, text):
    """``text`` of variant ``label`` as a number >= 0, else exit naming the variant and the ``name``."""
    try:
        value = float(text)
    except ValueError:
        raise SystemExit(f"--variants {label!r}: the {name} {text!r} is not a number") from None
    if not value >= 0:
        raise SystemExit(f"--variants {label!r}: the {name} must be >= 0")
    return value


def sequence_names(dataset, text):
    """The sequences ``--sequence`` names: one, several (comma-separated) or ``all`` of the dataset's
    (its manifest's order)."""
    from engine.mesh_io.dataset import read_capture_manifest

    known = [s["name"] for s in read_capture_manifest(dataset)["sequences"]]
    names = known if text == "all" else [s.strip() for s in text.split(",") if s.strip()]
    missing = [s for s in names if s not in known]
    if not names or missing:
        raise SystemExit(f"--sequence {text!r}: no such sequence in {dataset}: {', '.join(missing) or '(none named)'}")
    return names


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", nargs="?", help="a dataset with ground truth (morphspace synth)")
    parser.add_argument("--sequence", default="dance", help="a sequence, several (walk,dance) or all (default dance)")
    parser.add_argument("--start", type=int, default=0, help="first frame of the slice (default 0)")
    parser.add_argument("--frames", type=int, default=None, help="frames in the slice (default: to the end)")
    parser.add_argument("--every", type=int, default=2, help="take every N-th frame from --start (default 2)")
    parser.add_argument("--variants", default="none,together@0.5,root_first@0.25",
                        help="comma-separated: none, or STRATEGY@BUDGET (default none,together@0.5,root_first@0.25)")
    parser.add_argument("--retries", type=int, default=3, help="trusted frames tried besides the root (default 3)")
    parser.add_argument("--option", dest="options", action="append", default=None, metavar="NAME=VALUE",
                        help="an AlignmentOptions field (repeatable)")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="processes for the alignment and the repairs (default up to 2)")
    parser.add_argument("--tiny", action="store_true", help="the test suite's smoke run (no dataset)")
    parser.add_argument("--out", type=Path, help="write the JSON here too")
    args = parse_arguments(parser, argv, TINY)
    if not args.tiny and args.dataset is None:
        parser.error("a dataset is needed (or --tiny)")
    if args.every < 1:
        parser.error("--every must be at least 1")
    variants = parse_variants(args.variants)
    import contextlib

    import numpy as np

    from engine.align import align_captures, repair_alignment, score_alignment
    from engine.align.captures import _outward
    from engine.align.repair import MIN_YIELD, TRUSTED
    from engine.align.root_trial import root_setup
    from engine.tasks import ProcessRunner

    options, changes = parse_options(args.options)
    count = args.frames if args.frames is not None else 1 << 30
    names = ["run"] if args.tiny else sequence_names(args.dataset, args.sequence)
    frames, truth, lengths = [], [], []
    for name in names:
        got, got_truth, faces, size = load_frames(args.dataset, name, args.start, count, args.tiny, args.every)
        frames += got
        truth.append(got_truth)
        lengths.append(len(got))
    truth = np.concatenate(truth)
    n = len(frames)
    load_before = os.getloadavg()
    started = time.perf_counter()
    run = align_captures(frames, np.array(lengths), workers=args.workers, options=options, retries=args.retries,
                         repair=False)
    align_seconds = time.perf_counter() - started
    base = run.aligned
    root = int(base.root)
    # the repair's aligner and frames, as align_captures set them up (faces wound outward)
    meshes, _ = _outward(frames)
    colours = all(getattr(m, "colors", None) is not None for m in meshes)
    aligner, _, _, _ = root_setup(meshes[root], options, "auto", colours, 0, tets=run.tets)

    def score(aligned):
        errors, summary = score_alignment(aligned.vertices, root, aligned.root_vertices, truth, faces, size)
        frame = 100.0 * errors.mean(axis=1) / size
        frame[root] = 0.0
        return summary, frame

    rows = []
    with ProcessRunner(args.workers) if args.workers > 1 else contextlib.nullcontext() as runner:
        for label, strategy, budget, least in variants:
            aligned = copy.deepcopy(base)
            least = None if strategy is None else MIN_YIELD if least is None else least
            started = time.perf_counter()
            if strategy is not None:
                repair_alignment(aligner, meshes, aligned, dissimilarity=run.similarity.dissimilarity,
                                 yaw=run.similarity.yaw, candidates=args.retries, budget=budget, runner=runner,
                                 strategy=strategy, min_yield=least)
            else:  # the confidence alone (a zero budget repairs nothing)
                repair_alignment(aligner, meshes, aligned, budget=0.0)
            seconds = time.perf_counter() - started
            summary, frame = score(aligned)
            flagged = aligned.confidence < TRUSTED
            row = {"variant": label, "strategy": strategy, "budget": budget,
                   "min_yield": least,
                   "stopped": list(aligned.repair_stopped or []),
                   "mean_pct": round(float(summary["mean_pct"]), 4), "p95_pct": round(float(summary["p95_pct"]), 4),
                   "frames_over_3pct": int(np.sum(frame > 3.0)),
                   "frames_over_3pct_flagged": int(np.sum((frame > 3.0) & flagged)),
                   "repaired": int(np.sum(aligned.repaired)), "flagged": int(np.sum(flagged)),
                   "alignments": int(aligned.repair_spent), "seconds": round(seconds, 2)}
            rows.append(row)
            print(f"{label:<18} mean {row['mean_pct']:.3f}%  p95 {row['p95_pct']:.3f}%  over 3% {row['frames_over_3pct']:>4}"
                  f" (flagged {row['frames_over_3pct_flagged']})  repaired {row['repaired']:>4}  flagged {row['flagged']:>4}"
                  f"  alignments {row['alignments']:>5}  {seconds:.1f} s"
                  + (f"  stopped: {', '.join(row['stopped'])}" if row["stopped"] else ""), flush=True)
    record = {"dataset": "tiny" if args.tiny else str(args.dataset), "sequence": "run" if args.tiny else args.sequence,
              "sequences": names, "start": args.start, "every": args.every, "frames": n, "root": root,
              "options": changes,
              "workers": args.workers, "retries": args.retries, "align_seconds": round(align_seconds, 2),
              "variants": rows, "load_average_before": [round(x, 2) for x in load_before],
              "load_average_after": [round(x, 2) for x in os.getloadavg()], "python": platform.python_version()}
    print(f"{n} frames of {', '.join(names)} from {args.start}, one in {args.every}, root {root}, aligned once in "
          f"{align_seconds:.0f} s ({args.workers} workers); each variant repairs a copy of that alignment")
    emit(record, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
