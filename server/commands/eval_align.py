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
import zipfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

from engine.align import AlignmentOptions, align_captures, error_summary, pattern_sheet, score_alignment
from engine.align.breakdown import error_breakdown
from engine.align.evaluation import part_errors, part_labels
from engine.align.similarity_tree import DEFAULT_TREE, TREE_KINDS, rooted_tree
from engine.align.captures import ROOT_CHOICES
from engine.align.repair import TRUSTED
from engine.mesh_io import read_mesh, read_sequence
from engine.mesh_io.dataset import load_capture_truth, read_capture_manifest
from engine.mesh_io.errors import MeshFormatError
from engine.mesh_io.units import UNITS_PER_METRE, resolve_convention, to_metres_y_up
from engine.surface import model_size
from server.commands.align import (COLOUR_MODES, Progress, check_job_ranges, check_root_early, check_root_given_once,
                                   convert_inputs, parse_root, read_inputs, resolve_inputs)
from server.units import (
    DISPLAY_PER_METRE,
    add_units_arguments,
    common_convention,
    count_text,
    declared_convention,
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


def _truth(dataset, sequences, picks, counts):
    """Template positions of each sequence's frames (a list, in the files' units and axes) and
    the template faces. ``picks``: per sequence, the indices of its frames that were kept
    (``_picked_frames``); ``counts``: its frames in all, which its ground truth must match (a
    frame missing in the middle would pair every later frame with the wrong truth)."""
    template = read_mesh(dataset / "template" / "body.obj")
    parts = []
    for s, pick, count in zip(sequences, picks, counts):
        truth = load_capture_truth(dataset, s["name"])
        where = f"{dataset}/sequences/{s['name']}/truth.npz"
        positions = truth.get("template_positions")
        if positions is None:
            raise MeshFormatError(f"{where}: no template_positions (the true place of every template vertex in "
                                  "every frame): not a morphspace synth ground truth")
        if positions.ndim != 3 or positions.shape[1:] != (len(template.vertices), 3):
            raise MeshFormatError(f"{where}: template_positions has shape {positions.shape}; the template "
                                  f"(template/body.obj) has {len(template.vertices)} vertices")
        if not np.isfinite(positions).all():
            raise MeshFormatError(f"{where}: template_positions holds NaN or infinite values")
        if len(positions) != count:
            raise MeshFormatError(f"{dataset}/sequences/{s['name']}/truth.npz: ground truth for {len(positions)} "
                                  f"frames, the sequence has {count}: frames and truth must match one to one")
        parts.append(np.asarray(positions[pick], dtype=np.float64))
    return parts, template.faces


def _picked_frames(lengths, every, max_frames):
    """Per sequence, the frames kept: every ``every``-th from the first, at most ``max_frames``."""
    return [np.arange(0, n, every)[:max_frames] for n in lengths]


def _truth_in_metres(parts, conventions):
    """The ground truth of all frames (concatenated) in metres, +Y up."""
    return np.concatenate([to_metres_y_up(P, c.units, c.up) for P, c in zip(parts, conventions)])


def _score(method, aligned_vertices, root, root_vertices, truth, faces, size, lengths, names, *, residual=None,
           residual_max=None, seconds=None, retried=None, cpu_seconds=None, confidence=None, repaired=None,
           part_counts=None, depth=None, pulled=None, frame_labels=None):
    errors, summary = score_alignment(aligned_vertices, root, root_vertices, truth, faces, size)
    frames = len(aligned_vertices)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    per_sequence = {}
    for name, start, n in zip(names, starts, lengths):
        # all frames but the root, as the summary (a sequence of the root alone: the root)
        picked = [f for f in range(start, start + n) if f != root] or [root]
        per_sequence[name] = {k: round(v, 3) for k, v in error_summary(errors[picked], size).items()}
    record = {"method": method, "frames": int(frames), **{k: round(v, 4) for k, v in summary.items()},
              "per_sequence": per_sequence}
    if part_counts:  # a studio body: the body and each garment apart
        record["per_part"] = part_errors(errors, root, root_vertices, truth, faces, part_counts, size)
    if residual is not None:
        record["residual_mean_mm"] = round(1000 * float(np.mean(residual)), 3)
        record["residual_max_mm"] = round(1000 * float(np.max(residual_max)), 2)
        record["residual_mean_pct"] = round(100 * float(np.mean(residual)) / size, 4)
        record["residual_max_pct"] = round(100 * float(np.max(residual_max)) / size, 3)
    if seconds is not None:
        record["seconds_per_frame"] = round(float(np.sum(seconds)) / max(frames - 1, 1), 3)
    if cpu_seconds is not None:
        record["cpu_seconds_per_frame"] = round(float(np.sum(cpu_seconds)) / max(frames - 1, 1), 3)
    if retried is not None:
        record["retried_frames"] = int(np.sum(retried))
    if pulled is not None:  # frames whose kept alignment pulled a limb onto what nothing covered
        record["pulled_frames"] = int(np.sum(np.asarray(pulled) > 0))
    frame_mean = errors.mean(axis=1)
    if confidence is not None:
        record["repaired_frames"] = int(np.sum(repaired))
        record["flagged_frames"] = int(np.sum(confidence < TRUSTED))
        # does the confidence find the bad frames? frames over 3% mean error, and how many are flagged
        bad = frame_mean > 0.03 * size
        record["frames_over_3pct"] = int(bad.sum())
        record["frames_over_3pct_flagged"] = int(np.sum(bad & (confidence < TRUSTED)))
    record["worst_frame_mean_mm"] = round(1000 * float(frame_mean.max()), 2)
    record["worst_frame_mean_pct"] = round(100 * float(frame_mean.max()) / size, 3)
    if len(errors) > 1:  # where the error lies (engine.align.breakdown)
        labels = names_of_parts = None
        if part_counts:
            labels = part_labels(root_vertices, truth[root], faces, part_counts)
            names_of_parts = list(part_counts)
        breakdown = error_breakdown(errors, root, size, labels=labels, names=names_of_parts, depth=depth,
                                    confidence=confidence, trusted=TRUSTED)
        breakdown.pop("mean_pct")
        breakdown.pop("p95_pct")
        if frame_labels is not None:  # the global index and the capture's own SEQUENCE:FRAME, as frames.csv's
            for entry in breakdown["worst_frames"]:
                entry["label"] = frame_labels[entry["frame"]]
        record["breakdown"] = breakdown
    return record, errors


PICTURES = ("aligned_pattern.png", "aligned_pattern_sequential.png", "similarity.png", "tree.png")  # what a run may write
FRAME_COLUMNS = ("method", "sequence", "frame", "mean_pct", "p95_pct", "max_pct", "depth", "parent", "confidence",
                 "flagged", "repaired")


def _frame_rows(method, errors, size, names, picks, *, depth=None, parent=None, confidence=None, repaired=None):
    """One row per aligned frame (``FRAME_COLUMNS``): its sequence and frame number in the capture
    (``picks``: the frames of each sequence that were aligned), its error's mean, 95th percentile
    and max in % of the model size, its depth in the tree, the frame it was finally aligned from
    (``sequence:frame``; empty for the root), its confidence, whether that is flagged (below
    ``TRUSTED``) and whether the repair aligned it again. Unknown values are empty."""
    frame_errors = np.asarray(errors) / size * 100.0
    labels = [(name, int(f)) for name, pick in zip(names, picks) for f in pick]

    def cell(values, k, text):
        return "" if values is None else text(values[k])
    rows = []
    for k, (name, frame) in enumerate(labels):
        e = frame_errors[k]
        up = None if parent is None or parent[k] < 0 else labels[int(parent[k])]
        rows.append([method, name, frame, f"{e.mean():.4f}", f"{np.percentile(e, 95):.4f}", f"{e.max():.4f}",
                     cell(depth, k, lambda v: str(int(v))), "" if up is None else f"{up[0]}:{up[1]}",
                     cell(confidence, k, lambda v: f"{float(v):.4f}"),
                     cell(confidence, k, lambda v: str(int(float(v) < TRUSTED))),
                     cell(repaired, k, lambda v: str(int(bool(v))))])
    return rows


def _frame_labels(names, picks):
    """``SEQUENCE:FRAME`` (the capture's own frame numbering, as frames.csv's) of every frame
    aligned, in the global order."""
    return [f"{name}:{int(f)}" for name, pick in zip(names, picks) for f in pick]


def _read_record(path):
    """A JSON object from ``path``; {} when the file is missing, unreadable or not an object."""
    try:
        record = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        record = {}
    return record if isinstance(record, dict) else {}


def _recorded_alignment(directory):
    """The ``alignment`` record of an align output's manifest ({} when it has none)."""
    alignment = _read_record(directory / "manifest.json").get("alignment")
    return alignment if isinstance(alignment, dict) else {}


def _part_counts(manifest):
    """The template's parts and their vertex counts (``body.parts``), or None."""
    parts = manifest.get("body", {}).get("parts")
    return parts if isinstance(parts, dict) and parts else None


def _model_size(manifest, conventions, truth):
    """Model size in metres: the manifest's (in its body's units, else the sequences' common
    units), else that of the first frame's ground truth (already in metres)."""
    body = manifest.get("body", {})
    size = float(body.get("model_size") or 0.0)
    common = common_convention(conventions)
    units = body.get("units") if body.get("units") in UNITS_PER_METRE else (
        common.units if common.units_from != "mixed" else None)
    if size > 0 and units is not None:
        return size / UNITS_PER_METRE[units]
    return model_size(truth[0])


def _truth_conventions(dataset, manifest, aligned, names, parts, units, up):
    """Units and up axis of each sequence's ground truth, for scoring an earlier alignment: as
    given, else detected on the truth, else what the sequence's meta.json, the alignment's
    record of its input and the dataset manifest say."""
    conventions = []
    for name, positions in zip(names, parts):
        recorded = _read_record(aligned / "sequences" / name / "meta.json").get("alignment") or {}
        _check_given_against_record(name, aligned, recorded, units, up)
        declared = declared_convention([_read_record(dataset / "sequences" / name / "meta.json"),
                                        {"units": recorded.get("source_units"), "up": recorded.get("source_up")},
                                        manifest.get("body")])
        conventions.append(resolve_convention(positions, units, up, declared_units=declared[0],
                                              declared_up=declared[1]))
    return conventions


def _check_given_against_record(name, aligned, recorded, units, up):
    """A --units or --up that contradicts what the alignment recorded of a sequence's input is
    refused: the aligned frames were converted from that input, so ground truth read otherwise
    would be scored in other units or axes than the frames (nonsense errors, not a warning)."""
    plain = lambda value: str(value).strip().lower().lstrip("+")  # noqa: E731  ("+Z" and "z" are one axis)
    for flag, given, key in (("units", units, "source_units"), ("up", up, "source_up")):
        said = recorded.get(key)
        if given != "auto" and said not in (None, "", "mixed") and plain(given) != plain(said):
            raise ValueError(f"--{flag} {given}: {aligned} aligned {name} from input in {said} ({key} in its "
                             f"meta.json), so its ground truth is read in {said} too; leave --{flag} out with --aligned")


def _depth(extra, root, frames):
    """Each frame's depth in the similarity tree the frames were aligned along (``alignment.npz``'s
    ``tree_edges``; repairs change a frame's ``parent``, not its depth), or None without it."""
    if "tree_edges" not in extra:
        return None
    edges = extra["tree_edges"]
    return rooted_tree(edges, extra.get("tree_weights", np.zeros(len(edges))), root, frames).depth


def _load_aligned(directory, dataset_names):
    """An earlier `morphspace align` output: vertices, faces, root, root vertices, names, lengths."""
    path = directory / "alignment.npz"
    try:
        with np.load(path, allow_pickle=False) as data:
            names = [str(n) for n in data["sequence_names"]]
            lengths = data["lengths"].astype(np.int64)
            root = int(data["root"])
            extra = {k: data[k] for k in ("residual", "residual_max", "seconds", "retried", "cpu_seconds",
                                          "confidence", "repaired", "pulled", "tree_edges", "tree_weights", "parent")
                     if k in data.files}
    except FileNotFoundError:
        raise MeshFormatError(f"{path}: not found; is {directory} a `morphspace align` output?") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        why = "it holds pickled objects, which are never loaded" if "allow_pickle" in str(exc) else exc
        raise MeshFormatError(f"{path}: unreadable alignment record: {why}") from None
    timings = directory / "timings.json"  # per-frame times (older outputs kept them in alignment.npz)
    if timings.is_file():
        try:
            recorded = json.loads(timings.read_text())
            for key in ("seconds", "cpu_seconds"):
                if recorded.get(key) is not None:
                    extra[key] = np.asarray(recorded[key], dtype=np.float64)
        except (OSError, ValueError, TypeError) as exc:
            raise MeshFormatError(f"{timings}: unreadable: {exc}") from None
    missing = [n for n in names if n not in dataset_names]
    if missing:
        raise ValueError(f"{directory}: sequence(s) {', '.join(missing)} are not in the dataset")
    vertices, faces = [], None
    for name, n in zip(names, lengths):
        sequence = read_sequence(directory / "sequences" / name / "consistent")
        if len(sequence.vertices) != n:
            raise MeshFormatError(f"{directory}/sequences/{name}/consistent: {len(sequence.vertices)} frames, "
                                  f"alignment.npz says {n}")
        vertices.append(sequence.vertices)
        faces = sequence.faces
    root_mesh = read_mesh(directory / "template" / "body.obj")
    return np.concatenate(vertices), faces, root, root_mesh.vertices, names, lengths, extra


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
            vertices, faces, root, root_vertices, names, lengths, extra = _load_aligned(args.aligned, dataset_names)
            sequences = [{"name": n} for n in names]
            every_frame = [np.arange(n) for n in lengths]  # an align output keeps every frame
            labels, depth = _frame_labels(names, every_frame), _depth(extra, root, int(lengths.sum()))
            parts, template_faces = _truth(dataset, sequences, every_frame, lengths)
            # the ground truth is in the files' units and axes; the aligned frames in metres, +Y up
            conventions = _truth_conventions(dataset, manifest, args.aligned, names, parts, args.units, args.up)
            say_conventions(conventions, names, _say_line, what="ground truth")
            truth = _truth_in_metres(parts, conventions)
            size = _model_size(manifest, conventions, truth)
            record, errors = _score("aligned", vertices, root, root_vertices, truth, template_faces, size, lengths,
                                    names, residual=extra.get("residual"), residual_max=extra.get("residual_max"),
                                    seconds=extra.get("seconds"), retried=extra.get("retried"),
                                    cpu_seconds=extra.get("cpu_seconds"), confidence=extra.get("confidence"),
                                    repaired=extra.get("repaired"), pulled=extra.get("pulled"),
                                    part_counts=_part_counts(manifest), depth=depth, frame_labels=labels)
            report.update(model_size_m=size, frames=int(lengths.sum()), sequences=names, root=int(root),
                          root_frame=labels[int(root)], aligned=record, **_units_report(names, conventions))
            recorded = _recorded_alignment(args.aligned)
            reason = recorded.get("root_reason")
            if reason and isinstance(reason, str):  # why the alignment ran no trial or race, as it recorded
                report["root_reason"] = reason
            results = {"aligned": (vertices, faces, root_vertices)}
            frame_rows = _frame_rows("aligned", errors, size, names, every_frame, depth=depth,
                                     parent=extra.get("parent"),
                                     confidence=extra.get("confidence"), repaired=extra.get("repaired"))
        else:
            sequences = resolve_inputs([dataset], args.only)
            check_root_early(args.root if args.root is not None and ":" in args.root else None, sequences)
            meshes, lengths = read_inputs(sequences, progress, say=_say_line)
            picks = _picked_frames(lengths, args.every, args.max_frames)
            counts, starts = lengths, np.concatenate([[0], np.cumsum(lengths)[:-1]])
            meshes = [meshes[start + i] for start, pick in zip(starts, picks) for i in pick]
            lengths = np.array([len(pick) for pick in picks], dtype=np.int64)
            names = [s["name"] for s in sequences]
            meshes, conventions = convert_inputs(meshes, sequences, lengths, args.units, args.up, say=_say_line)
            parts, template_faces = _truth(dataset, sequences, picks, counts)
            truth = _truth_in_metres(parts, conventions)  # in the same units and axes as the frames
            size = _model_size(manifest, conventions, truth)
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
            labels = _frame_labels(names, picks)
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
                record, errors = _score(method, a.vertices, root, a.root_vertices, truth, template_faces, size,
                                        lengths, names, residual=a.residual, residual_max=a.residual_max,
                                        seconds=a.seconds, retried=a.retried, cpu_seconds=a.cpu_seconds,
                                        confidence=a.confidence, repaired=a.repaired, pulled=a.pulled,
                                        part_counts=_part_counts(manifest), depth=result.tree.depth,
                                        frame_labels=labels)
                report[method] = {**report.get(method, {}), **record}
                results[method] = (a.vertices, a.faces, a.root_vertices)
                frame_rows += _frame_rows(method, errors, size, names, picks, depth=result.tree.depth, parent=a.parent,
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
