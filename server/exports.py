"""Exports over REST: a request (server.jobs.models.ExportSpec) -> a played clip -> a file.

The synchronous endpoint (server/api/exports.py) runs ``ExportBlenders.export_bytes`` in a
thread with blenders of its own (the streams' blenders keep scratch buffers and are used on the
event loop); the ``export`` job runs ``run_export`` in a worker process and publishes the file
into ``exports/`` under the data directory, served by ``GET /v1/exports/{file}``.
"""

from __future__ import annotations

import tempfile
import threading
import time
from collections import OrderedDict
from pathlib import Path

from engine.export import Clip, play_clip, write_export

SUFFIX = {"glb": ".glb", "usd": ".usd", "obj": ".zip", "ply": ".zip", "vat": ".zip"}
MEDIA_TYPE = {"glb": "model/gltf-binary", "usd": "application/octet-stream", "obj": "application/zip",
              "ply": "application/zip", "vat": "application/zip"}


def clip_of(spec):
    """The engine's Clip for an ExportSpec (as a dict)."""
    return Clip(params=dict(spec.get("params") or {}),
                track=tuple((float(e["time"]), dict(e["params"])) for e in spec.get("track") or []),
                duration=float(spec["duration"]), rate=float(spec["rate"]), mode=spec["mode"],
                smoothing=float(spec["smoothing"]))


def export_file(space, spec, path, *, blender=None, progress=None):
    """Play ``spec`` on ``space`` and write it to ``path``; returns (stats, notes).

    ``progress(stage, done, total)`` with stage "play" then "write"."""
    clip = clip_of(spec)
    frames = play_clip(space, clip, blender=blender,
                       progress=None if progress is None else lambda d, t: progress("play", d, t))
    stats = write_export(path, frames, spec["format"], precision=spec["precision"],
                         interpolation=spec["interpolation"],
                         progress=None if progress is None else lambda d, t: progress("write", d, t))
    return stats, list(frames.notes)


class ExportBlenders:
    """Blenders for synchronous exports, one per (space, mode), each used by one thread at a time.

    ``export_bytes(space, spec, scratch)`` plays and writes under the entry's lock and returns the
    file's bytes; exports of other spaces or modes run beside it.
    """

    def __init__(self, capacity=8):
        self.capacity = capacity
        self._entries = OrderedDict()  # (id(space), mode) -> [space, blender or None, lock]
        self._lock = threading.Lock()

    def _entry(self, space, mode):
        key = (id(space), mode)
        with self._lock:
            entry = self._entries.get(key)
            if entry is None or entry[0] is not space:
                entry = self._entries[key] = [space, None, threading.Lock()]
            self._entries.move_to_end(key)
            while len(self._entries) > self.capacity:
                self._entries.popitem(last=False)
        return entry

    def export_bytes(self, space, spec, scratch):
        """(file bytes, stats, notes, seconds) of the export ``spec`` of ``space``."""
        from engine.blend.cache import PhaseTableBlender

        entry = self._entry(space, spec["mode"])
        Path(scratch).mkdir(parents=True, exist_ok=True)
        with entry[2]:
            started = time.perf_counter()
            if entry[1] is None:
                entry[1] = space.new_blender(spec["mode"])
            blender = entry[1]
            if spec["mode"] != "nonlinear":
                # phase tables afresh for each export, as the CLI's player starts: a table kept from an
                # earlier export would make this one's frames differ from it in the last float bit
                blender = PhaseTableBlender(blender, space.n_phases, space.cyclic)
            with tempfile.TemporaryDirectory(prefix="export-", dir=scratch) as directory:
                path = Path(directory) / f"{space.name}{SUFFIX[spec['format']]}"
                stats, notes = export_file(space, spec, path, blender=blender)
                data = path.read_bytes()
        return data, stats, notes, time.perf_counter() - started


def run_export(payload, reporter):
    """The ``export`` job (a clip of a space, or a graph's recorded performance: server/graph_exports.py):
    play and write in the staging directory; the server publishes the file."""
    from engine.export import ClipError
    from engine.motion_space import MotionSpace
    from server.jobs.tasks import JobError

    params, staging = payload["params"], Path(payload["staging"])
    name = f"{payload['id']}{SUFFIX[params['format']]}"
    started = time.perf_counter()
    if params.get("graph") is not None:  # a recorded graph performance
        from server.graph_exports import run_graph_export

        stats, notes = run_graph_export(payload, reporter, name)
        what = {"graph": params["graph"]}
    else:
        path = Path(payload["data_dir"]) / "spaces" / f"{params['space']}.mspace"
        if not path.is_file():
            raise JobError(f"no motion space {params['space']!r}")
        with MotionSpace.open(path) as space:
            try:
                stats, notes = export_file(space, params, staging / name, progress=reporter.progress)
            except ClipError as exc:
                raise JobError(str(exc)) from None
        what = {"space": params["space"]}
    for note in notes:
        reporter.log(f"note: {note}")
    seconds = time.perf_counter() - started
    reporter.log(f"exported {stats['frames']} frames of {next(iter(what.values()))} as {params['format']}: "
                 f"{stats['bytes'] / 1e6:.2f} MB in {seconds:.1f} s")
    summary = {**what, "format": params["format"], "frames": stats["frames"],
               "bytes": stats["bytes"], "file": name, "notes": notes, "seconds": round(seconds, 2)}
    if "max_error_m" in stats:
        summary["max_error_mm"] = 1000 * stats["max_error_m"]
    return {"output": {"type": "export", "name": name, "path": name}, "summary": summary}
