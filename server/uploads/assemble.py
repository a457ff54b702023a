"""From extracted files to a dataset: sequences planned from the paths, every frame read and
checked with engine.mesh_io, meta.json files checked, the files moved into the capture-dataset
layout and its manifest written (``assemble_dataset``). The files a frame refers to (an OBJ's
material library, texture images) move with it, at the same place relative to it; textures no
frame refers to are not kept."""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field

import numpy as np

from engine.mesh_io import MeshError, natural_key, read_mesh
from engine.mesh_io.texture import RESOURCE_SUFFIXES, directory_resources
from engine.mesh_io.dataset import write_capture_manifest
from engine.mesh_io.units import UNITS_PER_METRE, UP_AXES
from engine.names import is_name
from server.uploads.rules import KINDS, META_MAX_BYTES, UploadError


@dataclass
class SequencePlan:
    name: str
    frames: dict = field(default_factory=dict)  # kind (consistent / unstructured / None) -> [(name, path)]
    meta: tuple | None = None  # (upload name, path)


def _strip_wrapper(files):
    """Drop one folder that wraps every file (e.g. a zipped directory)."""
    if not files or any(len(parts) < 2 for _, parts, _ in files):
        return files
    first = {parts[0] for _, parts, _ in files}
    if len(first) != 1 or first.pop() in ("sequences", "template"):
        return files
    seconds = {parts[1] for _, parts, _ in files}
    if seconds & {"sequences", "manifest.json", "template"} or (
            all(len(parts) >= 3 for _, parts, _ in files) and not seconds & set(KINDS)):
        return [(name, parts[1:], path) for name, parts, path in files]
    return files


def plan_dataset(extracted, dataset_name):
    """Sequences, their frames and meta files, and template meshes, from the uploaded paths."""
    sequences, templates = {}, []

    def sequence(seq, name):
        if not is_name(seq):
            raise UploadError(422, f"{name}: sequence name {seq!r} must be letters, digits, '_', '-', '.'")
        return sequences.setdefault(seq, SequencePlan(seq))

    for name, parts, path in _strip_wrapper(extracted.files):
        leaf = parts[-1]
        if os.path.splitext(leaf)[1].lower() in RESOURCE_SUFFIXES:
            continue  # read through the frames that refer to them
        is_meta = leaf == "meta.json"
        if parts == ["manifest.json"]:
            continue  # the server writes its own
        if leaf == "manifest.json":
            raise UploadError(422, f"{name}: manifest.json is only read at the top of the dataset")
        if parts[0] == "template":
            if len(parts) != 2 or is_meta:
                raise UploadError(422, f"{name}: template/ holds rest meshes only (template/body.obj)")
            templates.append((name, path, parts[1]))
            continue
        if parts[0] == "sequences":
            parts = parts[1:]
            if len(parts) < 2:
                raise UploadError(422, f"{name}: expected sequences/<sequence>/<frame> or "
                                       "sequences/<sequence>/consistent/<frame>")
        if len(parts) == 1:
            seq, kind = sequence(dataset_name, name), None
        elif len(parts) == 2:
            seq, kind = sequence(parts[0], name), None
        elif len(parts) == 3 and parts[1] in KINDS and not is_meta:
            seq, kind = sequence(parts[0], name), parts[1]
        else:
            raise UploadError(422, f"{name}: unexpected location; frames go in <sequence>/ or "
                                   "<sequence>/consistent|unstructured/ (see docs/rest.md)")
        if is_meta:
            seq.meta = (name, path)
        else:
            seq.frames.setdefault(kind, []).append((name, path))
    if not sequences:
        raise UploadError(422, "the upload has no mesh frames (.obj, .ply, .off, .glb)")
    for seq in sequences.values():
        if not seq.frames:
            raise UploadError(422, f"sequence {seq.name!r} has a meta.json but no frames")
        if None in seq.frames and len(seq.frames) > 1:
            raise UploadError(422, f"sequence {seq.name!r} has frames both directly in its folder and in "
                                   "consistent/ or unstructured/; use one place")
    return sequences, templates


def read_meta(name, path, fps, cyclic):
    """A sequence's meta.json, checked: a JSON object with optional positive fps and boolean cyclic."""
    if path is None:
        return {"fps": fps, "cyclic": cyclic}
    if path.stat().st_size > META_MAX_BYTES:
        raise UploadError(422, f"{name}: larger than {META_MAX_BYTES} bytes")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UploadError(422, f"{name}: not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise UploadError(422, f"{name}: must be a JSON object")
    meta.setdefault("fps", fps)
    meta.setdefault("cyclic", cyclic)
    value = meta["fps"]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= 1000:
        raise UploadError(422, f"{name}: fps must be a number in (0, 1000], got {value!r}")
    if not isinstance(meta["cyclic"], bool):
        raise UploadError(422, f"{name}: cyclic must be true or false, got {meta['cyclic']!r}")
    if "units" in meta and str(meta["units"]).strip().lower() not in UNITS_PER_METRE:
        raise UploadError(422, f"{name}: units must be one of {', '.join(UNITS_PER_METRE)}, got {meta['units']!r}")
    if "up" in meta and str(meta["up"]).strip().lower().lstrip("+") not in UP_AXES:
        raise UploadError(422, f"{name}: up must be +Y or +Z, got {meta['up']!r}")
    return meta


@dataclass
class FrameStats:
    frames: int = 0
    vertices: int | None = None
    faces: np.ndarray | None = None
    consistent: bool = True
    first_problem: str | None = None
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    resources: dict = field(default_factory=dict)   # frame path -> names it refers to

    def add(self, mesh, label):
        V = mesh.vertices
        lo, hi = V.min(axis=0), V.max(axis=0)
        self.lo = lo if self.lo is None else np.minimum(self.lo, lo)
        self.hi = hi if self.hi is None else np.maximum(self.hi, hi)
        if self.faces is None:
            self.vertices, self.faces = len(V), mesh.faces
        elif self.consistent and (len(V) != self.vertices or not np.array_equal(mesh.faces, self.faces)):
            self.consistent = False
            self.first_problem = (f"{label}: has {len(V)} vertices and {len(mesh.faces)} faces, the first frame "
                                  f"{self.vertices} and {len(self.faces)} (or different faces)")
        self.frames += 1


def validate_frames(frames, progress=None, done=0, total=None):
    """Read every frame with engine.mesh_io; stats of the group. 422 naming the first bad frame."""
    stats = FrameStats()
    for name, path in frames:
        used = stats.resources.setdefault(path, [])
        try:
            mesh = read_mesh(path, name=name, resources=_recording(directory_resources(path, name), used))
        except MeshError as exc:
            raise UploadError(422, str(exc)) from None
        for reference in used:
            if reference.startswith("../"):
                raise UploadError(422, f"{name}: refers to {reference!r}, outside the frame's folder; keep "
                                       "textures beside the frames or in a folder below them")
        stats.add(mesh, name)
        done += 1
        if progress is not None:
            progress(done, total)
    return stats


def _recording(read, names):
    """A resource reader that also notes every name it read."""
    def recording(name):
        data = read(name)
        names.append(name)
        return data
    return recording


def move_frame(path, target, resources):
    """Move a frame file into the folder ``target`` with the files it refers to (same relative place)."""
    os.replace(path, target / path.name)
    for reference in resources:
        destination = target / reference
        if destination.exists():   # shared by an earlier frame
            continue
        destination.parent.mkdir(parents=True, exist_ok=True)
        os.replace(path.parent / reference, destination)


def sequence_meta(name, meta, kind, stats):
    meta = {k: v for k, v in meta.items() if k not in ("name", "frames", "duration", "topology", "vertices", "faces")}
    return {"name": name, **meta, "frames": stats.frames, "duration": stats.frames / float(meta["fps"]),
            "topology": kind, "vertices": stats.vertices if kind == "consistent" else None,
            "faces": int(len(stats.faces)) if kind == "consistent" else None}


def assemble_dataset(extracted, out, dataset_name, *, fps, cyclic, progress=None):
    """Validate every frame and move the files into the dataset layout under ``out``; the manifest."""
    sequences, templates = plan_dataset(extracted, dataset_name)
    total = sum(len(frames) for seq in sequences.values() for frames in seq.frames.values()) + len(templates)
    done = 0
    metas, lo, hi = [], None, None
    for seq_name in sorted(sequences, key=natural_key):
        seq = sequences[seq_name]
        meta = read_meta(*(seq.meta or (None, None)), fps, cyclic)
        kinds = {}
        for kind, frames in seq.frames.items():
            frames.sort(key=lambda item: natural_key(item[0]))
            stats = validate_frames(frames, progress, done, total)
            done += stats.frames
            if kind == "consistent" and not stats.consistent:
                raise UploadError(422, f"{stats.first_problem}; frames in consistent/ must share one mesh structure")
            kind = kind or ("consistent" if stats.consistent else "unstructured")
            if kind in kinds:
                raise UploadError(422, f"sequence {seq_name!r}: {kind} frames given twice")
            kinds[kind] = stats
            target = out / "sequences" / seq_name / kind
            target.mkdir(parents=True)
            for _, path in frames:
                move_frame(path, target, stats.resources.get(path, ()))
            lo = stats.lo if lo is None else np.minimum(lo, stats.lo)
            hi = stats.hi if hi is None else np.maximum(hi, stats.hi)
        if len(kinds) > 1 and kinds["consistent"].frames != kinds["unstructured"].frames:
            raise UploadError(422, f"sequence {seq_name!r}: consistent/ has {kinds['consistent'].frames} frames and "
                                   f"unstructured/ {kinds['unstructured'].frames}; both hold the same take, frame by frame")
        main = "consistent" if "consistent" in kinds else "unstructured"
        record = sequence_meta(seq_name, meta, main, kinds[main])
        if len(kinds) > 1:
            record["unstructured_frames"] = kinds["unstructured"].frames
        (out / "sequences" / seq_name / "meta.json").write_text(json.dumps(record, indent=2) + "\n")
        metas.append(record)
    for name, path, leaf in templates:
        stats = validate_frames([(name, path)])
        (out / "template").mkdir(exist_ok=True)
        move_frame(path, out / "template", stats.resources.get(path, ()))
    write_capture_manifest(out, {"uploaded": True, "created": time.time(), "fps": fps,
                                 "bounds": [lo.tolist(), hi.tolist()], "sequences": metas})
    return out
