"""A loaded motion graph: its nodes' spaces and samples and its edges' dissimilarity tables."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from engine.graph.build import GRAPH_FORMAT, GRAPH_VERSION, GraphError
from engine.graph.features import NodeSamples, WindowOptions
from engine.motion_space.container import Container, MotionSpaceError


@dataclass
class Node:
    """A node of a loaded graph.

    name : str; index : int; space : MotionSpace; samples : NodeSamples
    meta : dict (the file's record: parameters, units, per_axis, dims, return_to, ...)
    """

    name: str
    index: int
    space: object
    samples: NodeSamples
    meta: dict
    _cache: dict = field(default_factory=dict, repr=False)

    def cached(self, key, compute):
        """``compute()`` once per node (derived data players share, e.g. the feet's contacts)."""
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]

    @property
    def cyclic(self):
        return bool(self.space.cyclic)

    @property
    def parameters(self):
        return list(self.meta["parameters"])

    def solve(self, params):
        """(weights (N,), realised (k,), clamped, message) for a {name: value} request (missing
        names: the middle of their range); a space without parameters has fixed weights."""
        pmap = self.space.parameter_map
        params = dict(params or {})
        if pmap is None:
            if params:
                raise GraphError(f"node {self.name!r} has no parameters, got {', '.join(sorted(params))}")
            return self.samples.weights[0], np.zeros(0), False, ""
        unknown = sorted(set(params) - set(pmap.names))
        if unknown:
            raise GraphError(f"node {self.name!r}: unknown parameter(s) {', '.join(unknown)}; "
                             f"it has {', '.join(pmap.names)}")
        values = []
        for name, (lo, hi) in zip(pmap.names, pmap.domain()):
            value = params.get(name, 0.5 * (lo + hi))
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise GraphError(f"node {self.name!r}: {name} must be a number, got {value!r}") from None
            if not np.isfinite(value):
                raise GraphError(f"node {self.name!r}: {name} must be finite, got {value}")
            values.append(value)
        solution = pmap.solve(np.array(values))
        return solution.weights, solution.realised, bool(solution.clamped), solution.message

    def sample_of(self, weights):
        """Index of the weight sample nearest ``weights``."""
        w = np.asarray(weights, dtype=float)
        return int(np.argmin(np.abs(self.samples.weights - w / w.sum()).sum(axis=1)))


class MotionGraph:
    """A motion graph opened from its ``.mgraph`` file; its spaces are opened from the paths the
    file records (relative to the file) and must be the ones it was built from.

    Attributes
    ----------
    name : str; path : Path; metadata : dict; nodes : list of Node; options : WindowOptions
    edges : dict (from name, to name) -> (KA, MA, KB, MB) float32 dissimilarity table (m)
    model_size : float
    """

    def __init__(self, path, container, spaces):
        self.path = Path(path)
        self.container = container
        self.checksum = container.checksum
        meta = container.metadata
        self.metadata = meta
        self.name = meta["name"]
        self.model_size = float(meta["model_size"])
        self.options = WindowOptions(**meta["window"])
        self.nodes = []
        for i, (record, space) in enumerate(zip(meta["nodes"], spaces)):
            arrays = {key: np.asarray(container[f"node/{record['name']}/{key}"])
                      for key in ("u", "weights", "params", "durations", "phases")}
            self.nodes.append(Node(record["name"], i, space, NodeSamples(**arrays), record))
        self.edges = {(e["from"], e["to"]): np.asarray(container[f"edge/{i}/dissimilarity"])
                      for i, e in enumerate(meta["edges"])}

    @classmethod
    def open(cls, path, *, verify=True, open_space=None):
        """Open a ``.mgraph`` file and its spaces.

        Raises
        ------
        GraphError   not a motion graph, a newer or older version, truncated or corrupt (the
                     container's message), a space missing or changed since the graph was built
        """
        from engine.motion_space import MotionSpace

        path = Path(path)
        try:
            container = Container.open(path, verify=verify)
        except MotionSpaceError as err:
            raise GraphError(str(err).replace("motion space file", "motion graph file")) from None
        meta = container.metadata
        if meta.get("format") != GRAPH_FORMAT:
            container.close()
            raise GraphError(f"{path}: the file holds {meta.get('format')!r}, not a {GRAPH_FORMAT}")
        if meta.get("version") != GRAPH_VERSION:
            container.close()
            raise GraphError(f"{path}: motion graph version {meta.get('version')}; this morphspace reads version "
                             f"{GRAPH_VERSION} (rebuild it with morphspace build-graph)")
        open_space = open_space or MotionSpace.open
        spaces = []
        for record in meta["nodes"]:
            space_path = path.parent / record["space"]
            try:
                space = open_space(space_path)
            except (MotionSpaceError, OSError) as err:
                raise GraphError(f"{path}: node {record['name']!r}: cannot open its space: {err}") from None
            if space.container.checksum != record["space_checksum"]:
                raise GraphError(f"{path}: node {record['name']!r}: {space_path} changed since the graph was built; "
                                 "rebuild the graph (morphspace build-graph)")
            spaces.append(space)
        return cls(path, container, spaces)

    def close(self):
        for node in self.nodes:
            node.space.close()
        self.container.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def node(self, name):
        for node in self.nodes:
            if node.name == name:
                return node
        raise GraphError(f"no node {name!r} in graph {self.name!r}; nodes: {', '.join(n.name for n in self.nodes)}")

    def successors(self, name):
        return [b for a, b in self.edges if a == name]

    def route(self, start, goal):
        """Node names from ``start`` to ``goal`` along edges (shortest by hops), both included."""
        self.node(start), self.node(goal)
        previous = {start: None}
        queue = deque([start])
        while queue:
            here = queue.popleft()
            if here == goal:
                path = [here]
                while previous[path[-1]] is not None:
                    path.append(previous[path[-1]])
                return path[::-1]
            for nxt in self.successors(here):
                if nxt not in previous:
                    previous[nxt] = here
                    queue.append(nxt)
        raise GraphError(f"graph {self.name!r}: no path from {start!r} to {goal!r}")
