"""Does the root trial pick a good root? Its badness against each candidate's true error.

On a slice of a sequence with ground truth, takes the candidate roots (the trial's own, as
``engine.align.align_captures`` would, or ``--roots``), runs the trial
(``engine.align.root_trial.try_roots``: every candidate aligns the same probe frames straight
from itself), then, with ``--truth``, the whole alignment rooted at each candidate, scored against
the ground truth. Prints each candidate's mean probe badness and true mean and 95th-percentile
error, the rank correlation between the two, and which root the trial, the geodesic spread
(``apart``) and the truth would take. With ``--truth`` it also reads each whole alignment's mean
confidence (what the race, ``root_choice="race"``, compares between the trial's two best
candidates: ``engine.align.root_race``), its rank correlation with the true error, and which
finalist the race would take. ``--picture`` plots badness against true error.

    .venv/bin/python benchmarks/root_trial.py /tmp/studio-strikes --sequence strikes --start 0 --frames 43 \\
        --every 9 [--roots 42,2,3,1,0,41,7,12] [--truth] [--picture /tmp/trial.png] [--out result.json]
    .venv/bin/python benchmarks/root_trial.py --tiny --out /tmp/root_trial.json

``--tiny`` (the test suite's smoke run) needs no dataset: 8 frames of the generator's
1,000-vertex run at 15 fps, two candidates, two probes, small alignment settings, with
``--truth``; ``--out`` is required with it.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

from _tiny import emit, parse_arguments
from align_breakdown import parse_options
from align_speed import load_frames

TINY = {"start": 0, "frames": 8, "every": 1, "roots": "0,4", "probes": 2, "truth": True,
        "options": ["patches=8", "levels=2"]}


def ranks(values):
    """Ranks 0..n-1 of ``values`` (ties in order)."""
    import numpy as np

    order = np.argsort(np.asarray(values, dtype=np.float64), kind="stable")
    out = np.empty(len(order))
    out[order] = np.arange(len(order))
    return out


def rank_correlation(values, truth):
    """Spearman's rank correlation of ``values`` and ``truth`` (None for fewer than 2)."""
    import numpy as np

    k = len(values)
    if k < 2:
        return None
    d = ranks(values) - ranks(truth)
    return round(1.0 - 6.0 * float(np.sum(d ** 2)) / (k * (k * k - 1)), 3)


def picture(path, rows, title):
    """Badness of the trial's probes against true error, and beside it (when measured) the whole
    alignments' mean confidence against true error (what the race compares)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("badness_mean", "mean badness of the candidate's probes (the trial)")]
    if all("confidence_mean" in r for r in rows):
        panels.append(("confidence_mean", "mean confidence of the whole alignment (the race)"))
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4.5), squeeze=False)
    for ax, (key, label) in zip(axes[0], panels):
        x = [r[key] for r in rows]
        y = [r["true_mean_pct"] for r in rows]
        ax.scatter(x, y, color="tab:blue")
        for r in rows:
            text = f"{r['frame']}" + (" trial" if r["trial_choice"] else "") + (" apart" if r["spread_choice"] else "")
            ax.annotate(text, (r[key], r["true_mean_pct"]), textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.set_xlabel(label)
        ax.set_ylabel("true mean error of the whole alignment (% of model size)")
        ax.grid(alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", nargs="?", help="a dataset with ground truth (morphspace synth)")
    parser.add_argument("--sequence", default="strikes")
    parser.add_argument("--start", type=int, default=0, help="first frame of the slice (default 0)")
    parser.add_argument("--frames", type=int, default=43, help="frames in the slice (default 43)")
    parser.add_argument("--every", type=int, default=9, help="take every N-th frame from --start (default 9)")
    parser.add_argument("--roots", help="candidate roots, frames of the slice counted from 0, comma separated "
                        "(default: the trial's own candidates)")
    parser.add_argument("--probes", type=int, default=None, help="probe frames (default: the trial's, 6)")
    parser.add_argument("--truth", action="store_true", help="also align the whole slice from every candidate and "
                        "score it against the ground truth (one whole alignment per candidate)")
    parser.add_argument("--option", dest="options", action="append", default=None, metavar="NAME=VALUE",
                        help="an AlignmentOptions field (repeatable), e.g. levels=3")
    parser.add_argument("--picture", type=Path, help="with --truth: badness against true error (PNG)")
    parser.add_argument("--tiny", action="store_true", help="the test suite's smoke run (no dataset)")
    parser.add_argument("--out", type=Path, help="write the JSON here too")
    args = parse_arguments(parser, argv, TINY)
    if not args.tiny and args.dataset is None:
        parser.error("a dataset is needed (or --tiny)")
    import numpy as np

    from engine.align import align_captures, score_alignment
    from engine.align.captures import _apart, _outward
    from engine.align.root_choice import ROOT_SLACK
    from engine.align.root_race import finalists, race_score
    from engine.align.root_trial import TRIAL_PROBES, trial_candidates, trial_probes, try_roots
    from engine.align.similarity import shape_dissimilarity
    from engine.align.similarity_tree import similarity_tree

    options, changes = parse_options(args.options)
    frames, truth, faces, size = load_frames(args.dataset, args.sequence, args.start, args.frames, args.tiny,
                                           args.every)
    n = len(frames)
    load_before = os.getloadavg()
    oriented, _ = _outward(frames)
    lengths = np.array([n])
    similarity = shape_dissimilarity(oriented, lengths, window=2, workers=1)
    chooser = _apart(oriented, None)
    spread_choice = similarity_tree(similarity.dissimilarity, choose_root=chooser).root
    if args.roots:
        candidates = [int(x) for x in args.roots.split(",")]
        if any(not 0 <= c < n for c in candidates) or len(set(candidates)) != len(candidates):
            parser.error(f"--roots must be distinct frames of the slice, 0..{n - 1}")
    else:
        candidates = trial_candidates(similarity.dissimilarity, chooser.centrality, spread_choice, slack=ROOT_SLACK,
                                      allowed=chooser.report["allowed"])
    probes = trial_probes(n, candidates, args.probes or TRIAL_PROBES)
    colours = all(getattr(m, "colors", None) is not None for m in oriented)
    cpu_started = time.process_time()
    chosen, trial, _ = try_roots(oriented, candidates, probes, similarity.yaw, options=options, use_colors="auto",
                                 colours=colours)
    trial_cpu = time.process_time() - cpu_started
    rows = []
    for c, mean in zip(candidates, trial["mean"]):
        row = {"frame": c, "badness_mean": mean, "trial_choice": c == chosen, "spread_choice": c == spread_choice}
        if args.truth:
            run = align_captures(frames, lengths, root=c, workers=1, options=options)
            errors, _ = score_alignment(run.aligned.vertices, c, run.aligned.root_vertices, truth, faces, size)
            row["true_mean_pct"] = round(float(100.0 * errors.mean() / size), 3)
            row["true_p95_pct"] = round(float(100.0 * np.percentile(errors, 95) / size), 3)
            row["confidence_mean"] = round(race_score(run.aligned.confidence, c), 4)
        rows.append(row)
        print(f"  root {c:>4}: trial badness {mean:.3f}"
              + (f", true mean {row['true_mean_pct']:.2f}%, p95 {row['true_p95_pct']:.2f}%, whole alignment's mean "
                 f"confidence {row['confidence_mean']:.3f}" if args.truth else "")
              + (" (trial's choice)" if row["trial_choice"] else "") + (" (spread's choice)" if row["spread_choice"] else ""),
              flush=True)
    record = {"dataset": "tiny" if args.tiny else str(args.dataset), "sequence": "run" if args.tiny else args.sequence,
              "start": args.start, "every": args.every, "frames": n, "options": changes, "candidates": candidates,
              "probes": probes, "trial_choice": chosen, "finalists": finalists(trial), "spread_choice": int(spread_choice),
              "trial_cpu_seconds": round(trial_cpu, 2), "badness": trial["badness"], "rows": rows,
              "load_average_before": [round(x, 2) for x in load_before],
              "load_average_after": [round(x, 2) for x in os.getloadavg()], "python": platform.python_version()}
    print(f"{n} frames of {record['sequence']} from {args.start}, one in {args.every}: {len(candidates)} candidates x "
          f"{len(probes)} probes in {trial_cpu:.1f} CPU s; the trial takes {chosen}, the spread {spread_choice}")
    if args.truth:
        true = [r["true_mean_pct"] for r in rows]
        best = candidates[int(np.argmin(true))]
        record["rank_correlation"] = rank_correlation([r["badness_mean"] for r in rows], true)
        confidence = {r["frame"]: r["confidence_mean"] for r in rows}
        record["confidence_rank_correlation"] = rank_correlation([-c for c in confidence.values()], true)
        race = max(record["finalists"], key=lambda c: confidence[c])  # the first of equals, as the race
        record["race_choice"] = int(race)
        record["race_choice_true_mean_pct"] = true[candidates.index(race)]
        record["truth_choice"] = int(best)
        record["trial_choice_true_mean_pct"] = true[candidates.index(chosen)]
        record["spread_choice_true_mean_pct"] = true[candidates.index(spread_choice)] if spread_choice in candidates else None
        print(f"  truly best {best} ({min(true):.2f}%); the trial's {chosen}: {record['trial_choice_true_mean_pct']:.2f}%; "
              f"rank correlation of badness and true error {record['rank_correlation']}")
        print(f"  the race between {record['finalists']} takes {race} ({record['race_choice_true_mean_pct']:.2f}%); "
              f"rank correlation of the whole alignments' confidence and true error "
              f"{record['confidence_rank_correlation']}")
        if args.picture is not None:
            picture(args.picture, rows, f"{record['sequence']} from {args.start}, one in {args.every} ({n} frames): "
                                        f"rank correlation {record['rank_correlation']} (badness), "
                                        f"{record['confidence_rank_correlation']} (confidence)")
            print(f"wrote {args.picture}")
    emit(record, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
