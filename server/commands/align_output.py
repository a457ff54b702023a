"""The output of an alignment (`morphspace align` and the align job): the aligned frames, their
meta.json files, alignment.npz, timings.json, the pictures and the manifest (docs/file-formats.md),
and the lines that summarise what was aligned."""

from __future__ import annotations

import json

import numpy as np

from engine.align.captures import FINE_EDGE
from engine.align.repair import TRUSTED
from engine.mesh_io import write_obj, write_sequence
from engine.mesh_io.dataset import write_capture_manifest
from engine.mesh_io.npz import savez_stable
from engine.mesh_io.units import Convention
from engine.motion_space import SourceClip
from engine.motion_space.roots import capture_travel_turn
from engine.surface import model_size
from server.commands.align_inputs import file_name, frame_label
from server.units import common_convention, display_unit

ALIGNMENT_FORMAT = "morphspace-alignment"
ALIGNMENT_VERSION = 1

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
        + ", ".join(f"{frame_label(c, sequences, lengths)} {x:.2f}"
                    for c, x in zip(race["finalists"], race["confidence"]))
        + ")")
    return (f"root tried: {len(trial['candidates'])} candidates aligned {len(trial['probes'])} probe frames each "
            f"(mean badness, lower is better: {tried}){raced}; {frame_label(chosen, sequences, lengths)} {change}")


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


def confidence_summary(aligned, sequences, lengths):
    """The per-frame confidence in a few numbers (the align job's summary, the CLI's last line):
    ``root_frame`` ("SEQUENCE:FRAME"), ``repaired_frames`` and ``flagged_frames`` (below
    ``TRUSTED``) counted over all sequences, ``repair_alignments`` (the pairwise alignments the
    repair tried, kept or not), ``repair_stopped`` (the repair's phases, "root", "others" or with
    ``graft_limbs`` "limbs", that ended early because a run of alignments had stopped mending frames), ``confidence_min``,
    ``pulled_frames`` (frames whose alignment pulled a limb onto what nothing covered,
    ``reach_limbs``), and ``flagged``: per sequence the frames (its own numbering) still below
    ``TRUSTED``."""
    return {"root_frame": frame_label(aligned.root, sequences, lengths),
            "repaired_frames": int(np.sum(aligned.repaired)),
            "repair_alignments": int(aligned.repair_spent),
            "repair_stopped": list(aligned.repair_stopped or []),
            "flagged_frames": int(np.sum(aligned.confidence < TRUSTED)),
            "confidence_min": float(np.min(aligned.confidence)),
            "pulled_frames": int(np.sum(np.asarray(aligned.pulled) > 0)) if aligned.pulled is not None else 0,
            "flagged": flagged_by_sequence(aligned, sequences, lengths)}


def stopped_text(confidence):
    """"" when no phase of the repair stopped early, else "; stopped early from the root and ...: a
    run of about 32 alignments mended fewer frames than 1 in 16 of them" for the phases in
    ``confidence["repair_stopped"]`` (:func:`confidence_summary`)."""
    from engine.align.repair import MIN_YIELD, YIELD_CHUNK

    phases = {"root": "from the root", "others": "from trusted frames", "limbs": "with grafted limbs",
              "all": "from every source"}
    stopped = [phases.get(p, p) for p in confidence.get("repair_stopped") or []]
    if not stopped:
        return ""
    return (f"; stopped early {' and '.join(stopped)}: a run of about {YIELD_CHUNK} alignments mended fewer "
            f"frames than 1 in {round(1 / MIN_YIELD)} of them")


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
            "source_files": [file_name(meshes[i].source) for i in range(starts[k], starts[k] + lengths[k])],
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
               "cpu_seconds": None if aligned.cpu_seconds is None else
               [round(float(x), 4) for x in aligned.cpu_seconds]}
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


__all__ = ["ALIGNMENT_FORMAT", "ALIGNMENT_VERSION", "OPTION_NAMES", "aligned_meta", "colour_cues_text",
           "confidence_summary", "flagged_by_sequence", "options_record", "root_trial_text", "root_vertices_text",
           "write_alignment"]
