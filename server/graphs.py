"""The motion graphs a server offers: every ``*.mgraph`` file beside its spaces (the spaces directory).

Like the SpaceRegistry, the directory is scanned on every listing, so a graph written there (by
``morphspace build-graph`` or a ``graph`` job) appears without a restart and a rebuilt one is
reopened. Names are file stems (``demo.mgraph`` -> ``demo``). A graph's nodes are spaces: those
in the same directory are opened through the SpaceRegistry (shared with the space streams and the
REST API), others from the path the graph file records.
"""

from __future__ import annotations

import threading
from pathlib import Path

from engine.graph import GraphError, MotionGraph
from engine.motion_space.space import MotionSpace
from server.registry import BrokenSpace, UnknownSpace, named_files, named_path, within

SUFFIX = ".mgraph"


class UnknownGraph(LookupError):
    """No such motion graph (or an unusable name)."""


class BrokenGraph(RuntimeError):
    """The file is there but cannot be used: not a graph, or a node's space is missing or changed."""


class GraphRegistry:
    """Opens motion graphs from ``spaces.directory`` on demand (their nodes' spaces through the
    SpaceRegistry ``spaces``) and keeps them open while their file is unchanged."""

    def __init__(self, spaces):
        self.spaces = spaces
        self.directory = Path(spaces.directory)
        self._entries = {}
        self._lock = threading.Lock()

    def path(self, name):
        return named_path(self.directory, name, SUFFIX, UnknownGraph, "motion graph")

    def names(self):
        """Sorted names of the graphs in the directory now."""
        return named_files(self.directory, SUFFIX)

    def _space_opener(self, used):
        """MotionGraph.open's ``open_space``: spaces in the directory through the SpaceRegistry
        (each appended to ``used`` as (name, space)), others from their file."""
        def open_space(path):
            path = Path(path)
            if path.parent.resolve() == self.directory.resolve() and path.name.endswith(".mspace"):
                name = path.name[:-len(".mspace")]
                try:
                    space = self.spaces.get(name)
                except (UnknownSpace, BrokenSpace) as exc:
                    raise OSError(str(exc)) from None
                used.append((name, space))
                return space
            return MotionSpace.open(path)
        return open_space

    def _current(self, used):
        """The spaces a graph was opened with are still the files in the directory."""
        try:
            return all(self.spaces.get(name) is space for name, space in used)
        except (UnknownSpace, BrokenSpace):
            return False

    def get(self, name):
        """The open MotionGraph called ``name``.

        Raises UnknownGraph (no such file) or BrokenGraph (the GraphError's message)."""
        path = self.path(name)
        try:
            st = path.stat()
        except FileNotFoundError:
            raise UnknownGraph(f"no motion graph {name!r} (have: {', '.join(self.names()) or 'none'})") from None
        stamp = (st.st_ino, st.st_mtime_ns, st.st_size)
        with self._lock:
            entry = self._entries.get(name)
        if entry is not None and entry[0] == stamp and self._current(entry[2]):
            return entry[1]
        used = []
        try:
            graph = MotionGraph.open(path, open_space=self._space_opener(used))
        except (GraphError, OSError, ValueError, KeyError) as exc:
            raise BrokenGraph(f"motion graph {name!r} cannot be used: {within(exc, self.directory)}") from None
        with self._lock:
            # an older version stays open for connections already streaming it (mapped memory)
            self._entries[name] = (stamp, graph, used)
        return graph

    def describe(self, name):
        """A JSON-ready description: nodes (space, cyclic, return node, parameters), edges, sizes."""
        graph = self.get(name)
        nodes = []
        for node in graph.nodes:
            pmap = node.space.parameter_map
            parameters = []
            if pmap is not None:
                for pname, unit, (lo, hi) in zip(pmap.names, pmap.units, pmap.domain()):
                    parameters.append({"name": pname, "unit": unit, "min": lo, "max": hi, "default": (lo + hi) / 2})
            nodes.append({"name": node.name, "space": Path(node.meta["space"]).name.removesuffix(".mspace"),
                          "cyclic": node.cyclic, "return_to": node.meta.get("return_to"),
                          "duration": float(node.space.root_track.duration(node.samples.weights[0])),
                          "parameters": parameters})
        start = next((n.name for n in graph.nodes if n.cyclic), graph.nodes[0].name)
        return {"name": name, "graph": graph.name, "start": start, "nodes": nodes,
                "edges": [{"from": a, "to": b} for a, b in graph.edges],
                "n_vertices": int(graph.nodes[0].space.n_vertices), "model_size": graph.model_size,
                "file_bytes": self.path(name).stat().st_size, "checksum": graph.checksum}
