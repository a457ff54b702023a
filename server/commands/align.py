"""Align unstructured captures into one mesh structure (shape similarity tree + non-rigid alignment).

Each DIR is a capture dataset (its sequences/*/unstructured frames are used), one sequence
directory of a dataset (sequences/<name>, its unstructured/ frames), or any directory or zip of
per-frame meshes. All frames of all sequences are compared by volumetric shape histograms, a
shape similarity tree is built over them, and every frame is deformed into the root frame's
mesh along the tree (Casas et al. 2012, section 3). Frames in centimetres or millimetres, or
with +Z up, are converted to metres with +Y up first (--units, --up; detected by default, and
said on stderr). Output, in metres with +Y up, readable by `morphspace build --source
OUT/sequences/<name>`:

    OUT/sequences/<name>/consistent/frame_0000.obj ...   every frame in the root's mesh
    OUT/sequences/<name>/meta.json                        input meta.json + alignment fields
    OUT/template/body.obj                                 the root mesh (the rest shape)
    OUT/alignment.npz                                     dissimilarities, tree, root, residuals
    OUT/similarity.png, OUT/tree.png                      the matrix and the tree (fig. 1c, 1d)
    OUT/aligned_pattern.png                               a pattern fixed on the root, carried
                                                          into aligned frames (fig. 2)
    OUT/manifest.json                                     + the inputs' units and up axis

Example:

    morphspace align data/captures/demo --out data/aligned/demo
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

from tqdm import tqdm

from engine.align import AlignmentOptions, align_captures
from engine.align.captures import FINE_EDGE, ROOT_CHOICES
from engine.align.repair import TRUSTED
from engine.align.similarity_tree import DEFAULT_TREE, TREE_KINDS
from engine.surface import model_size
from server.commands.align_inputs import (DEFAULT_FPS, check_root_early, convert_inputs, frame_label, parse_root,
                                          read_inputs, resolve_inputs)
from server.commands.align_output import (colour_cues_text, confidence_summary, options_record, root_trial_text,
                                          root_vertices_text, stopped_text, write_alignment)
from server.commands.checks import MAX_FPS
from server.commands.staging import staged
from server.units import add_units_arguments, common_convention, count_text, length_text

COLOUR_MODES = {"auto": "auto", "on": True, "off": False}  # --colors -> align_captures(use_colors=...)


def add_arguments(parser):
    parser.add_argument("inputs", nargs="+", type=Path, metavar="DIR",
                        help="capture dataset, sequence directory, or directory/zip of frames (one per sequence)")
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="with a capture dataset: only these sequences")
    parser.add_argument("--root", help="root frame as SEQUENCE:FRAME or a global frame index "
                        "(default: chosen by --root-choice)")
    parser.add_argument("--root-choice", choices=ROOT_CHOICES, default="auto",
                        help="without --root: auto (default) is race, except on one densely tracked take (a single "
                             "sequence, 80%% of the tree's steps or more join neighbours in time), where it is trial "
                             "(no race); "
                             "race runs the trial, then its two best candidates each align "
                             "the capture (a capture of more than 128 frames: 64 frames of it, evenly spaced) and the "
                             "root of the alignment with the higher mean confidence wins; "
                             "trial lets the apart choice and up to 3 other central frames "
                             "each align 6 probe frames and takes the one that aligns them best (captures of 24 "
                             "frames or more); apart takes a frame nearly as central as the most central one whose "
                             "limbs are apart (no merged contact tied into every frame); central is the paper's "
                             "most central frame of the tree")
    parser.add_argument("--sequential", action="store_true",
                        help="frame-to-frame tracking from the root instead of the tree (the baseline)")
    parser.add_argument("--tree", choices=TREE_KINDS, default=DEFAULT_TREE,
                        help="mst: the paper's minimum spanning tree; paths: every frame's cheapest path from the root, "
                             "big steps penalised (shallower); steps: every frame's path of the least expected error "
                             f"(default {DEFAULT_TREE})")
    parser.add_argument("--window", type=int, default=2, help="temporal filter half-width in frames (default 2)")
    parser.add_argument("--patches", type=int, default=30, help="patches at the coarsest level (default 30)")
    parser.add_argument("--levels", type=int, default=4, help="coarse-to-fine levels, patches doubling (default 4)")
    parser.add_argument("--retries", type=int, default=3,
                        help="other parents tried for a frame whose alignment scores poorly or, with colour cues, "
                             "whose step lost the root's colours (default 3)")
    parser.add_argument("--repair-budget", type=float, default=0.25, metavar="B",
                        help="pairwise alignments per frame the repair of low-confidence frames may spend, "
                             "from the root first, the frames most like it first (default 0.25; 0 turns the repair off)")
    parser.add_argument("--swing-limbs", action="store_true",
                        help="swing limbs onto the parts of a frame nothing covers in the coarse matching (an arm "
                             "thrown into a punch): better on tight-fitting clothes, not on loose garments "
                             "(docs/alignment.md)")
    parser.add_argument("--reach-limbs", action=argparse.BooleanOptionalAction, default=True,
                        help="pull the root's extremities (hands, feet, head, a sleeve's or hem's end) onto "
                             "the parts of a frame nothing covers, bending the limb as-rigid-as-possible (an "
                             "arm thrown into a punch; default on; docs/alignment.md)")
    parser.add_argument("--graft-limbs", action=argparse.BooleanOptionalAction, default=False,
                        help="in the repair, give a frame the root left flagged the limbs of the other frames' "
                             "poses that fit it clearly better (an arm raised where its parent's hung) and align "
                             "it again from there (default off; docs/alignment.md)")
    parser.add_argument("--colors", nargs="?", const="on", default="auto", choices=("auto", "on", "off"),
                        help="vertex colours as local matching cues when every frame has them: auto (default) "
                             "when the meshes are fine enough for colours to carry texture (median edge "
                             f"under {FINE_EDGE * 100:.1f}%% of the square root of the root's surface area), on "
                             "(--colors alone), off")
    parser.add_argument("--fps", type=float, default=None,
                        help="frame rate of inputs without meta.json (default 30, with a note that it was assumed)")
    add_units_arguments(parser)
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="worker processes for the shape histograms, the dissimilarity matrix (from 3,000 "
                             "frames) and independent pieces of the tree (default: up to 2)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (patch sampling; default 0)")
    parser.add_argument("--force", action="store_true", help="replace an existing output directory")


class Progress:
    """tqdm bars on stderr, one per stage."""

    LABELS = {"read": "read frames", "histograms": "shape histograms", "dissimilarity": "dissimilarity",
              "root": "choose root", "trial": "try roots", "race": "race roots", "align": "align", "align sequential": "align (sequential)", "repair": "repair",
              "write": "write"}
    UNITS = {"trial": "root"}  # the trial counts candidate roots, the other stages frames (the race: each finalist's)

    def __init__(self):
        self.bars = {}

    def __call__(self, stage, done, total):
        if stage not in self.bars:
            self.close()
            self.bars[stage] = tqdm(total=total or None, desc=self.LABELS.get(stage, stage), unit=self.UNITS.get(stage, "frame"),
                                    dynamic_ncols=True, mininterval=0.5, file=sys.stderr)
        bar = self.bars[stage]
        if total:
            bar.total = total
        if done >= bar.n:
            bar.update(done - bar.n)  # redrawn at most every mininterval (logs stay short)
        else:
            bar.n = done
            bar.refresh()

    def close(self):
        for bar in self.bars.values():
            bar.close()
        self.bars.clear()


def check_output(out, inputs, force):
    """Refuse an output directory ``out`` that would destroy what it is made from or cannot be
    written, before any work: an existing one without ``force``, a file, an input or a directory
    holding one (``--force`` would delete it), a directory inside an input."""
    if out.exists() and not force:
        raise FileExistsError(f"{out} already exists; pass --force to replace it")
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} is a file, not a directory: name a directory for the output")
    target = out.resolve()
    here = Path.cwd()
    if target == here or target in here.parents:  # (--force would remove it, as synth refuses too)
        raise ValueError(f"--out {out}: is the current directory or holds it; give a new directory")
    for path in inputs:
        source = Path(path).resolve()
        if target == source or target in source.parents:
            raise ValueError(f"--out {out} holds the input {path}: replacing it would delete the frames being aligned")
        if source in target.parents:
            raise ValueError(f"--out {out} is inside the input {path}: name a directory outside it")


def job_range(field):
    """(low, high) of the align job's ``field`` (server/jobs/models.py): the CLI takes what REST takes."""
    from server.jobs.models import AlignJob

    metadata = AlignJob.model_fields[field].metadata
    return (next(m.ge for m in metadata if hasattr(m, "ge")), next(m.le for m in metadata if hasattr(m, "le")))


def check_root_given_once(args):
    """--root with a --root-choice other than the default: the root is given, so nothing would be
    chosen; refused rather than recorded as a choice that never ran."""
    if args.root is not None and args.root_choice != "auto":
        raise ValueError(f"--root-choice {args.root_choice}: the root is given (--root {args.root}), so no root "
                         "is chosen; give one or the other")


def check_job_ranges(args, fields=("window", "patches", "levels", "retries", "repair_budget")):
    """Refuse ``fields`` (--window, --patches, ...) outside the align job's ranges."""
    for field in fields:
        value, (low, high) = getattr(args, field), job_range(field)
        if not low <= value <= high:  # (NaN fails too)
            raise ValueError(f"--{field.replace('_', '-')} must be from {low:g} to {high:g}, got {value}")


def run(args):
    out = args.out
    check_output(out, args.inputs, args.force)
    for name, value, low in (("--workers", args.workers, 1), ("--seed", args.seed, 0)):
        if not value >= low or not math.isfinite(value):  # (NaN fails both)
            raise ValueError(f"{name} must be a number >= {low}, got {value}")
    check_job_ranges(args)
    check_root_given_once(args)
    if args.fps is not None and not (math.isfinite(args.fps) and 0 < args.fps <= MAX_FPS):
        raise ValueError(f"--fps must be above 0 and at most {MAX_FPS:g} frames/s, got {args.fps}")
    sequences = resolve_inputs(args.inputs, args.only)
    check_root_early(args.root, sequences)
    progress = Progress()
    started = time.perf_counter()
    try:
        say = lambda line: tqdm.write(f"morphspace align: {line}", file=sys.stderr)  # noqa: E731
        meshes, lengths = read_inputs(sequences, progress, say=say)
        meshes, conventions = convert_inputs(meshes, sequences, lengths, args.units, args.up, say=say)
        unlabelled = [s["name"] for s in sequences if not s["meta"]]
        if unlabelled and args.fps is None:
            say(f"note: {', '.join(unlabelled)}: no meta.json gives the frame rate; written as {DEFAULT_FPS:g} "
                f"frames/s (say --fps)")
        root = parse_root(args.root, sequences, lengths)
        options = AlignmentOptions(patches=args.patches, levels=args.levels, swing_limbs=args.swing_limbs,
                                   reach_limbs=args.reach_limbs, graft_limbs=args.graft_limbs)
        result = align_captures(meshes, lengths, method="sequential" if args.sequential else "tree", tree_kind=args.tree,
                                root=root, root_choice=args.root_choice, options=options, window=args.window,
                                workers=args.workers, retries=args.retries,
                                use_colors=COLOUR_MODES[args.colors], seed=args.seed, repair_budget=args.repair_budget,
                                progress=progress)
        with staged(out) as staging:
            write_alignment(staging, sequences, meshes, lengths, result, fps=args.fps or DEFAULT_FPS,
                            options_record=options_record(vars(args), result.colour_cues),
                            progress=progress, conventions=conventions)
    finally:
        progress.close()
    aligned = result.aligned
    t = result.timings
    frames = int(lengths.sum())
    print(f"aligned {count_text(frames, 'frame')} of {count_text(len(sequences), 'sequence')} "
          f"to {out} in {time.perf_counter() - started:.1f} s "
          f"({result.method}, root {frame_label(aligned.root, sequences, lengths)} = frame {aligned.root}, "
          f"{root_vertices_text(len(aligned.root_vertices), len(meshes[aligned.root].vertices))})")
    print(f"  similarity {t['similarity']:.1f} s, tree {t['tree']:.2f} s (depth {int(result.tree.depth.max())}, "
          + ("the pruned graph in one piece), " if result.tree.components == 1 else
             f"{result.tree.components} pieces of the pruned graph reconnected), ")
          + (f"root trial {t['trial']:.1f} s, " if "trial" in t else "")
          + (f"root race {t['race']:.1f} s, " if "race" in t else "") + f"tetrahedralise {t['tetrahedralize']:.1f} s, "
          + (f"alignment {t['align']:.1f} s = {t['align'] / (frames - 1):.2f} s/frame wall with "
             f"{args.workers} worker{'s' if args.workers != 1 else ''} ({aligned.seconds.sum() / (frames - 1):.2f} s, "
             f"{aligned.cpu_seconds.sum() / (frames - 1):.2f} CPU s per frame and aligner)" if frames > 1 else
             "no alignment (the root is the only frame)") + f", repair {t['repair']:.1f} s")
    size = model_size(aligned.root_vertices)
    confidence = confidence_summary(aligned, sequences, lengths)
    convention = common_convention(conventions)
    given = ("mixed units or axes" if convention.units_from == "mixed"
             else f"{convention.units}, {convention.up_label} up")
    print(f"  input {given} (written in metres, +Y up); fit residual mean "
          f"{length_text(aligned.residual.mean(), convention, size)}, max "
          f"{length_text(aligned.residual_max.max(), convention, size, digits=1)}; "
          f"{count_text(int(aligned.retried.sum()), 'frame')} re-aligned from other parents, "
          f"{confidence['pulled_frames']} with a limb pulled onto what nothing covered")
    print(f"  colour cues {colour_cues_text(args.colors, result.colour_cues, meshes)}")
    if result.root_trial:
        print(f"  {root_trial_text(result.root_trial, int(aligned.root), sequences, lengths)}")
    if result.root_reason:
        print(f"  root: {result.root_reason}")
    if result.turned:
        shown = [frame_label(i, sequences, lengths) for i in sorted(result.turned)]
        print(f"  faces wound inward (or mixed) turned outward in {count_text(len(shown), 'frame')}: "
              f"{', '.join(shown[:6])}"
              + (", ..." if len(shown) > 6 else ""))
    print(f"  confidence: {count_text(confidence['repaired_frames'], 'frame')} repaired (aligned again from the root "
          f"or trusted frames; {count_text(confidence['repair_alignments'], 'alignment')} tried"
          f"{stopped_text(confidence)}), "
          f"{confidence['flagged_frames']} of {frames} still below {TRUSTED} (listed per sequence in meta.json)")
    return 0


__all__ = ["COLOUR_MODES", "Progress", "add_arguments", "check_job_ranges", "check_output", "check_root_given_once",
           "run"]
