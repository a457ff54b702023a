"""On-disk layout of a capture dataset with ground truth (written by ``morphspace synth``).

```
DATASET/
  manifest.json                 format, preset, body, fps, model size, sequence list + metadata
  template/body.obj             rest surface (A-pose) with vertex colours
  template/body.npz             skin weights, segments, hand vertex ids, skeleton rest pose
  sequences/<name>/consistent/frame_0000.obj ...    template topology every frame (micrometres)
  sequences/<name>/unstructured/frame_0000.ply ...  independently re-meshed frames
  sequences/<name>/truth.npz    root trajectory, joints, template_positions (frames, n, 3)
  sequences/<name>/meta.json    requested and measured parameters, events
  previews/<name>.png           rendered strips
```
Everything is written atomically (temporary name, then rename).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from engine.mesh_io.atomic import atomic_write
from engine.mesh_io.errors import MeshFormatError
from engine.mesh_io.npz import savez_stable

DATASET_FORMAT = "morphspace-capture-dataset"
DATASET_VERSION = 1


def _write_json(path, payload):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as fh:  # (mode 0666 less the umask, like every other file of a dataset)
        fh.write((json.dumps(payload, indent=2, sort_keys=False) + "\n").encode())


def _write_npz(path, arrays):
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as fh:
        savez_stable(fh, arrays)


def sequence_dir(root, name):
    """Directory of sequence ``name`` inside dataset ``root``."""
    return Path(root) / "sequences" / name


def write_capture_sequence(root, name, *, faces, vertices, colors, unstructured, truth, meta,
                           consistent_format="obj", unstructured_format="ply", textured=False, progress=None):
    """Write one sequence: consistent frames, unstructured frames, truth.npz and meta.json.

    Parameters
    ----------
    root : path                          dataset directory
    name : str                           sequence name (a directory name)
    faces : (m, 3) int array             template faces
    vertices : (frames, n, 3) float      consistent-topology frames
    colors : (n, 3) float or None        template vertex colours
    unstructured : list of (V, F, colors) or None
    textured : bool                      unstructured frames with colours are written with their
                                         colours as a texture atlas (``atlas.write_textured``)
    truth : dict of arrays               saved to truth.npz (no pickles)
    meta : dict                          saved to meta.json
    """
    from engine.mesh_io import write_obj, write_ply
    from engine.mesh_io.atlas import write_textured

    writers = {"obj": lambda path, V, F, colors: write_obj(path, V, F, colors=colors, precision=6),
               "ply": write_ply}
    for fmt in (consistent_format, unstructured_format):
        if fmt not in writers:
            raise ValueError(f"unsupported output format {fmt!r}; choose obj or ply")
    base = sequence_dir(root, name)
    total = len(vertices) + (len(unstructured) if unstructured else 0)
    done = 0
    for k, V in enumerate(vertices):
        writers[consistent_format](base / "consistent" / f"frame_{k:04d}.{consistent_format}", V, faces,
                                   colors=colors)
        done += 1
        if progress is not None:
            progress(done, total)
    for k, (V, F, C) in enumerate(unstructured or ()):
        write = write_textured if textured and C is not None else writers[unstructured_format]
        write(base / "unstructured" / f"frame_{k:04d}.{unstructured_format}", V, F, colors=C)
        done += 1
        if progress is not None:
            progress(done, total)
    _write_npz(base / "truth.npz", {k: np.asarray(v) for k, v in truth.items()})
    _write_json(base / "meta.json", meta)
    return base


def write_capture_template(root, body):
    """Write the rest body (OBJ with colours) and its rig (npz) under ``root/template``."""
    from engine.mesh_io import write_obj

    write_obj(Path(root) / "template" / "body.obj", body.V, body.F, colors=body.colors)
    _write_npz(Path(root) / "template" / "body.npz", {
        "vertices": body.V, "faces": body.F, "weight_index": body.weight_index, "weight": body.weight,
        "segment": body.segment, "soft_tissue": body.soft_tissue, "garment": body.garment,
        "colors": body.colors, "hand_l": body.hand_vertices("l"), "hand_r": body.hand_vertices("r"),
        "joint_rest": body.skeleton.rest, "joint_parents": body.skeleton.parents,
        "joint_names": np.array(body.skeleton.names),
    })


def write_capture_manifest(root, manifest):
    """Write ``manifest.json`` (adds the format name and version)."""
    payload = {"format": DATASET_FORMAT, "version": DATASET_VERSION, **manifest}
    _write_json(Path(root) / "manifest.json", payload)


def read_capture_manifest(root):
    """Read and check a dataset's manifest.

    Raises
    ------
    MeshFormatError   missing, unreadable, foreign or newer-version manifest
    """
    path = Path(root) / "manifest.json"
    if not path.is_file():
        raise MeshFormatError(f"{path}: no capture-dataset manifest here (expected manifest.json)")
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MeshFormatError(f"{path}: unreadable manifest: {exc}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != DATASET_FORMAT:
        raise MeshFormatError(f"{path}: not a morphspace capture dataset (format {manifest.get('format')!r})"
                              if isinstance(manifest, dict) else f"{path}: not a JSON object")
    sequences = manifest.get("sequences", [])
    if not isinstance(sequences, list) or not all(isinstance(q, dict) and isinstance(q.get("name"), str)
                                                  for q in sequences):
        raise MeshFormatError(f"{path}: 'sequences' must be a list of objects with a 'name'")
    if manifest.get("version", 0) > DATASET_VERSION:
        raise MeshFormatError(f"{path}: dataset version {manifest['version']} is newer than this "
                              f"morphspace understands ({DATASET_VERSION})")
    return manifest


def load_capture_truth(root, name):
    """Ground-truth arrays of sequence ``name`` as a dict (never unpickled)."""
    path = sequence_dir(root, name) / "truth.npz"
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except FileNotFoundError:
        raise MeshFormatError(f"{path}: no ground truth for sequence {name!r}") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise MeshFormatError(f"{path}: unreadable ground truth: {exc}") from None
