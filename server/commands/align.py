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
import contextlib
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path, PurePosixPath

import numpy as np
from tqdm import tqdm

from engine.align import AlignmentOptions, align_captures
from engine.align.similarity_tree import DEFAULT_TREE, TREE_KINDS
from engine.align.captures import FINE_EDGE, ROOT_CHOICES
from engine.align.repair import TRUSTED
from engine.mesh_io import MESH_EXTENSIONS, read_frames, write_obj, write_sequence
from engine.mesh_io.frames import left_out_frames, list_frames
from engine.mesh_io.dataset import read_capture_manifest, write_capture_manifest
from engine.motion_space import SourceClip
from engine.motion_space.roots import capture_travel_turn
from engine.mesh_io.errors import MeshFormatError, MeshSequenceError
from engine.mesh_io.natural_sort import stem_runs
from server.commands.checks import MAX_FPS, read_meta
from engine.mesh_io.npz import savez_stable
from engine.mesh_io.units import Convention
from engine.surface import model_size
from server.units import (
    add_units_arguments,
    common_convention,
    count_text,
    display_unit,
    declared_convention,
    length_text,
    meshes_to_metres,
    say_conventions,
)

ALIGNMENT_FORMAT = "morphspace-alignment"
ALIGNMENT_VERSION = 1

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


def root_trial_text(trial, chosen, sequences, lengths):
    """One line on the root trial (and the race, when one ran): the candidates' mean badness, the
    finalists' mean confidence and the root taken (``chosen``, the root the alignment used)."""
    tried = ", ".join(f"{frame_label(c, sequences, lengths)} " + ("no tet mesh" if m is None else f"{m:.2f}")
                      for c, m in zip(trial["candidates"], trial["mean"]))
    change = ("kept (the spread's choice too)" if chosen == trial["spread_choice"]
              else f"taken instead of the spread's choice, {frame_label(trial['spread_choice'], sequences, lengths)}")
    race = trial.get("race")
    raced = "" if race is None else (
        f"; the best {len(race['finalists'])} each aligned {race['frames']} frames (mean confidence, higher is better: "
        + ", ".join(f"{frame_label(c, sequences, lengths)} {x:.2f}" for c, x in zip(race["finalists"], race["confidence"]))
        + ")")
    return (f"root tried: {len(trial['candidates'])} candidates aligned {len(trial['probes'])} probe frames each "
            f"(mean badness, lower is better: {tried}){raced}; {frame_label(chosen, sequences, lengths)} {change}")


def resolve_inputs(inputs, only=None):
    """Sequences to align from the command-line DIRs.

    Returns
    -------
    sequences : list of dict   name, frames (path of the frame directory or zip), meta (dict or None),
                               declared (metadata that may say units and up: meta.json, the
                               dataset manifest's ``body``)
    """
    sequences = []
    for path in inputs:
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such file or directory")
        if (path / "manifest.json").is_file() and (path / "sequences").is_dir():
            manifest = read_capture_manifest(path)
            names = [s["name"] for s in manifest.get("sequences", [])] or sorted(
                p.name for p in (path / "sequences").iterdir() if p.is_dir())
            if only:
                unknown = sorted(set(only) - set(names))
                if unknown:
                    raise ValueError(f"{path}: no sequence(s) {', '.join(unknown)}; it has {', '.join(names)}")
                names = [n for n in names if n in only]
            for name in names:
                sequences.append(_sequence_entry(path / "sequences" / name, manifest.get("body")))
        else:
            if only:
                raise ValueError("--only selects sequences of a capture dataset; "
                                 f"{path} is not one (no manifest.json and sequences/)")
            sequences.append(_sequence_entry(path))
    names = [s["name"] for s in sequences]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"two inputs have the same sequence name {duplicates[0]!r}; rename one directory")
    return sequences


def _sequence_entry(path, body=None):
    meta = read_meta(path) if (path / "meta.json").is_file() else None
    # a sequence's re-meshed frames; without them its consistent ones (an upload, or an aligned
    # output aligned again: "no mesh files among the 2 entries" named the wrong problem)
    frames = next((path / sub for sub in ("unstructured", "consistent") if (path / sub).is_dir()), path)
    name = (meta or {}).get("name") or (path.stem if path.suffix.lower() == ".zip" else path.name)
    if body is None and (path.parent.parent / "manifest.json").is_file():  # a sequence of a dataset
        try:
            body = read_capture_manifest(path.parent.parent).get("body")
        except (OSError, ValueError):
            body = None
    return {"name": str(name), "frames": frames, "meta": meta, "declared": [meta, body]}


def parse_root(text, sequences, lengths, label="--root"):
    """Global frame index from "SEQUENCE:FRAME" or an integer (``label`` names it in errors).
    With ``lengths`` None (the frames not counted yet) only the form, the sequence and a frame
    number from 0 are checked, and None is returned."""
    if text is None:
        return None
    if ":" in text:
        name, _, frame = text.rpartition(":")
        names = [s["name"] for s in sequences]
        if name not in names:
            only = "--only" if label.startswith("--") else "only"
            raise ValueError(f"{label} {text}: no sequence {name!r}; sequences are {', '.join(names) or 'none'}"
                             f" (those aligned: {only} picks them)")
        k = names.index(name)
        try:
            frame = int(frame)
        except ValueError:
            raise ValueError(f"{label} {text}: frame must be an integer") from None
        if lengths is None:
            if frame < 0:
                raise ValueError(f"{label} {text}: frame must be an integer from 0")
            return None
        if not 0 <= frame < lengths[k]:
            raise ValueError(f"{label} {text}: sequence {name} has frames 0..{lengths[k] - 1}")
        return int(np.sum(lengths[:k]) + frame)
    try:
        index = int(text)
    except ValueError:
        raise ValueError(f"{label} {text}: expected SEQUENCE:FRAME or a frame index") from None
    if lengths is None:
        if index < 0:
            raise ValueError(f"{label} {text}: a frame index is an integer from 0")
        return None
    total = int(np.sum(lengths))
    if not 0 <= index < total:
        raise ValueError(f"{label} {text}: there are {total} frames (0..{total - 1})")
    return index


def check_root_early(text, sequences, label="--root"):
    """:func:`parse_root` against the frame files listed, before any frame is read (a root past a
    sequence's end was refused only after reading every frame). Where a listing fails or finds no
    frames, the reading names the problem; the root is parsed again against the frames read."""
    if text is None:
        return
    with contextlib.suppress(MeshFormatError, MeshSequenceError, OSError):
        counts = np.array([len(list_frames(s["frames"])) for s in sequences], dtype=np.int64)
        if len(counts) and counts.min() > 0:
            parse_root(text, sequences, counts, label=label)


DEFAULT_FPS = 30.0  # the frame rate of inputs without a meta.json, unless --fps says


def read_inputs(sequences, progress=None, *, say=None):
    """All frames of all sequences (concatenated) and the frame count of each sequence.

    ``say(line)`` is told of files beside a sequence's frames in a mesh format that is not read
    (an ``.stl`` among ``.obj`` frames): they are left out, and the frames renumbered without them;
    and of frame files of more than one name (``frame_10.ply`` beside ``take_0004.ply``): they are
    taken in natural order all the same (`mixed_names_text`).
    """
    meshes, lengths = [], []
    total = None
    if progress is not None:  # the bar's total: every sequence's frame files, listed first
        with contextlib.suppress(MeshFormatError, MeshSequenceError):  # read_frames below names the problem
            total = sum(len(list_frames(s["frames"])) for s in sequences)
    for s in sequences:
        frames = read_frames(s["frames"], progress=(lambda d, t: progress("read", len(meshes) + d, total))
                             if progress else None)
        left_out = left_out_frames(s["frames"])
        if left_out and say is not None:
            shown = ", ".join(left_out[:5]) + (f" and {len(left_out) - 5} more" if len(left_out) > 5 else "")
            say(f"warning: {s['name']}: {len(left_out)} file(s) in a mesh format that is not read "
                f"({', '.join(MESH_EXTENSIONS)} are), left out of the sequence: {shown}")
        mixed = mixed_names_text([_file_name(m.source) for m in frames])
        if mixed and say is not None:
            say(f"warning: {s['name']}: {mixed}")
        if len(frames) < 1:
            raise MeshFormatError(f"{s['frames']}: no frames")
        meshes.extend(frames)
        lengths.append(len(frames))
    return meshes, np.array(lengths, dtype=np.int64)


def mixed_names_text(names, shown=6):
    """None when every frame file of a sequence (``names``, in natural order) has one name apart from
    its number, else a line naming the names and the order the frames are taken in (``shown`` runs)::

        the frame files mix names 'frame_' and 'take_', taken in natural order: frame_1.ply to
        frame_10.ply as frames 0-9, then take_0004.ply to take_0007.ply as frames 10-13
    """
    runs = stem_runs(names)
    stems = list(dict.fromkeys(stem.casefold() for stem, _, _ in runs))
    if len(stems) < 2:
        return None
    spelled = [next(repr(stem) for stem, _, _ in runs if stem.casefold() == folded) for folded in stems]
    listed = (f"names {', '.join(spelled[:-1])} and {spelled[-1]}" if len(spelled) <= 4 else
              f"{len(spelled)} names ({spelled[0]}, {spelled[1]}, ..., {spelled[-1]})")
    if len(runs) == len(names) and len(spelled) == len(names):  # no two files share a name: nothing is numbered
        order = [f"{name} as frame {k}" for k, name in enumerate(names)]
        order = order if len(order) <= 3 else order[:2] + ["...", order[-1]]
        return f"the frame files have {len(names)} different names, taken in natural order: " + ", ".join(order)
    parts = [f"{names[first]} as frame {first}" if first == last
             else f"{names[first]} to {names[last]} as frames {first}-{last}" for _, first, last in runs[:shown]]
    more = f", ... ({len(runs)} runs in all)" if len(runs) > shown else ""
    return f"the frame files mix {listed}, taken in natural order: " + ", then ".join(parts) + more


def convert_inputs(meshes, sequences, lengths, units="auto", up="auto", *, say=None):
    """Every sequence's frames in metres with +Y up (see ``server.units``).

    Each sequence is decided on its own frames (a dataset may mix units and axes), its
    meta.json, then its dataset manifest's ``body``, consulted when the geometry cannot tell;
    ``say(line)`` is told what was decided and any doubt about it.

    Returns
    -------
    meshes : list of Mesh                      all frames, converted
    conventions : list of engine.mesh_io.Convention   one per sequence
    """
    converted, conventions, start = [], [], 0
    for s, n in zip(sequences, lengths):
        part, convention = meshes_to_metres(meshes[start:start + n], units, up,
                                            declared=declared_convention(s.get("declared", ())))
        converted.extend(part)
        conventions.append(convention)
        start += n
    if say is not None:
        say_conventions(conventions, [s["name"] for s in sequences], say)
    return converted, conventions


OPTION_NAMES = ("patches", "levels", "window", "retries", "repair_budget", "tree", "root_choice", "colors",
                "swing_limbs", "reach_limbs", "graft_limbs")


def colour_cues_text(mode, used, meshes):
    """Whether the alignment used vertex colours as matching cues, and why (``mode``: --colors)."""
    if mode != "auto":
        return f"{'on' if used else 'off'} (--colors {mode})"
    if used:
        return "on (--colors auto: the frames have vertex colours and the root is fine enough to carry a texture)"
    if not all(getattr(m, "colors", None) is not None for m in meshes):
        return "off (--colors auto: not every frame has vertex colours)"
    return (f"off (--colors auto: the root's median edge is not under {100 * FINE_EDGE:g}% of the square root of "
            "its surface area, too coarse to carry a texture; --colors on uses them anyway)")


def options_record(options, colour_cues):
    """The manifest's ``alignment.options``: ``options`` (a mapping with ``OPTION_NAMES``, ``seed``,
    ``units`` and ``up``: the command line's or an align job's) and whether colour cues were used,
    in one order, so `morphspace align` and the align job write the same manifest (a job queued
    before an option existed has it from ``server.jobs.tasks.ALIGN_DEFAULTS``)."""
    return {**{name: options[name] for name in OPTION_NAMES}, "colour_cues": colour_cues, "seed": options["seed"],
            "units": options["units"], "up": options["up"]}


# what describes the input's frames and not the aligned ones (their count, mesh structure and axes)
_INPUT_ONLY = ("frames", "duration", "topology", "vertices", "faces", "unstructured_frames",
               "unstructured_vertex_counts", "units", "up", "forward", "left", "from_metres_y_up",
               "studio", "noise_mm")  # the last two: a studio's reconstructions and their noise


def aligned_meta(meta, name, frames, fps, vertices, faces):
    """A written sequence's meta.json: the input's (``meta``, or None) with what describes the
    frames replaced by what was written: ``frames`` frames of one mesh structure (``vertices``,
    ``faces``), in metres with +Y up; the input's frame rate, else ``fps``."""
    meta = {k: v for k, v in (meta or {"cyclic": False, "frames_per_cycle": None}).items() if k not in _INPUT_ONLY}
    rate = float(meta.get("fps") or fps)
    return {"name": name, **{k: v for k, v in meta.items() if k != "name"}, "fps": rate, "frames": frames,
            "duration": frames / rate, "topology": "consistent", "vertices": int(vertices), "faces": int(faces),
            "units": "m", "up": "+Y"}


def frame_label(index, sequences, lengths):
    """"SEQUENCE:FRAME" of a global frame ``index`` (the form ``--root`` takes)."""
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    k = int(np.searchsorted(starts, int(index), side="right") - 1)
    return f"{sequences[k]['name']}:{int(index) - int(starts[k])}"


def confidence_summary(aligned, sequences, lengths):
    """The per-frame confidence in a few numbers (the align job's summary, the CLI's last line):
    ``root_frame`` ("SEQUENCE:FRAME"), ``repaired_frames`` and ``flagged_frames`` (below
    ``TRUSTED``) counted over all sequences, ``repair_alignments`` (the pairwise alignments the
    repair tried, kept or not), ``confidence_min``, ``pulled_frames`` (frames whose
    alignment pulled a limb onto what nothing covered, ``reach_limbs``), and ``flagged``: per
    sequence the frames (its own numbering) still below ``TRUSTED``."""
    return {"root_frame": frame_label(aligned.root, sequences, lengths),
            "repaired_frames": int(np.sum(aligned.repaired)),
            "repair_alignments": int(aligned.repair_spent),
            "flagged_frames": int(np.sum(aligned.confidence < TRUSTED)),
            "confidence_min": float(np.min(aligned.confidence)),
            "pulled_frames": int(np.sum(np.asarray(aligned.pulled) > 0)) if aligned.pulled is not None else 0,
            "flagged": flagged_by_sequence(aligned, sequences, lengths)}


def flagged_by_sequence(aligned, sequences, lengths):
    """{sequence name: its frames (its own numbering) whose confidence is below ``TRUSTED``}."""
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    return {s["name"]: [int(i) for i in np.flatnonzero(aligned.confidence[a:a + n] < TRUSTED)]
            for s, a, n in zip(sequences, starts, lengths)}


def write_alignment(out, sequences, meshes, lengths, result, *, fps, options_record, progress=None,
                    conventions=None):
    """Write the aligned frames, metadata, arrays and pictures (see the module docstring).

    ``meshes`` are in metres with +Y up; ``conventions`` (one engine.mesh_io.Convention per
    sequence) say what the input files were in, recorded in the meta.json files, alignment.npz
    and the manifest.
    """
    conventions = conventions or [Convention()] * len(sequences)
    common = common_convention(conventions)
    from PIL import Image

    from engine.align import pattern_sheet, similarity_image, tree_image

    aligned = result.aligned
    tree = result.tree
    root = aligned.root
    root_mesh = meshes[root]
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    root_label = frame_label(root, sequences, lengths)
    flagged = flagged_by_sequence(aligned, sequences, lengths)
    colors = None if root_mesh.colors is None else np.asarray(root_mesh.colors)[aligned.root_kept]
    write_obj(out / "template" / "body.obj", aligned.root_vertices, aligned.faces, colors=colors)
    size = model_size(aligned.root_vertices)
    metas = []
    written = 0
    for k, s in enumerate(sequences):
        span = slice(starts[k], starts[k] + lengths[k])
        base = out / "sequences" / s["name"]
        frame_colors = None if colors is None else np.broadcast_to(colors, (lengths[k],) + colors.shape)
        write_sequence(base / "consistent", aligned.vertices[span], aligned.faces, colors=frame_colors,
                       progress=(lambda d, t: progress("write", written + d, int(lengths.sum()))) if progress else None)
        written += int(lengths[k])
        meta = aligned_meta(s["meta"], s["name"], int(lengths[k]), fps, len(aligned.root_vertices),
                            len(aligned.faces))
        meta["alignment"] = {
            "method": result.method, "root": root_label,
            "source": str(s["frames"]),
            "source_files": [_file_name(meshes[i].source) for i in range(starts[k], starts[k] + lengths[k])],
            "source_units": conventions[k].units,
            "source_up": conventions[k].up_label, "input": conventions[k].to_metadata(),
            "residual_mean_mm": float(1000 * aligned.residual[span].mean()),
            "residual_max_mm": float(1000 * aligned.residual_max[span].max()),
            "residual_mean_pct": float(100 * aligned.residual[span].mean() / size),
            "residual_max_pct": float(100 * aligned.residual_max[span].max() / size),
            "retried_frames": int(aligned.retried[span].sum()),
            "pulled_frames": int((aligned.pulled[span] > 0).sum()),
            "repaired_frames": int(aligned.repaired[span].sum()),
            "confidence_min": float(aligned.confidence[span].min()),
            "flagged_frames": flagged[s["name"]],
        }
        (base / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")
        metas.append(meta)
    savez_stable(
        out / "alignment.npz", dict(
        format=np.array(ALIGNMENT_FORMAT), version=np.array(ALIGNMENT_VERSION),
        sequence_names=np.array([s["name"] for s in sequences]), lengths=lengths,
        root=np.array(root), method=np.array(result.method),
        dissimilarity=result.similarity.dissimilarity.astype(np.float32),
        raw_dissimilarity=result.similarity.raw.astype(np.float32), yaw=result.similarity.yaw,
        histogram_radius=np.array(result.similarity.radius), window=np.array(result.similarity.window),
        tree_edges=tree.edges, tree_weights=tree.weights, tree_threshold=np.array(tree.threshold),
        tree_components=np.array(tree.components), parent=aligned.parent,
        residual=aligned.residual, residual_max=aligned.residual_max, distortion=aligned.distortion,
        retried=aligned.retried, distortion_tail=aligned.distortion_tail,
        colour=np.full(len(aligned.parent), np.nan) if aligned.colour is None else aligned.colour,
        confidence=aligned.confidence, repaired=aligned.repaired, pulled=aligned.pulled,
        source_units=np.array([c.units for c in conventions]), source_up=np.array([c.up_label for c in conventions]),
    ))
    # the only output that differs from run to run: how long it took
    timings = {"stages_s": {k: round(v, 3) for k, v in result.timings.items()},
               "seconds": [round(float(x), 4) for x in aligned.seconds],
               "cpu_seconds": None if aligned.cpu_seconds is None else [round(float(x), 4) for x in aligned.cpu_seconds]}
    (out / "timings.json").write_text(json.dumps(timings, indent=1) + "\n")
    names = [s["name"] for s in sequences]
    Image.fromarray(similarity_image(result.similarity.dissimilarity, lengths, names)).save(out / "similarity.png")
    Image.fromarray(tree_image(tree, lengths, names)).save(out / "tree.png")
    Image.fromarray(pattern_sheet(aligned.vertices, aligned.faces, root, lengths, names)).save(
        out / "aligned_pattern.png")
    takes = [SourceClip(meta["name"], aligned.vertices[a:a + n], float(meta.get("fps", fps)), bool(meta.get("cyclic")))
             for meta, a, n in zip(metas, starts, lengths)]
    turn = capture_travel_turn(takes, aligned.faces, aligned.root_vertices, size)
    write_capture_manifest(out, {
        "aligned": True, "alignment": {"method": result.method, "root": root_label,
                                       "options": options_record, "root_trial": result.root_trial,
                                       "root_reason": result.root_reason,
                                       "input": {s["name"]: c.to_metadata() for s, c in zip(sequences, conventions)},
                                       "display_unit": display_unit(common)},
        "body": {"vertices": int(len(aligned.root_vertices)), "faces": int(len(aligned.faces)),
                 "model_size": size, "up": "+Y", "units": "m",
                 "source_units": common.units if common.units_from != "mixed" else "mixed",
                 "source_up": common.up_label if common.up_from != "mixed" else "mixed",
                 # heading 0 of every space built on this rest: where the capture travels (build)
                 "heading_turn_deg": round(float(np.degrees(turn)), 6)},
        # the first sequence's frame rate (its meta.json's, else ``fps``): the CLI and the align job agree
        "fps": float(metas[0].get("fps", fps)) if metas else fps, "sequences": metas,
    })


def root_vertices_text(kept, captured):
    """The root mesh's vertex count, and what was left out of its captured frame (``main_components``)."""
    if kept == captured:
        return f"{kept} vertices"
    return (f"{kept} of its frame's {captured} vertices: {captured - kept} left out (floating pieces, vertices "
            f"welded to a twin at the same place, vertices no face uses)")


def _file_name(source):
    """The file a frame came from, from its ``Mesh.source``: a file's name in a directory, or a zip
    member's whole path (``take1/frame_0003.obj``: one zip may hold several folders' frames)."""
    archive, sep, member = str(source).rpartition(".zip:")
    return str(PurePosixPath(member)) if sep else Path(str(source)).name


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
        staging = out.with_name(f".{out.name}.partial-{os.getpid()}")
        if staging.exists():
            shutil.rmtree(staging)
        staging.mkdir(parents=True)
        try:
            write_alignment(staging, sequences, meshes, lengths, result, fps=args.fps or DEFAULT_FPS,
                            options_record=options_record(vars(args), result.colour_cues),
                            progress=progress, conventions=conventions)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
    finally:
        progress.close()
    if out.exists():
        shutil.rmtree(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    os.replace(staging, out)
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
          f"or trusted frames; {count_text(confidence['repair_alignments'], 'alignment')} tried), "
          f"{confidence['flagged_frames']} of {frames} still below {TRUSTED} (listed per sequence in meta.json)")
    return 0


__all__ = ["add_arguments", "check_root_early", "confidence_summary", "convert_inputs",
           "flagged_by_sequence", "frame_label", "parse_root", "read_inputs", "resolve_inputs", "run",
           "write_alignment"]
