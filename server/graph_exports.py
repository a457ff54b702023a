"""Exports of recorded motion-graph performances over REST (docs/rest.md, "Exports").

``POST /v1/graphs/{name}/export`` checks the recording against the server's graph
(``check_graph_export``) and replays it in a thread on a copy of the graph opened for exports
(``GraphExports``): a graph stream blends on the event loop with its spaces' shared blenders, so an
export beside it needs blenders of its own. A long performance is an ``export`` job naming
``graph`` and ``recording``; ``run_graph_export`` runs it in a worker process.
"""

from __future__ import annotations

import tempfile
import threading
import time
from collections import OrderedDict
from pathlib import Path

from engine.export import ClipError, check_performance, play_performance, write_export
from server.exports import SUFFIX


def check_graph_export(graphs, name, recording, error):
    """The number of frames of ``recording`` on graph ``name`` of ``graphs`` (a GraphRegistry);
    raises ``error(status, message)``: 404 no such graph, 409 a graph that cannot be used, 422 a
    recording that is not one of this graph (the message names the problem)."""
    from server.graphs import BrokenGraph, UnknownGraph

    try:
        graph = graphs.get(name)
    except UnknownGraph as exc:
        raise error(404, str(exc)) from None
    except BrokenGraph as exc:
        raise error(409, str(exc)) from None
    try:
        _, frames = check_performance(graph, recording)
    except ClipError as exc:
        raise error(422, f"recording: {exc}" if not str(exc).startswith("recording") else str(exc)) from None
    return graph, frames


def export_graph_file(graph, spec, path, progress=None):
    """Replay ``spec["recording"]`` on ``graph`` and write it to ``path``; returns (stats, notes, digest).
    ``progress(stage, done, total)`` with stage "play" then "write"."""
    frames, digest = play_performance(graph, spec["recording"],
                                      progress=None if progress is None else lambda d, t: progress("play", d, t))
    stats = write_export(path, frames, spec["format"], precision=spec["precision"],
                         interpolation=spec["interpolation"],
                         progress=None if progress is None else lambda d, t: progress("write", d, t))
    return stats, list(frames.notes), digest


class GraphExports:
    """Graphs opened again for synchronous exports (their spaces and blenders not shared with the
    streams), one per graph file and checksum, each used by one thread at a time."""

    def __init__(self, capacity=4):
        self.capacity = capacity
        self._entries = OrderedDict()  # (path, checksum) -> [MotionGraph or None, lock]
        self._lock = threading.Lock()

    def _entry(self, graph):
        key = (str(graph.path), graph.checksum)
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                entry = self._entries[key] = [None, threading.Lock()]
            self._entries.move_to_end(key)
            while len(self._entries) > self.capacity:
                _, (old, lock) = self._entries.popitem(last=False)
                if old is not None:
                    with lock:
                        old.close()
        return entry

    def export_bytes(self, graph, spec, scratch):
        """(file bytes, stats, notes, digest, seconds) of the export ``spec`` of ``graph``."""
        from engine.graph import MotionGraph

        entry = self._entry(graph)
        Path(scratch).mkdir(parents=True, exist_ok=True)
        with entry[1]:
            started = time.perf_counter()
            if entry[0] is None:
                entry[0] = MotionGraph.open(graph.path)
            with tempfile.TemporaryDirectory(prefix="export-", dir=scratch) as directory:
                path = Path(directory) / f"{graph.name}{SUFFIX[spec['format']]}"
                stats, notes, digest = export_graph_file(entry[0], spec, path)
                data = path.read_bytes()
        return data, stats, notes, digest, time.perf_counter() - started


def run_graph_export(payload, reporter, name):
    """The ``export`` job of a graph performance: replay and write ``name`` in the staging directory."""
    from engine.graph import GraphError, MotionGraph
    from server.jobs.tasks import JobError

    params, staging = payload["params"], Path(payload["staging"])
    path = Path(payload["data_dir"]) / "spaces" / f"{params['graph']}.mgraph"
    if not path.is_file():
        raise JobError(f"no motion graph {params['graph']!r}")
    try:
        graph = MotionGraph.open(path)
    except GraphError as exc:
        raise JobError(str(exc)) from None
    with graph:
        try:
            stats, notes, digest = export_graph_file(graph, params, staging / name, progress=reporter.progress)
        except ClipError as exc:
            raise JobError(f"recording: {exc}") from None
    recorded = params["recording"].get("frames_sha256")
    if recorded and recorded != digest:
        notes.append("the replayed frames differ from the recording's (frames_sha256)")
    return stats, notes
