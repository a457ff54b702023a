"""Building a motion graph file (``.mgraph``): what the run-time search needs for every edge.

``build_graph(path, nodes, edges, ...)`` samples every node's parameters and phases
(``features.node_samples``), plays a short window from each sample (``features.window``) and
stores, for every edge A -> B, the dissimilarity of every window of A with every window of B
(``features.dissimilarity``): where to leave A and where to enter B is then a table look-up.
The file is the motion-space container (``engine.motion_space.container``): versioned,
checksummed, written atomically, memory-mapped, never unpickled.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from engine.graph.features import WindowOptions, compared_vertices, dissimilarity, node_samples, node_windows
from engine.motion_space.container import write_container
from engine.names import is_name

GRAPH_FORMAT = "morphspace-motion-graph"
GRAPH_VERSION = 1


class GraphError(ValueError):
    """A motion graph (its spec, file or a request to it) is wrong; the message says how."""


@dataclass(frozen=True)
class NodeSpec:
    """A node: a motion space under a name.

    name : str
    space : path            the .mspace file
    return_to : str or None a one-shot node's cyclic node to go back to when it ends
                            (default: the first cyclic node it has an edge to)
    """

    name: str
    space: Path
    return_to: str | None = None


def check_graph(nodes, edges, spaces):
    """Validate nodes, edges and their spaces; returns the edges as (from, to) index pairs and
    each node's return node index (-1 for cyclic nodes)."""
    names = [n.name for n in nodes]
    if len(nodes) < 2:
        raise GraphError(f"a motion graph needs at least 2 nodes, got {len(nodes)}")
    for name in names:   # a node's name names its arrays in the file (node/<name>/...)
        if not is_name(name):
            raise GraphError(f"node name {name!r}: use letters, digits, '_', '-', '.' (at most 128, starting "
                             "with a letter or digit, no '..')")
    if len(set(names)) != len(names):
        raise GraphError(f"node names must differ, got {names}")
    first = spaces[0]
    for node, space in zip(nodes, spaces):
        if space.n_vertices != first.n_vertices or not np.array_equal(space.faces, first.faces):
            how = (f"{space.n_vertices} vs {first.n_vertices} vertices" if space.n_vertices != first.n_vertices
                   else f"the same {space.n_vertices} vertices, joined by other faces")
            raise GraphError(f"node {node.name!r}: its space {node.space} has a different mesh structure from "
                             f"{nodes[0].name!r}'s ({how}); the spaces of a graph share one mesh structure")
    pairs = []
    for edge in edges:
        if len(edge) != 2 or any(e not in names for e in edge):
            raise GraphError(f"edge {list(edge)}: both ends must be nodes ({', '.join(names)})")
        if edge[0] == edge[1]:
            raise GraphError(f"edge {list(edge)}: a node does not transition to itself")
        pair = (names.index(edge[0]), names.index(edge[1]))
        if pair in pairs:
            raise GraphError(f"edge {list(edge)} is listed twice")
        pairs.append(pair)
    returns = []
    for i, (node, space) in enumerate(zip(nodes, spaces)):
        if space.cyclic:
            if node.return_to is not None:
                raise GraphError(f"node {node.name!r} is cyclic: return_to is for one-shot nodes")
            returns.append(-1)
            continue
        targets = [b for a, b in pairs if a == i and spaces[b].cyclic]
        if node.return_to is not None:
            if node.return_to not in names or names.index(node.return_to) not in targets:
                raise GraphError(f"node {node.name!r}: return_to {node.return_to!r} must be a cyclic node "
                                 "it has an edge to")
            returns.append(names.index(node.return_to))
        elif targets:
            returns.append(targets[0])
        else:
            raise GraphError(f"one-shot node {node.name!r} has no edge to a cyclic node to return to")
    check_connected(names, pairs)
    return pairs, returns


def check_connected(names, pairs):
    """Every node can be reached from every other along the edges: a player asked for a node it
    cannot reach from where it is has no answer (a graph in pieces, a node no edge leads to)."""
    n = len(names)
    for start in range(n):
        seen, todo = {start}, [start]
        while todo:
            a = todo.pop()
            for x, b in pairs:
                if x == a and b not in seen:
                    seen.add(b)
                    todo.append(b)
        if len(seen) < n:
            missing = [names[k] for k in range(n) if k not in seen]
            raise GraphError(f"node {missing[0]!r} cannot be reached from {names[start]!r} along the edges"
                             + (f" (nor {', '.join(repr(m) for m in missing[1:])})" if len(missing) > 1 else "")
                             + "; every node must be reachable from every other: add edges")


def build_graph(path, nodes, edges, *, name, options=None, open_space=None, progress=None, relative_to=None):
    """Build and write a motion graph.

    Parameters
    ----------
    path : path                  destination ``.mgraph`` (written atomically)
    nodes : list of NodeSpec
    edges : list of (str, str)   allowed transitions, by node name
    name : str
    options : WindowOptions or None
    open_space : callable(path) -> MotionSpace   (default ``MotionSpace.open``)
    progress : callable(stage: str, done: int, total: int) or None   stages "windows", "edges"
    relative_to : path or None   the directory the file records the spaces' paths relative to
                                 (default: the file's own; another when it will be moved there)

    Returns
    -------
    report : dict   the file's metadata, its ``path`` and ``build_s`` (seconds; not in the file, so the
                    same input gives the same bytes)
    """
    from engine.motion_space import MotionSpace

    options = options or WindowOptions()
    open_space = open_space or MotionSpace.open
    report = progress or (lambda stage, done, total: None)
    started = time.perf_counter()
    path = Path(path)
    spaces = []
    for node in nodes:   # a node's space that is not one (a spec, a graph, a truncated file) is named by its node
        try:
            spaces.append(open_space(node.space))
        except (ValueError, OSError) as exc:
            raise GraphError(f"node {node.name!r}: its space cannot be opened: {exc}") from None
    pairs, returns = check_graph(nodes, edges, spaces)
    vertices = compared_vertices(spaces[0].n_vertices, options.vertices)
    home = Path(relative_to or path.parent).resolve()
    arrays, node_meta, windows = {}, [], []
    all_samples = [node_samples(space, options) for space in spaces]
    total = sum(len(s.weights) for s in all_samples)
    done = 0
    for i, (node, space, samples) in enumerate(zip(nodes, spaces, all_samples)):
        windows.append(node_windows(space, samples, options, vertices,
                                    progress=lambda d, t, done=done: report("windows", done + d, total)))
        done += len(samples.weights)
        for key in ("u", "weights", "params", "durations", "phases"):
            arrays[f"node/{node.name}/{key}"] = getattr(samples, key)
        pmap = space.parameter_map
        node_meta.append({
            "name": node.name, "space": os.path.relpath(Path(node.space).resolve(), home),
            "space_name": space.name, "space_checksum": space.container.checksum, "cyclic": bool(space.cyclic),
            "parameters": [] if pmap is None else list(pmap.names),
            "units": [] if pmap is None else list(pmap.units),
            "per_axis": options.per_axis if pmap is not None else 1,
            "dims": 0 if pmap is None else pmap.layout.dims,
            "samples": int(len(samples.weights)), "phases": int(len(samples.phases)),
            "return_to": None if returns[i] < 0 else nodes[returns[i]].name})
    edge_meta = []
    for e, (a, b) in enumerate(pairs):
        report("edges", e, len(pairs))
        table = dissimilarity(windows[a], windows[b])
        arrays[f"edge/{e}/dissimilarity"] = table
        edge_meta.append({"from": nodes[a].name, "to": nodes[b].name, "min_m": float(table.min()),
                          "median_m": float(np.median(table))})
    report("edges", len(pairs), len(pairs))
    arrays["vertices"] = vertices.astype(np.int32)
    metadata = {"format": GRAPH_FORMAT, "version": GRAPH_VERSION, "name": name, "nodes": node_meta,
                "edges": edge_meta, "window": asdict(options), "model_size": float(spaces[0].model_size),
                "n_vertices": int(spaces[0].n_vertices)}
    write_container(path, arrays, metadata)  # no timings in it: the same input gives the same bytes
    for space in spaces:
        space.close()
    return {"path": str(path), **metadata, "build_s": round(time.perf_counter() - started, 3)}
