"""Datasets on disk: publishing and removing them atomically, listing and describing them, their
alignment pictures, and cleaning what a crashed server left behind."""

from __future__ import annotations

import json
import os
import shutil
import time
import uuid
from pathlib import Path, PurePosixPath

from engine.mesh_io import MESH_EXTENSIONS, natural_key
from engine.mesh_io.dataset import DATASET_FORMAT
from engine.names import NAME, is_name
from server.uploads.rules import KINDS, STAGING_PREFIX, TRASH_PREFIX, UploadError, dataset_path


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
    """Remove upload staging and trash directories left by a crashed server: trash always, the
    staging of a receiving process that no longer runs (its id is in the name), and any staging
    older than ``older_than`` seconds (a process id the system gave to another process since)."""
    if not settings.datasets_dir.is_dir():
        return 0
    removed, now = 0, time.time()
    for entry in settings.datasets_dir.iterdir():
        if entry.name.startswith((STAGING_PREFIX, TRASH_PREFIX)):
            try:
                if (entry.name.startswith(TRASH_PREFIX) or not _receiver_alive(entry.name)
                        or now - entry.stat().st_mtime > older_than):
                    shutil.rmtree(entry, ignore_errors=True)
                    removed += 1
            except FileNotFoundError:
                pass
    return removed


def _receiver_alive(name):
    """Whether the process whose id a staging directory's name carries (``.upload-PID-ID``) runs."""
    pid, sep, _ = name[len(STAGING_PREFIX):].partition("-")
    if not sep or not pid.isdigit():
        return False   # a name without a process id: made before ids were kept, so by a process now gone
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # another user's process of that id: running
        return True
    return True


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
    if not is_name(name):
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
        raise UploadError(409, f"dataset {name!r} has no readable manifest.json "
                               f"({str(exc).replace(f'{settings.datasets_dir}/', '')})") from None
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
