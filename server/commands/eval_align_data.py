"""What `morphspace eval-align` scores against: a capture dataset's ground truth (in the frames'
units and axes, then in metres with +Y up), its model size, and an earlier `morphspace align`
output read back (``--aligned``)."""

from __future__ import annotations

import json
import zipfile

import numpy as np

from engine.align.similarity_tree import rooted_tree
from engine.mesh_io import read_mesh, read_sequence
from engine.mesh_io.dataset import load_capture_truth
from engine.mesh_io.errors import MeshFormatError
from engine.mesh_io.units import UNITS_PER_METRE, resolve_convention, to_metres_y_up
from engine.surface import model_size
from server.units import common_convention, declared_convention

def read_truth(dataset, sequences, picks, counts):
    """Template positions of each sequence's frames (a list, in the files' units and axes) and
    the template faces. ``picks``: per sequence, the indices of its frames that were kept
    (``picked_frames``); ``counts``: its frames in all, which its ground truth must match (a
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


def picked_frames(lengths, every, max_frames):
    """Per sequence, the frames kept: every ``every``-th from the first, at most ``max_frames``."""
    return [np.arange(0, n, every)[:max_frames] for n in lengths]


def truth_in_metres(parts, conventions):
    """The ground truth of all frames (concatenated) in metres, +Y up."""
    return np.concatenate([to_metres_y_up(P, c.units, c.up) for P, c in zip(parts, conventions)])


def read_record(path):
    """A JSON object from ``path``; {} when the file is missing, unreadable or not an object."""
    try:
        record = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        record = {}
    return record if isinstance(record, dict) else {}


def recorded_alignment(directory):
    """The ``alignment`` record of an align output's manifest ({} when it has none)."""
    alignment = read_record(directory / "manifest.json").get("alignment")
    return alignment if isinstance(alignment, dict) else {}


def part_vertex_counts(manifest):
    """The template's parts and their vertex counts (``body.parts``), or None."""
    parts = manifest.get("body", {}).get("parts")
    return parts if isinstance(parts, dict) and parts else None


def model_size_in_metres(manifest, conventions, truth):
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


def truth_conventions(dataset, manifest, aligned, names, parts, units, up):
    """Units and up axis of each sequence's ground truth, for scoring an earlier alignment: as
    given, else detected on the truth, else what the sequence's meta.json, the alignment's
    record of its input and the dataset manifest say."""
    conventions = []
    for name, positions in zip(names, parts):
        recorded = read_record(aligned / "sequences" / name / "meta.json").get("alignment") or {}
        check_given_against_record(name, aligned, recorded, units, up)
        declared = declared_convention([read_record(dataset / "sequences" / name / "meta.json"),
                                        {"units": recorded.get("source_units"), "up": recorded.get("source_up")},
                                        manifest.get("body")])
        conventions.append(resolve_convention(positions, units, up, declared_units=declared[0],
                                              declared_up=declared[1]))
    return conventions


def check_given_against_record(name, aligned, recorded, units, up):
    """A --units or --up that contradicts what the alignment recorded of a sequence's input is
    refused: the aligned frames were converted from that input, so ground truth read otherwise
    would be scored in other units or axes than the frames (nonsense errors, not a warning)."""
    plain = lambda value: str(value).strip().lower().lstrip("+")  # noqa: E731  ("+Z" and "z" are one axis)
    for flag, given, key in (("units", units, "source_units"), ("up", up, "source_up")):
        said = recorded.get(key)
        if given != "auto" and said not in (None, "", "mixed") and plain(given) != plain(said):
            raise ValueError(f"--{flag} {given}: {aligned} aligned {name} from input in {said} ({key} in its "
                             f"meta.json), so its ground truth is read in {said} too; "
                             f"leave --{flag} out with --aligned")


def tree_depth(extra, root, frames):
    """Each frame's depth in the similarity tree the frames were aligned along (``alignment.npz``'s
    ``tree_edges``; repairs change a frame's ``parent``, not its depth), or None without it."""
    if "tree_edges" not in extra:
        return None
    edges = extra["tree_edges"]
    return rooted_tree(edges, extra.get("tree_weights", np.zeros(len(edges))), root, frames).depth


def load_aligned(directory, dataset_names):
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


__all__ = ["check_given_against_record", "load_aligned", "model_size_in_metres", "part_vertex_counts",
           "picked_frames", "read_record", "read_truth", "recorded_alignment", "tree_depth", "truth_conventions",
           "truth_in_metres"]
