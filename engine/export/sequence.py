"""A played clip as a mesh sequence: one OBJ or PLY file per frame, in world coordinates.

``write_mesh_sequence(directory, frames, "obj")`` writes ``frame_0000.obj`` ... (the player's
placed vertices: root transform applied) with the project's writers (engine.mesh_io), plus
``clip.json``: the frame times, root positions, headings and realised parameters. OBJ
coordinates have 6 decimals (micrometres); PLY is binary float32 (exact). A ``.zip`` path
writes the same files into one zip archive (deflated) instead of a directory.
"""

from __future__ import annotations

import json
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from engine.mesh_io import write_obj, write_ply
from engine.mesh_io.atomic import atomic_write, discard_partial

SEQUENCE_FORMATS = ("obj", "ply")
OBJ_DECIMALS = 6


def clip_record(frames):
    """The JSON sidecar of a sequence: what each frame is."""
    record = {"space": frames.space, "rate": frames.rate, "frames": len(frames), "coordinates": "world",
              "units": "m", "up": "+Y", "parameters": list(frames.names), "notes": list(frames.notes),
              "times": np.round(frames.times, 9).tolist(),
              "root_position": np.round(frames.root_position, 9).tolist(),
              "heading_deg": np.round(np.degrees(frames.heading), 9).tolist(),
              "realised": [[None if np.isnan(x) else x for x in row] for row in np.round(frames.params, 9).tolist()]}
    if frames.nodes is not None:  # a graph performance: the node of each frame; realised is null off it
        record["nodes"] = list(frames.nodes)
    return record


MESH_SUFFIXES = (".obj", ".ply", ".off", ".glb")  # mesh files a frame directory must not mix in


def write_mesh_sequence(directory, frames, format="obj", progress=None):
    """Write every frame of ``frames`` (ClipFrames) as ``{directory}/frame_{k:04d}.{format}``.

    The directory must not hold other mesh files (reading it back would mix them in).
    Returns the list of paths written (frames, then clip.json).
    """
    if format not in SEQUENCE_FORMATS:
        raise ValueError(f"sequence format must be one of {', '.join(SEQUENCE_FORMATS)}, not {format!r}")
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ValueError(f"{directory}: exists and is not a directory")
    digits = max(4, len(str(len(frames) - 1)))
    names = [f"frame_{k:0{digits}d}.{format}" for k in range(len(frames))]
    if directory.is_dir():
        stale = sorted(p.name for p in directory.iterdir() if p.suffix.lower() in MESH_SUFFIXES
                       and p.name not in set(names))
        if stale:
            raise ValueError(f"{directory}: already holds {len(stale)} other mesh files (e.g. {stale[0]}); export "
                             f"into an empty directory")
    created = not directory.exists()
    F = frames.faces
    paths = []
    try:
        directory.mkdir(parents=True, exist_ok=True)
        for k, name in enumerate(names):
            if format == "obj":
                write_obj(directory / name, frames.world(k), F, precision=OBJ_DECIMALS)
            else:
                write_ply(directory / name, frames.world(k), F)
            paths.append(directory / name)
            if progress is not None and (k % 16 == 15 or k == len(frames) - 1):
                progress(k + 1, len(frames))
        with atomic_write(directory / "clip.json") as file:
            file.write(json.dumps(clip_record(frames), indent=1).encode())
    except BaseException:  # interrupted or failed: no half-written sequence stays behind (the frame being
        # written too, and its hidden temporary: left, they kept the directory from going)
        started = names[:len(paths) + 1] + (["clip.json"] if len(paths) == len(names) else [])
        discard_partial(directory, started, created)
        raise
    return paths + [directory / "clip.json"]


def write_sequence_zip(path, frames, format="obj", progress=None):
    """The same files as ``write_mesh_sequence``, in one zip archive at ``path`` (written atomically)."""
    with tempfile.TemporaryDirectory(prefix=".morphspace-export-", dir=Path(path).parent) as scratch:
        files = write_mesh_sequence(Path(scratch) / "clip", frames, format, progress)
        with atomic_write(path) as out, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED, compresslevel=6) as archive:
            for file in files:
                write_member(archive, file.name, file.read_bytes())
    return path


ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # every member's timestamp: the same clip gives the same archive, byte for byte


def write_member(archive, name, data):
    """Add ``data`` to the open ``archive`` as ``name``, stamped ``ZIP_TIME`` (not the time of
    writing) with mode 0644, compressed as the archive is."""
    info = zipfile.ZipInfo(name, date_time=ZIP_TIME)
    info.compress_type = archive.compression
    info.external_attr = 0o644 << 16
    archive.writestr(info, data, compresslevel=archive.compresslevel)
