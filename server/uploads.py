"""Capture datasets on the server: safe uploads, the on-disk layout, descriptions.

An upload (a zip body, or multipart/form-data whose parts are files named by their relative
path) becomes ``data_dir/datasets/<name>/`` in the capture-dataset layout that ``morphspace
build --source`` and ``morphspace align`` read (engine/mesh_io/dataset.py)::

    <name>/manifest.json                          format, sequences (written here)
    <name>/template/<mesh>                        optional rest mesh(es), e.g. template/body.obj
    <name>/sequences/<seq>/meta.json              name, fps, cyclic, frames, topology, ...
    <name>/sequences/<seq>/consistent/<frames>    frames sharing one mesh structure, or
    <name>/sequences/<seq>/unstructured/<frames>  frames with a mesh each (align them first)

Accepted upload layouts (one folder wrapping everything is stripped): ``<seq>/<frame>`` (a folder
per sequence), ``<seq>/{consistent,unstructured}/<frame>``, the capture-dataset layout above,
or frames at the top level (one sequence named like the dataset). ``<seq>/meta.json`` may give
``fps`` and ``cyclic`` (defaults from the request). Hidden files and ``__MACOSX/`` are skipped;
any other file type, a path that is absolute or has ``..``, a symlink, a name with unusual
characters, too many files or bytes, or a compression ratio typical of a zip bomb is refused
with a 4xx naming the file. Every frame is read with engine.mesh_io before the dataset becomes
visible: the upload is assembled in ``datasets/.upload-<id>/`` and renamed into place, so a
failed or partial upload never shows.

Nothing here imports FastAPI: errors are ``UploadError(status, message)``.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import shutil
import stat
import time
import uuid
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np

from engine.mesh_io import MESH_EXTENSIONS, MeshError, natural_key, read_mesh
from engine.mesh_io.dataset import DATASET_FORMAT, write_capture_manifest

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
PART = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.@+=,() -]{0,127}$")
KINDS = ("consistent", "unstructured")
MAX_DEPTH = 5
ZIP_MAX_RATIO = 100  # uncompressed / compressed, for members over ZIP_RATIO_FLOOR bytes
ZIP_RATIO_FLOOR = 1 << 20
META_MAX_BYTES = 64 * 1024
CHUNK = 1 << 20
STAGING_PREFIX = ".upload-"
TRASH_PREFIX = ".trash-"


class UploadError(Exception):
    """A refused upload or dataset request: HTTP ``status`` and a message naming the problem."""

    def __init__(self, status, message):
        super().__init__(message)
        self.status, self.message = status, message


@dataclass
class Limits:
    max_bytes: int
    max_files: int
    max_unpacked: int

    @classmethod
    def from_settings(cls, settings):
        return cls(settings.max_upload_bytes, settings.max_upload_files, settings.max_unpacked_bytes)


def check_name(name, what="dataset"):
    if not isinstance(name, str) or not NAME.match(name) or ".." in name:
        raise UploadError(422, f"{name!r} is not a valid {what} name: use letters, digits, '_', '-', '.' "
                               "(at most 128, not starting with '.')")
    return name


def dataset_path(settings, name):
    return settings.datasets_dir / check_name(name)


# --- paths inside an upload ----------------------------------------------------------------------
def member_parts(name):
    """Path parts of an uploaded file's relative name, or None for a skipped (hidden) file.

    Raises UploadError(400) for absolute paths, drive letters, backslashes, '..' and empty parts,
    and 422 for names with unusual characters or too deep.
    """
    if not name or "\x00" in name:
        raise UploadError(400, f"{name!r}: empty or NUL in a file name")
    if "\\" in name:
        raise UploadError(400, f"{name}: backslash in a path; use '/' between folders")
    if name.startswith("/") or re.match(r"^[A-Za-z]:", name):
        raise UploadError(400, f"{name}: absolute paths are not allowed in an upload")
    parts = name.rstrip("/").split("/")
    if any(part in ("..", ".") for part in parts):
        raise UploadError(400, f"{name}: '..' or '.' in a path is not allowed (it could point outside the dataset)")
    if any(part == "" for part in parts):
        raise UploadError(400, f"{name}: empty folder name in the path")
    if any(part.startswith(".") or part == "__MACOSX" for part in parts):
        return None
    for part in parts:
        if not PART.match(part):
            raise UploadError(422, f"{name}: {part!r} has characters other than letters, digits, space and "
                                   "_ - . @ + = , ( ) (or is longer than 128)")
    if len(parts) > MAX_DEPTH:
        raise UploadError(422, f"{name}: nested {len(parts)} folders deep; see the accepted layouts in docs/rest.md")
    return parts


def file_role(parts, name):
    """'mesh' or 'json'; any other file type is refused (422)."""
    suffix = PurePosixPath(parts[-1]).suffix.lower()
    if suffix in MESH_EXTENSIONS:
        return "mesh"
    if suffix == ".json":
        if parts[-1] not in ("meta.json", "manifest.json"):
            raise UploadError(422, f"{name}: unexpected JSON file; only <sequence>/meta.json and manifest.json are read")
        return "json"
    raise UploadError(422, f"{name}: unsupported file type {suffix or '(none)'!r}; a dataset holds mesh frames "
                           f"({', '.join(MESH_EXTENSIONS)}) and meta.json files")


# --- receiving the body ---------------------------------------------------------------------------
async def receive_body(request, path, limits):
    """Stream the request body to ``path``; 413 as soon as it passes ``limits.max_bytes``."""
    declared = request.headers.get("content-length")
    if declared is not None:
        try:
            declared = int(declared)
        except ValueError:
            raise UploadError(400, f"Content-Length {declared!r} is not a number") from None
        if declared > limits.max_bytes:
            raise UploadError(413, f"the upload is {declared} bytes; the limit is {limits.max_bytes} bytes "
                                   "(MORPHSPACE_MAX_UPLOAD_BYTES)")
    size = 0
    with open(path, "xb") as out:
        async for chunk in request.stream():
            size += len(chunk)
            if size > limits.max_bytes:
                raise UploadError(413, f"the upload passed the limit of {limits.max_bytes} bytes "
                                       "(MORPHSPACE_MAX_UPLOAD_BYTES)")
            out.write(chunk)
    if size == 0:
        raise UploadError(400, "the upload is empty: send a zip archive or multipart/form-data files")
    return size


@dataclass
class Extracted:
    root: Path
    files: list = field(default_factory=list)  # (relative name, parts, path on disk)
    bytes: int = 0

    def add(self, name, parts, limits):
        path = self.target(parts)
        self.files.append((name, parts, path))
        if len(self.files) > limits.max_files:
            raise UploadError(413, f"more than {limits.max_files} files in the upload (MORPHSPACE_MAX_UPLOAD_FILES)")
        return path

    def target(self, parts):
        path = self.root.joinpath(*parts)
        if not path.resolve().is_relative_to(self.root.resolve()):  # belt and braces: parts are checked
            raise UploadError(400, f"{'/'.join(parts)}: resolves outside the dataset")
        return path


def _open_new(path, name):
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return open(path, "xb")
    except FileExistsError:
        raise UploadError(400, f"{name}: the same file appears twice in the upload") from None
    except (NotADirectoryError, IsADirectoryError):
        raise UploadError(400, f"{name}: a file and a folder have the same name") from None


def extract_zip(body, root, limits):
    """Check every member's name, type and declared size, then extract counting real bytes."""
    try:
        archive = zipfile.ZipFile(body)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, ValueError) as exc:
        raise UploadError(400, f"the upload is not a readable zip archive ({exc})") from None
    out = Extracted(root)
    with archive:
        infos = archive.infolist()
        if len(infos) > 2 * limits.max_files + 1000:
            raise UploadError(413, f"the zip has {len(infos)} entries; at most {limits.max_files} files are "
                                   "accepted (MORPHSPACE_MAX_UPLOAD_FILES)")
        members, declared = [], 0
        for info in infos:
            name = info.filename
            if stat.S_ISLNK(info.external_attr >> 16):
                raise UploadError(400, f"{name}: symbolic links are not allowed in an upload")
            parts = member_parts(name)
            if parts is None or info.is_dir():
                continue
            file_role(parts, name)
            if info.flag_bits & 0x1:
                raise UploadError(400, f"{name}: encrypted zip members are not supported")
            if info.file_size > ZIP_RATIO_FLOOR and info.file_size > ZIP_MAX_RATIO * max(info.compress_size, 1):
                raise UploadError(413, f"{name}: compression ratio {info.file_size / max(info.compress_size, 1):.0f}:1 "
                                       f"is over {ZIP_MAX_RATIO}:1 (refused as a likely zip bomb)")
            declared += info.file_size
            if declared > limits.max_unpacked:
                raise UploadError(413, f"the zip unpacks to more than {limits.max_unpacked} bytes "
                                       "(MORPHSPACE_MAX_UNPACKED_BYTES)")
            members.append((info, out.add(name, parts, limits)))
        for info, path in members:
            name = info.filename
            written = 0
            with _open_new(path, name) as dst:
                try:
                    with archive.open(info) as src:
                        while chunk := src.read(CHUNK):
                            written += len(chunk)
                            out.bytes += len(chunk)
                            if written > info.file_size:
                                raise UploadError(400, f"{name}: more data than the zip declares "
                                                       f"({info.file_size} bytes); refused as a zip bomb")
                            if out.bytes > limits.max_unpacked:
                                raise UploadError(413, f"the zip unpacks to more than {limits.max_unpacked} bytes "
                                                       "(MORPHSPACE_MAX_UNPACKED_BYTES)")
                            dst.write(chunk)
                except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as exc:
                    raise UploadError(400, f"{name}: cannot extract the zip member ({exc})") from None
    return out


def extract_multipart(body, content_type, root, limits):
    """Write each file part (named by its relative path) under ``root``; a lone .zip part is unzipped."""
    from python_multipart.multipart import MultipartParser, parse_options_header

    _, options = parse_options_header(content_type)
    boundary = options.get(b"boundary")
    if not boundary:
        raise UploadError(400, "multipart/form-data without a boundary")
    out = Extracted(root)
    state = {"headers": {}, "field": b"", "value": b"", "file": None, "parts": None, "name": None, "count": 0,
             "zip": None}

    def on_part_begin():
        state["headers"], state["file"], state["parts"] = {}, None, None

    def on_header_field(data, start, end):
        state["field"] += data[start:end]

    def on_header_value(data, start, end):
        state["value"] += data[start:end]

    def on_header_end():
        state["headers"][state["field"].decode("latin-1").lower()] = state["value"].decode("utf-8", "replace")
        state["field"], state["value"] = b"", b""

    def on_headers_finished():
        state["count"] += 1
        _, disposition = parse_options_header(state["headers"].get("content-disposition", ""))
        filename = disposition.get(b"filename")
        if filename is None:
            field_name = disposition.get(b"name", b"?").decode("utf-8", "replace")
            raise UploadError(400, f"form field {field_name!r} is not a file; every part must be a file whose "
                                   "filename is its path in the dataset (e.g. walk/frame_0001.obj)")
        name = filename.decode("utf-8", "replace")
        if name.lower().endswith(".zip") and "/" not in name:
            if state["count"] > 1 or state["zip"] is not None:
                raise UploadError(400, f"{name}: a zip must be the only part of a multipart upload")
            state["zip"] = root.parent / "nested.zip"
            state["name"], state["file"] = name, open(state["zip"], "xb")
            return
        if state["zip"] is not None:
            raise UploadError(400, f"{name}: a zip must be the only part of a multipart upload")
        parts = member_parts(name)
        state["name"] = name
        if parts is None:
            return  # hidden file: skipped
        file_role(parts, name)
        state["parts"] = parts
        state["file"] = _open_new(out.add(name, parts, limits), name)

    def on_part_data(data, start, end):
        if state["file"] is not None:
            out.bytes += end - start
            if out.bytes > limits.max_unpacked:
                raise UploadError(413, f"the upload has more than {limits.max_unpacked} bytes of files "
                                       "(MORPHSPACE_MAX_UNPACKED_BYTES)")
            state["file"].write(data[start:end])

    def on_part_end():
        if state["file"] is not None:
            state["file"].close()
            state["file"] = None

    parser = MultipartParser(boundary, {
        "on_part_begin": on_part_begin, "on_header_field": on_header_field, "on_header_value": on_header_value,
        "on_header_end": on_header_end, "on_headers_finished": on_headers_finished,
        "on_part_data": on_part_data, "on_part_end": on_part_end})
    try:
        with open(body, "rb") as src:
            while chunk := src.read(CHUNK):
                parser.write(chunk)
        parser.finalize()
    except UploadError:
        raise
    except Exception as exc:  # python-multipart raises its own parse errors (and ValueError)
        raise UploadError(400, f"malformed multipart/form-data body ({exc})") from None
    finally:
        if state["file"] is not None:
            state["file"].close()
    if state["zip"] is not None:
        return extract_zip(state["zip"], root, limits)
    if state["count"] == 0:
        raise UploadError(400, "the multipart body has no parts")
    return out


# --- from uploaded files to a dataset -------------------------------------------------------------
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
        if not NAME.match(seq) or ".." in seq:
            raise UploadError(422, f"{name}: sequence name {seq!r} must be letters, digits, '_', '-', '.'")
        return sequences.setdefault(seq, SequencePlan(seq))

    for name, parts, path in _strip_wrapper(extracted.files):
        leaf = parts[-1]
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
        try:
            mesh = read_mesh(path, name=name)
        except MeshError as exc:
            raise UploadError(422, str(exc)) from None
        stats.add(mesh, name)
        done += 1
        if progress is not None:
            progress(done, total)
    return stats


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
                os.replace(path, target / path.name)
            lo = stats.lo if lo is None else np.minimum(lo, stats.lo)
            hi = stats.hi if hi is None else np.maximum(hi, stats.hi)
        main = "consistent" if "consistent" in kinds else "unstructured"
        record = sequence_meta(seq_name, meta, main, kinds[main])
        if len(kinds) > 1:
            record["unstructured_frames"] = kinds["unstructured"].frames
        (out / "sequences" / seq_name / "meta.json").write_text(json.dumps(record, indent=2) + "\n")
        metas.append(record)
    for name, path, leaf in templates:
        validate_frames([(name, path)])
        (out / "template").mkdir(exist_ok=True)
        os.replace(path, out / "template" / leaf)
    write_capture_manifest(out, {"uploaded": True, "created": time.time(), "fps": fps,
                                 "bounds": [lo.tolist(), hi.tolist()], "sequences": metas})
    return out


# --- datasets on disk ------------------------------------------------------------------------------
def publish_dir(staging, target, *, replace=False):
    """Rename a finished directory into place; with ``replace`` swap out an existing one."""
    target = Path(target)
    if target.exists():
        if not replace:
            raise UploadError(409, f"dataset {target.name!r} already exists (pass replace=true to replace it)")
        trash = target.with_name(f"{TRASH_PREFIX}{uuid.uuid4().hex[:12]}")
        os.rename(target, trash)
        os.rename(staging, target)
        shutil.rmtree(trash, ignore_errors=True)
        return
    try:
        os.rename(staging, target)
    except OSError as exc:  # another upload of the same name won the race
        raise UploadError(409, f"dataset {target.name!r} already exists ({exc.strerror})") from None


def remove_dir(path):
    """Make a directory vanish at once (rename to a hidden name), then delete it. A link to a
    directory (scripts/demo publishes its captures so) is removed, not what it points to."""
    if path.is_symlink():
        path.unlink()
        return
    trash = path.with_name(f"{TRASH_PREFIX}{uuid.uuid4().hex[:12]}")
    os.rename(path, trash)
    shutil.rmtree(trash, ignore_errors=True)


def clean_stale(settings, older_than=3600.0):
    """Remove upload staging and trash directories left by a crashed server."""
    if not settings.datasets_dir.is_dir():
        return 0
    removed, now = 0, time.time()
    for entry in settings.datasets_dir.iterdir():
        if entry.name.startswith((STAGING_PREFIX, TRASH_PREFIX)):
            try:
                if now - entry.stat().st_mtime > older_than or entry.name.startswith(TRASH_PREFIX):
                    shutil.rmtree(entry, ignore_errors=True)
                    removed += 1
            except FileNotFoundError:
                pass
    return removed


def _mesh_count(directory):
    try:
        return sum(1 for e in os.scandir(directory)
                   if e.is_file() and not e.name.startswith(".") and PurePosixPath(e.name).suffix.lower() in MESH_EXTENSIONS)
    except OSError:
        return 0


def _directory_bytes(directory):
    total = 0
    for base, _, files in os.walk(directory):
        for name in files:
            try:
                total += os.lstat(os.path.join(base, name)).st_size
            except OSError:
                pass
    return total


def dataset_names(settings):
    directory = settings.datasets_dir
    if not directory.is_dir():
        return []
    return sorted((p.name for p in directory.iterdir() if p.is_dir() and NAME.match(p.name)), key=natural_key)


def describe_dataset(settings, name):
    """JSON-ready description read from disk: sequences (frames, topology, fps), templates, bytes."""
    if not isinstance(name, str) or not NAME.match(name) or ".." in name:
        raise UploadError(404, f"no dataset {name!r}")
    root = settings.datasets_dir / name
    if not root.is_dir():
        raise UploadError(404, f"no dataset {name!r} (have: {', '.join(dataset_names(settings)) or 'none'})")
    manifest_path = root / "manifest.json"
    try:
        manifest = json.loads(manifest_path.read_text())
        if not isinstance(manifest, dict) or manifest.get("format") != DATASET_FORMAT:
            raise ValueError(f"format {manifest.get('format') if isinstance(manifest, dict) else None!r}")
    except (OSError, ValueError) as exc:
        raise UploadError(409, f"dataset {name!r} has no readable manifest.json ({exc})") from None
    sequences = []
    seq_root = root / "sequences"
    names = sorted((p.name for p in seq_root.iterdir() if p.is_dir() and NAME.match(p.name)), key=natural_key) \
        if seq_root.is_dir() else []
    for seq in names:
        base = seq_root / seq
        try:
            meta = json.loads((base / "meta.json").read_text())
        except (OSError, ValueError):
            meta = {}
        kinds = {kind: _mesh_count(base / kind) for kind in KINDS if (base / kind).is_dir()}
        fps = meta.get("fps")
        sequences.append({
            "name": seq,
            "frames": kinds.get("consistent", kinds.get("unstructured", 0)),
            "consistent_frames": kinds.get("consistent", 0),
            "unstructured_frames": kinds.get("unstructured", 0),
            "fps": float(fps) if isinstance(fps, (int, float)) else None,
            "cyclic": bool(meta.get("cyclic", False)),
            "vertices": meta.get("vertices") if isinstance(meta.get("vertices"), int) else None,
        })
    templates = sorted(p.name for p in (root / "template").iterdir()
                       if PurePosixPath(p.name).suffix.lower() in MESH_EXTENSIONS) if (root / "template").is_dir() else []
    return {
        "name": name,
        "kind": "aligned" if manifest.get("aligned") else ("uploaded" if manifest.get("uploaded") else "capture"),
        "created": manifest.get("created", root.stat().st_mtime),
        "sequences": sequences,
        "templates": templates,
        "frames": sum(s["frames"] for s in sequences),
        "bytes": _directory_bytes(root),
        "buildable": [s["name"] for s in sequences if s["consistent_frames"] > 0],
        "pictures": [p for p in PICTURES if (root / p).is_file()],
    }


# The pictures an align job (morphspace align) writes into its dataset: figs. 1c, 1d and 2.
PICTURES = {"similarity.png": "shape dissimilarity matrix", "tree.png": "shape similarity tree",
            "aligned_pattern.png": "a pattern fixed on the root mesh, carried by the alignment"}


def picture_path(settings, name, picture):
    """The file of one of a dataset's alignment pictures (PICTURES); UploadError 404 otherwise."""
    if picture not in PICTURES:
        raise UploadError(404, f"no picture {picture!r}: a dataset may have {', '.join(PICTURES)}")
    path = dataset_path(settings, name) / picture
    if not path.is_file():
        raise UploadError(404, f"dataset {name!r} has no {picture} (only aligned datasets have pictures)")
    return path


def sequence_names(settings, name):
    root = dataset_path(settings, name) / "sequences"
    return sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else []


# --- the whole upload ------------------------------------------------------------------------------
ZIP_TYPES = ("application/zip", "application/x-zip-compressed", "application/x-zip", "application/octet-stream", "")


def _unpack(staging, content_type, target, name, limits, *, fps, cyclic, replace):
    media = content_type.split(";")[0].strip().lower()
    body = staging / "body"
    raw = staging / "raw"
    raw.mkdir()
    if media == "multipart/form-data":
        extracted = extract_multipart(body, content_type, raw, limits)
    elif media in ZIP_TYPES:
        with open(body, "rb") as fh:
            magic = fh.read(4)
        if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
            raise UploadError(400, f"the upload is not a zip archive (it starts with {magic!r}); send a zip or "
                                   "multipart/form-data files")
        extracted = extract_zip(body, raw, limits)
    else:
        raise UploadError(415, f"unsupported Content-Type {media!r}: send application/zip or multipart/form-data")
    body.unlink()
    dataset = assemble_dataset(extracted, staging / "dataset", name, fps=fps, cyclic=cyclic)
    publish_dir(dataset, target, replace=replace)


async def receive_dataset(request, settings, *, name, fps=30.0, cyclic=False, replace=False, busy=None):
    """Receive, check, validate and publish one dataset upload; returns its description.

    ``busy(name)`` says whether a queued or running job uses the dataset (then it cannot be replaced).
    """
    target = dataset_path(settings, name)
    if target.exists() and not replace:
        raise UploadError(409, f"dataset {name!r} already exists (pass replace=true to replace it)")
    if target.exists() and busy is not None and busy(name):
        raise UploadError(409, f"dataset {name!r} is used by a queued or running job; it cannot be replaced now")
    limits = Limits.from_settings(settings)
    settings.datasets_dir.mkdir(parents=True, exist_ok=True)
    staging = settings.datasets_dir / f"{STAGING_PREFIX}{uuid.uuid4().hex[:12]}"
    staging.mkdir()
    try:
        await receive_body(request, staging / "body", limits)
        await asyncio.to_thread(_unpack, staging, request.headers.get("content-type", ""), target, name, limits,
                                fps=fps, cyclic=cyclic, replace=replace)
    finally:
        await asyncio.to_thread(shutil.rmtree, staging, True)
    return describe_dataset(settings, name)
