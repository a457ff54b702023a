"""Measure alignment accuracy on a capture dataset with ground truth: tree vs sequential tracking.

Aligns the dataset's unstructured frames along the shape similarity tree and, for comparison,
by frame-to-frame tracking from the same root, then scores both against the generator's ground
truth: every root-mesh vertex is located on the true surface of the root frame and followed to
every other frame. Reports mean, 95th percentile and max correspondence error (mm and % of the
model size), the surface fit residual and seconds per frame, and writes DIR/results.json,
DIR/frames.csv (every frame's error, depth, parent, confidence and repair), a render of aligned frames textured with a pattern fixed on the root mesh (paper fig. 2,
DIR/aligned_pattern.png), DIR/similarity.png and DIR/tree.png. With --aligned, scores the output
of an earlier `morphspace align` instead. Frames and ground truth in centimetres or millimetres, or
with +Z up, are converted to metres with +Y up (--units, --up; detected by default); lengths are
reported in the data's units (mm for data in metres) and in % of the model size. Example:

    morphspace eval-align data/captures/demo --only walk jog jump_low_short --out eval-align
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from engine.align import AlignmentOptions, align_captures, pattern_sheet
from engine.align.similarity_tree import DEFAULT_TREE, TREE_KINDS
from engine.align.captures import ROOT_CHOICES
from engine.mesh_io.dataset import read_capture_manifest
from server.commands.align import COLOUR_MODES, Progress, check_job_ranges, check_root_given_once
from server.commands.align_inputs import check_root_early, convert_inputs, parse_root, read_inputs, resolve_inputs
from server.commands.eval_align_data import (load_aligned, model_size_in_metres, part_vertex_counts, picked_frames,
                                             read_truth, recorded_alignment, tree_depth, truth_conventions,
                                             truth_in_metres)
from server.commands.eval_align_score import FRAME_COLUMNS, PICTURES, csv_rows, kept_frame_labels, score_method
from server.units import (
    DISPLAY_PER_METRE,
    add_units_arguments,
    common_convention,
    count_text,
    display_unit,
    figure_text,
    say_conventions,
)


def add_arguments(parser):
    parser.add_argument("dataset", type=Path, help="capture dataset with ground truth (morphspace synth output)")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="only these sequences")
    parser.add_argument("--max-frames", type=int, metavar="N", help="use at most the first N frames of each sequence")
    parser.add_argument("--every", type=int, default=1, metavar="K",
                        help="use every K-th frame of each sequence from its first (default 1: all): frames far "
                             "apart in time, as when a few frames of a long take are re-meshed and scored")
    parser.add_argument("--aligned", type=Path, metavar="DIR", help="score this `morphspace align` output "
                        "instead of aligning here")
    parser.add_argument("--tree", choices=TREE_KINDS, default=DEFAULT_TREE,
                        help=f"the similarity tree: mst, paths or steps (see `morphspace align --help`; default {DEFAULT_TREE})")
    parser.add_argument("--no-sequential", action="store_true", help="skip the frame-to-frame baseline")
    parser.add_argument("--root", help="root frame as SEQUENCE:FRAME or a global index (default: the tree's)")
    parser.add_argument("--root-choice", choices=ROOT_CHOICES, default="auto",
                        help="without --root: auto (default), race, trial, apart or central (see `morphspace align "
                             "--help`)")
    parser.add_argument("--colors", nargs="?", const="on", default="auto", choices=("auto", "on", "off"),
                        help="vertex colours as local matching cues (see `morphspace align --help`; default auto)")
    parser.add_argument("--swing-limbs", action="store_true",
                        help="swing limbs onto what nothing covers (see `morphspace align --help`)")
    parser.add_argument("--reach-limbs", action=argparse.BooleanOptionalAction, default=True,
                        help="pull limbs onto what nothing covers (see `morphspace align --help`; default on)")
    parser.add_argument("--graft-limbs", action=argparse.BooleanOptionalAction, default=False,
                        help="graft flagged frames' limbs from other frames' poses in the repair (see "
                             "`morphspace align --help`; default off)")
    parser.add_argument("--out", type=Path, help="directory for results.json and the pictures "
                        "(default: <dataset>-align-eval next to the dataset)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="worker processes for the shape histograms, the dissimilarity matrix (from 3,000 "
                             "frames) and independent pieces of the tree (default: up to 2)")
    parser.add_argument("--repair-budget", type=float, default=0.25, metavar="B",
                        help="pairwise alignments per frame the repair of the tree's low-confidence frames may "
                             "spend (see `morphspace align --help`; default 0.25; 0 turns the repair off)")
    parser.add_argument("--retries", type=int, default=3,
                        help="other parents tried for a frame whose alignment scores poorly (see `morphspace align "
                             "--help`; default 3; 0: none)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--patches", type=int, default=30, help="patches at the coarsest level (default 30; as "
                        "`morphspace align`'s)")
    parser.add_argument("--levels", type=int, default=4, help="coarse-to-fine levels, patches doubling (default 4; "
                        "as `morphspace align`'s: 2 costs about half the CPU, docs/evaluation.md)")
    add_units_arguments(parser)


ALIGNING_OPTIONS = ("only", "max_frames", "every", "tree", "root", "root_choice", "colors", "swing_limbs",
                    "reach_limbs", "graft_limbs", "repair_budget", "retries", "seed", "patches", "levels")


def _refuse_alignment_options(args):
    """With --aligned nothing is aligned here: options that only steer an alignment are refused
    (they were accepted and did nothing; --root was even printed as given)."""
    defaults = argparse.ArgumentParser()
    add_arguments(defaults)
    given = [name for name in ALIGNING_OPTIONS if getattr(args, name) != defaults.get_default(name)]
    if given:
        shown = ", ".join("--" + name.replace("_", "-") if getattr(args, name) is not False else
                          "--no-" + name.replace("_", "-") for name in given)
        raise ValueError(f"{shown}: with --aligned the output of `morphspace align` is scored as it is, every sequence "
                         "it holds; these options pick or steer an alignment eval-align runs itself (give them to "
                         "`morphspace align`)")


def _kept_root(text, sequences, counts, picks):
    """The global index among the kept frames of ``--root``: SEQUENCE:FRAME in the files' own
    numbering (as frames.csv and `align` name frames), which must be a kept frame; an integer
    counts the kept frames, as the report's ``root`` does. None without ``--root``."""
    if text is None:
        return None
    kept = np.array([len(pick) for pick in picks], dtype=np.int64)
    if ":" not in text:
        return parse_root(text, sequences, kept)
    whole = parse_root(text, sequences, counts)
    k = int(np.searchsorted(np.cumsum(counts), whole, side="right"))
    frame = whole - int(np.sum(counts[:k]))
    at = np.flatnonzero(picks[k] == frame)
    if len(at) == 0:
        shown = ", ".join(str(int(f)) for f in picks[k][:6]) + (", ..." if len(picks[k]) > 6 else "")
        raise ValueError(f"--root {text}: frame {frame} of {sequences[k]['name']} is not among the frames kept "
                         f"({shown}; --every and --max-frames pick them)")
    return int(np.sum(kept[:k]) + at[0])


def run(args):
    dataset = args.dataset
    if not dataset.is_dir():
        raise FileNotFoundError(f"{dataset}: no such directory" if not dataset.exists() else
                                f"{dataset}: not a directory (a capture dataset is one)")
    manifest = read_capture_manifest(dataset)
    out = args.out or dataset.with_name(dataset.name + "-align-eval")
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} is a file, not a directory: name a directory for the report (--out)")
    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if args.max_frames is not None and args.max_frames < 2:
        raise ValueError(f"--max-frames must be >= 2, got {args.max_frames}")
    if args.every < 1:
        raise ValueError(f"--every must be >= 1, got {args.every}")
    check_job_ranges(args, ("patches", "levels", "retries", "repair_budget"))
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if args.aligned is not None:
        _refuse_alignment_options(args)
    check_root_given_once(args)
    progress = Progress()
    report = {"dataset": str(dataset)}
    recorded = None   # with --aligned: the align output's manifest's ``alignment`` record
    started = time.perf_counter()
    try:
        if args.aligned is not None:
            dataset_names = [s["name"] for s in manifest.get("sequences", [])]
            vertices, faces, root, root_vertices, names, lengths, extra = load_aligned(args.aligned, dataset_names)
            sequences = [{"name": n} for n in names]
            every_frame = [np.arange(n) for n in lengths]  # an align output keeps every frame
            labels, depth = kept_frame_labels(names, every_frame), tree_depth(extra, root, int(lengths.sum()))
            parts, template_faces = read_truth(dataset, sequences, every_frame, lengths)
            # the ground truth is in the files' units and axes; the aligned frames in metres, +Y up
            conventions = truth_conventions(dataset, manifest, args.aligned, names, parts, args.units, args.up)
            say_conventions(conventions, names, _say_line, what="ground truth")
            truth = truth_in_metres(parts, conventions)
            size = model_size_in_metres(manifest, conventions, truth)
            record, errors = score_method("aligned", vertices, root, root_vertices, truth, template_faces, size, lengths,
                                    names, residual=extra.get("residual"), residual_max=extra.get("residual_max"),
                                    seconds=extra.get("seconds"), retried=extra.get("retried"),
                                    cpu_seconds=extra.get("cpu_seconds"), confidence=extra.get("confidence"),
                                    repaired=extra.get("repaired"), pulled=extra.get("pulled"),
                                    part_counts=part_vertex_counts(manifest), depth=depth, frame_labels=labels)
            report.update(model_size_m=size, frames=int(lengths.sum()), sequences=names, root=int(root),
                          root_frame=labels[int(root)], aligned=record, **_units_report(names, conventions))
            recorded = recorded_alignment(args.aligned)
            reason = recorded.get("root_reason")
            if reason and isinstance(reason, str):  # why the alignment ran no trial or race, as it recorded
                report["root_reason"] = reason
            results = {"aligned": (vertices, faces, root_vertices)}
            frame_rows = csv_rows("aligned", errors, size, names, every_frame, depth=depth,
                                     parent=extra.get("parent"),
                                     confidence=extra.get("confidence"), repaired=extra.get("repaired"))
        else:
            sequences = resolve_inputs([dataset], args.only)
            check_root_early(args.root if args.root is not None and ":" in args.root else None, sequences)
            meshes, lengths = read_inputs(sequences, progress, say=_say_line)
            picks = picked_frames(lengths, args.every, args.max_frames)
            counts, starts = lengths, np.concatenate([[0], np.cumsum(lengths)[:-1]])
            meshes = [meshes[start + i] for start, pick in zip(starts, picks) for i in pick]
            lengths = np.array([len(pick) for pick in picks], dtype=np.int64)
            names = [s["name"] for s in sequences]
            meshes, conventions = convert_inputs(meshes, sequences, lengths, args.units, args.up, say=_say_line)
            parts, template_faces = read_truth(dataset, sequences, picks, counts)
            truth = truth_in_metres(parts, conventions)  # in the same units and axes as the frames
            size = model_size_in_metres(manifest, conventions, truth)
            root = _kept_root(args.root, sequences, counts, picks)
            options = AlignmentOptions(patches=args.patches, levels=args.levels, swing_limbs=args.swing_limbs,
                                       reach_limbs=args.reach_limbs, graft_limbs=args.graft_limbs)
            report.update(model_size_m=size, frames=int(lengths.sum()), sequences=names, every=args.every,
                          **_units_report(names, conventions))
            tree_run = align_captures(meshes, lengths, method="tree", tree_kind=args.tree, root=root,
                                      root_choice=args.root_choice, options=options,
                                      workers=args.workers, use_colors=COLOUR_MODES[args.colors], seed=args.seed,
                                      retries=args.retries, repair_budget=args.repair_budget, progress=progress)
            root = tree_run.aligned.root
            report["root"] = int(root)
            labels = kept_frame_labels(names, picks)
            report["root_frame"] = labels[int(root)]
            report["root_trial"] = tree_run.root_trial
            report["root_reason"] = tree_run.root_reason
            report["colour_cues"] = bool(tree_run.colour_cues)
            report["similarity_seconds"] = round(tree_run.timings["similarity"], 3)
            report["tree_seconds"] = round(tree_run.timings["tree"], 4)
            for stage in ("trial", "race"):  # choosing the root by trying, then racing, candidates
                if stage in tree_run.timings:
                    report[f"root_{stage}_seconds"] = round(tree_run.timings[stage], 2)
            # wall seconds of every stage: similarity, tree, trial, race, tetrahedralize, align, repair
            report["stage_seconds"] = {stage: round(float(t), 2) for stage, t in tree_run.timings.items()}
            report["tree"] = {"kind": args.tree, "retries": args.retries, "repair_budget": args.repair_budget,
                              "swing_limbs": args.swing_limbs, "reach_limbs": args.reach_limbs,
                              "graft_limbs": args.graft_limbs,
                              "depth_max": int(tree_run.tree.depth.max()),
                              "depth_mean": round(float(tree_run.tree.depth.mean()), 2),
                              "components_reconnected": int(tree_run.tree.components)}
            runs = {"tree": tree_run}
            if not args.no_sequential:
                runs["sequential"] = align_captures(meshes, lengths, method="sequential", root=root, options=options,
                                                    use_colors=COLOUR_MODES[args.colors], seed=args.seed,
                                                    similarity=tree_run.similarity, tets=tree_run.tets,
                                                    progress=lambda stage, done, total: progress(
                                                        "align sequential" if stage == "align" else stage,
                                                        done, total))
            results, frame_rows = {}, []
            for method, result in runs.items():
                a = result.aligned
                record, errors = score_method(method, a.vertices, root, a.root_vertices, truth, template_faces, size,
                                        lengths, names, residual=a.residual, residual_max=a.residual_max,
                                        seconds=a.seconds, retried=a.retried, cpu_seconds=a.cpu_seconds,
                                        confidence=a.confidence, repaired=a.repaired, pulled=a.pulled,
                                        part_counts=part_vertex_counts(manifest), depth=result.tree.depth,
                                        frame_labels=labels)
                report[method] = {**report.get(method, {}), **record}
                if method == "tree":  # what the repair spent, and which of its phases stopped paying
                    report[method].update(repair_alignments=int(a.repair_spent),
                                          repair_stopped=list(a.repair_stopped or []))
                results[method] = (a.vertices, a.faces, a.root_vertices)
                frame_rows += csv_rows(method, errors, size, names, picks, depth=result.tree.depth, parent=a.parent,
                                          confidence=a.confidence, repaired=a.repaired)
            if "sequential" in report:
                report["sequential_over_tree_mean"] = round(report["sequential"]["mean_mm"]
                                                            / max(report["tree"]["mean_mm"], 1e-9), 2)
    finally:
        progress.close()
    report["seconds"] = round(time.perf_counter() - started, 1)
    out.mkdir(parents=True, exist_ok=True)
    for name in PICTURES:   # an earlier run's pictures are of another alignment: only this run's are left
        (out / name).unlink(missing_ok=True)
    from PIL import Image

    method = "tree" if "tree" in results else "aligned"
    vertices, faces, _ = results[method]
    Image.fromarray(pattern_sheet(vertices, faces, root, lengths, names)).save(out / "aligned_pattern.png")
    if "sequential" in results:  # the same frames, tracked frame to frame, for comparison
        vertices, faces, _ = results["sequential"]
        title = "sequential tracking: the same frames, pattern fixed on the root mesh"
        Image.fromarray(pattern_sheet(vertices, faces, root, lengths, names, title=title)).save(
            out / "aligned_pattern_sequential.png")
    if args.aligned is None:
        from engine.align import similarity_image, tree_image

        Image.fromarray(similarity_image(runs["tree"].similarity.dissimilarity, lengths, names)).save(
            out / "similarity.png")
        Image.fromarray(tree_image(runs["tree"].tree, lengths, names)).save(out / "tree.png")
    (out / "results.json").write_text(json.dumps(report, indent=2) + "\n")
    with open(out / "frames.csv", "w", newline="") as stream:   # every frame's figures, for plots and digging
        writer = csv.writer(stream)
        writer.writerow(FRAME_COLUMNS)
        writer.writerows(frame_rows)
    if args.json:
        print(json.dumps(report))
    else:
        _print_report(report, out, args, recorded)
    return 0


def _say_line(line):
    tqdm.write(f"morphspace eval-align: {line}", file=sys.stderr)


def _units_report(names, conventions):
    """Report entries: each sequence's input units and up axis, and the unit lengths are shown in."""
    return {"input": {name: c.to_metadata() for name, c in zip(names, conventions)},
            "display_unit": display_unit(common_convention(conventions))}


def _root_line(report, args, recorded=None):
    """The printed report's second line: the root frame and what chose it, as `align` says it.

    With ``--aligned`` (``recorded``: the align output's manifest ``alignment`` record) the root is
    the alignment's, and the trial and race, or why none ran, are what it recorded (its
    ``root_trial``, ``root_reason`` and ``options.root_choice``)."""
    if recorded is None:
        trial, given, choice = report.get("root_trial"), args.root is not None, args.root_choice
    else:
        trial, options = recorded.get("root_trial"), recorded.get("options")
        trial = trial if isinstance(trial, dict) else None
        given, choice = False, options.get("root_choice") if isinstance(options, dict) else None
    if trial:
        said = (f"tried: candidates {trial['candidates']}, mean badness {trial['mean']}"
                + (f"; raced: {trial['race']['finalists']}, mean confidence {trial['race']['confidence']}"
                   if trial.get("race") else "")
                + (f"; {report['root_reason']}" if report.get("root_reason") else ""))
    else:   # said, as align says it
        said = ("given: --root" if given else report.get("root_reason")
                or (f"--root-choice {choice}" if choice in ("apart", "central") else ""))
    if recorded is not None:
        said = f"align's root, as {args.aligned / 'manifest.json'} records" + (f": {said}" if said else "")
    return f"root frame {report['root']}, {report['root_frame']}" + (f" ({said})" if said else "")


def _print_report(report, out, args, recorded=None):
    unit = report["display_unit"]
    scale = DISPLAY_PER_METRE[unit] / 1000.0  # from the records' mm
    conventions = {}  # "units, up" -> the sequences in it
    for name, r in report["input"].items():
        conventions.setdefault(f"{r['units']}, {r['up']} up", []).append(name)
    inputs = sorted(conventions) if len(conventions) == 1 else \
        [f"{key} ({', '.join(conventions[key])})" for key in sorted(conventions)]
    print(f"{count_text(report['frames'], 'frame')} of {count_text(len(report['sequences']), 'sequence')}, model size "
          f"{report['model_size_m']:.3f} m; input in {' / '.join(inputs)}; lengths in {unit}")
    print(_root_line(report, args, recorded))
    if "similarity_seconds" in report:
        print(f"similarity {report['similarity_seconds']:.1f} s, tree {report['tree_seconds']:.3f} s "
              f"(depth max {report['tree']['depth_max']}, mean {report['tree']['depth_mean']})"
              + "".join(f", root {stage} {report[f'root_{stage}_seconds']:.1f} s" for stage in ("trial", "race")
                        if f"root_{stage}_seconds" in report))
    header = f"{'method':<12}{'mean %':>8}{'p95 %':>8}{'max %':>8}{'mean ' + unit:>9}{'p95 ' + unit:>8}" \
             f"{'max ' + unit:>8}{'resid ' + unit:>10}{'s/frame':>9}{'CPU s/fr':>9}"
    print(header)
    for method in ("tree", "sequential", "aligned"):
        r = report.get(method)
        if not r:
            continue
        # (figures under 1 keep 3 significant figures: none reads 0.00 unless it is 0)
        print(f"{method:<12}{figure_text(r['mean_pct']):>8}{figure_text(r['p95_pct']):>8}"
              f"{figure_text(r['max_pct'], 1):>8}{figure_text(scale * r['mean_mm'], 1):>9}"
              f"{figure_text(scale * r['p95_mm'], 1):>8}{figure_text(scale * r['max_mm'], 0):>8}"
              f"{figure_text(scale * r.get('residual_mean_mm', float('nan'))):>10}"
              f"{r.get('seconds_per_frame', float('nan')):>9.2f}{r.get('cpu_seconds_per_frame', float('nan')):>9.2f}")
    for method in ("tree", "sequential", "aligned"):
        parts = report.get(method, {}).get("per_part")
        if parts:
            print(f"{method} per part: " + ", ".join(f"{name} {figure_text(p['mean_pct'])}% "
                                                     f"(p95 {figure_text(p['p95_pct'])}%)"
                                                     for name, p in parts.items()))
    if "sequential_over_tree_mean" in report:
        print(f"sequential / tree mean error: {report['sequential_over_tree_mean']:.2f}x")
    pictures = [name for name in PICTURES if (out / name).is_file()]
    written = [out / "results.json", out / "frames.csv"] + [out / name for name in pictures]
    print(f"wrote {', '.join(str(p) for p in written[:-1])} and {written[-1]}")
