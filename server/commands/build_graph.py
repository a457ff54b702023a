"""Build a motion graph (``.mgraph``) from a graph spec (TOML).

The spec names the nodes (motion spaces, cyclic or one-shot) and the allowed transitions
(docs/file-formats.md, "Motion graph specs"); the build samples every node's parameters and
phases and stores, for every edge, the shape-and-motion dissimilarity of short windows of the
two spaces, which the run-time transition search looks up. Example:

    morphspace build-graph specs/demo/graph.toml --out data/spaces/demo.mgraph
"""

from __future__ import annotations

import sys
from pathlib import Path

from engine.graph import GraphError, NodeSpec, WindowOptions, build_graph
from server.commands.build import check_file_name, check_keys, read_toml
from server.commands.checks import check_number, check_output_file
from server.progress import StageBars

WINDOW_KEYS = {"window_frames": "frames", "window_step": "step", "vertices": "vertices",
               "velocity_weight": "velocity_weight", "phases": "phases", "per_axis": "per_axis"}
GRAPH_KEYS = ("name", "spaces", "edges", "window", "nodes")


def add_arguments(parser):
    parser.add_argument("spec", type=Path, help="a graph spec (.toml)")
    parser.add_argument("--out", type=Path, help="output .mgraph file (default: the spec's name in its spaces "
                        "directory, beside the spaces)")
    parser.add_argument("--force", action="store_true", help="replace an existing output file")


def window_limits():
    """Each [window] key's range, {key: (low, high, integer, above low)}, as the REST graph job's
    ``GraphWindow`` declares it (the bounds ``WindowOptions`` checks; its fields are the keys)."""
    from server.jobs.models import GraphWindow

    limits = {}
    for key, field in GraphWindow.model_fields.items():
        bounds = {name: getattr(m, name) for m in field.metadata for name in ("ge", "gt", "le") if hasattr(m, name)}
        above = "gt" in bounds
        limits[key] = (bounds["gt"] if above else bounds["ge"], bounds["le"], field.annotation is int, above)
    return limits


def read_graph_spec(path):
    """Parse and check a graph spec; returns {name, nodes: [NodeSpec], edges: [(a, b)], options,
    spaces (directory)}. Errors name the spec and the problem."""
    path = Path(path)
    spec = read_toml(path, "graph spec")
    check_keys(path, spec, GRAPH_KEYS)
    base = path.parent
    name = check_file_name(path, spec["name"], "name") if "name" in spec else path.stem
    if not isinstance(spec.get("spaces", "."), str) or not spec.get("spaces", "."):
        raise ValueError(f"{path}: spaces must be a directory (a non-empty string), got {spec['spaces']!r}")
    spaces = base / spec.get("spaces", ".")
    nodes = spec.get("nodes")
    if not isinstance(nodes, list) or len(nodes) < 2:
        raise ValueError(f"{path}: [[nodes]] must list at least 2 nodes")
    specs = []
    for entry in nodes:
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str) or not isinstance(
                entry.get("space"), str):
            raise ValueError(f"{path}: every [[nodes]] entry needs a name and a space (a .mspace file)")
        unknown = sorted(set(entry) - {"name", "space", "return_to"})
        if unknown:
            raise ValueError(f"{path}: node {entry['name']!r}: unknown key(s) {', '.join(unknown)} (in TOML, "
                             "top-level keys such as edges go before the first [[nodes]])")
        if not isinstance(entry.get("return_to", ""), str):
            raise ValueError(f"{path}: node {entry['name']!r}: return_to must be a node name, "
                             f"got {entry['return_to']!r}")
        file = spaces / entry["space"]
        if not file.is_file():
            raise ValueError(f"{path}: node {entry['name']!r}: {file} does not exist (build the space first)")
        specs.append(NodeSpec(entry["name"], file, entry.get("return_to")))
    edges = spec.get("edges")
    if not isinstance(edges, list) or not edges or not all(
            isinstance(e, list) and len(e) == 2 and all(isinstance(x, str) for x in e) for e in edges):
        raise ValueError(f"{path}: edges must be a list of [from, to] node-name pairs")
    window = spec.get("window", {})
    if not isinstance(window, dict):
        raise ValueError(f"{path}: window must be a table ([window]), got {window!r}")
    unknown = sorted(set(window) - set(WINDOW_KEYS))
    if unknown:
        raise ValueError(f"{path}: [window] has unknown key(s) {', '.join(unknown)}; known: {', '.join(WINDOW_KEYS)}")
    limits = window_limits() if window else {}
    for key, value in window.items():
        low, high, integer, above = limits[key]
        check_number(value, f"{path}: [window] {key}", low, high, integer=integer, above=above)
    try:
        options = WindowOptions(**{WINDOW_KEYS[k]: v for k, v in window.items()})
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: [window]: {exc}") from None
    return {"name": name, "nodes": specs, "edges": [tuple(e) for e in edges], "options": options, "spaces": spaces}


def run(args):
    spec = read_graph_spec(args.spec)
    out = args.out or spec["spaces"] / f"{spec['name']}.mgraph"
    check_output_file(out, "--out" if args.out else None, inputs=[args.spec, *(node.space for node in spec["nodes"])])
    if out.exists() and not args.force:
        raise FileExistsError(f"{out} already exists; pass --force to replace it")
    bars = StageBars()
    try:
        report = build_graph(out, spec["nodes"], spec["edges"], name=spec["name"], options=spec["options"],
                             progress=bars)
    except GraphError as exc:
        raise ValueError(f"{args.spec}: {exc}") from None
    finally:
        bars.close()
    print(f"wrote {out}: {len(report['nodes'])} nodes, {len(report['edges'])} edges in {report['build_s']:.1f} s",
          file=sys.stdout)
    for edge in report["edges"]:
        print(f"  {edge['from']:>10} -> {edge['to']:<10} best seam {1000 * edge['min_m']:.1f} mm, "
              f"median {1000 * edge['median_m']:.1f} mm")
    note = heading_turn_note({node.name: _heading_turn(node.space) for node in spec["nodes"]})
    if note:
        print(f"morphspace build-graph: warning: {note}", file=sys.stderr)
    return 0


def _heading_turn(path):
    from engine.motion_space import MotionSpace

    with MotionSpace.open(path) as space:
        return float(space.metadata.get("heading_turn_deg", 0.0))


def heading_turn_note(turns, tolerance=1.0):
    """A warning when the nodes' spaces took heading 0 from travel directions more than ``tolerance``
    degrees apart (``heading_turn_deg``: spaces built from a captured rest, one that travels and one
    that does not), else None: their root-local poses are turned that much from each other, and a
    transition between them turns the body by it."""
    spread = max(turns.values()) - min(turns.values()) if turns else 0.0
    if spread <= tolerance:
        return None
    listed = ", ".join(f"{name} {turn:+.1f}" for name, turn in turns.items())
    return (f"the nodes' spaces face heading 0 up to {spread:.1f} degrees apart "
            f"(heading_turn_deg: {listed}); a transition between two of them turns the body by their difference")
