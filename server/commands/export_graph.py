"""``morphspace export GRAPH.mgraph``: export a motion-graph performance, recorded or scripted.

The performance is a graph recording (``--recording session.json``: ``morphspace play --record``
or the browser's Record button) or a script as ``morphspace play`` takes it (``--start NODE
--set NAME=VALUE --at T NODE [NAME=VALUE ...] [budget=S] --seconds S --fps F``). It is replayed
by the graph player (engine.export.performance) and written as a clip of a space is
(server/commands/export.py): the frames cross nodes, the root moves and turns in the world.
"""

from __future__ import annotations

import time

from engine.export import ClipError, check_performance, play_performance, scripted_recording, write_export
from engine.graph import GraphError, MotionGraph
from server.commands.play import at_time
from server.commands.play_graph import node_assignments
from server.units import count_text


def recording_from_arguments(args, graph):
    """The recording document ``--recording`` names, or the one the script arguments make."""
    if args.recording:
        if args.at or args.set or args.start or args.seconds is not None or args.track:
            raise ValueError("--recording replays a recorded performance; --start, --set, --at, --seconds and "
                             "--track script one instead (give one or the other)")
        from server.commands.export import read_json_option

        return read_json_option(args.recording, "--recording")
    if args.track:
        raise ValueError("--track is for motion spaces; script a graph with --at T NODE [NAME=VALUE ...]")
    try:
        start = graph.node(args.start) if args.start else next(n for n in graph.nodes if n.cyclic)
    except GraphError as exc:
        raise ValueError(str(exc)) from None
    params, _ = node_assignments(args.set, start)
    requests = []
    for entry in args.at:
        if len(entry) < 2:
            raise ValueError(f"--at needs a time and a node, got {' '.join(entry)!r}")
        try:
            node = graph.node(entry[1])
        except GraphError as exc:
            raise ValueError(f"--at {' '.join(entry)}: {exc}") from None
        values, budget = node_assignments(entry[2:], node)
        requests.append({"time": at_time(entry), "node": node.name, "params": values, "budget": budget})
    requests.sort(key=lambda request: request["time"])  # given in any order, as play takes them; ties keep theirs
    return scripted_recording(graph, start=start.name, params=params, requests=requests, fps=args.fps,
                              seconds=args.seconds, mode=args.mode)


def run_graph(args, fmt, bar):
    """Export the graph performance of ``args`` as ``fmt``; prints what was written."""
    if args.smoothing is not None:
        raise ValueError("--smoothing is for motion spaces (a graph's nodes change parameters at once)")
    try:
        graph = MotionGraph.open(args.space)
    except GraphError as exc:
        raise ValueError(str(exc)) from None
    with graph:
        document = recording_from_arguments(args, graph)
        source = f"--recording {args.recording}" if args.recording else "the script"
        started = time.perf_counter()
        try:
            _, n_frames = check_performance(graph, document)
            frames, digest = play_performance(graph, document, progress=bar.stage("play", n_frames))
        except ClipError as exc:
            raise ValueError(f"{source}: {exc}") from None
        played = time.perf_counter()
        from server.commands.export import replace_export, writing

        with writing(args.out):
            replace_export(args.out, args.force)
            stats = write_export(args.out, frames, fmt, progress=bar.stage("write", len(frames)),
                                 precision=args.precision, interpolation=args.interpolation)
        bar.close()
        done = time.perf_counter()
    seconds = float(frames.times[-1])
    print(f"{graph.name}: {count_text(len(frames), 'frame')} ({seconds:g} s, {document['mode']}, nodes "
          f"{' -> '.join(_runs(frames.nodes))}) -> {args.out} ({fmt}, {stats['bytes'] / 1e6:.2f} MB); played in "
          f"{played - started:.2f} s, written in {done - played:.2f} s")
    if fmt == "glb":
        print(f"  {stats['targets']} morph targets ({stats['dense_targets']} dense, {stats['sparse_targets']} "
              f"sparse, {stats['empty_targets']} empty), {args.precision}, largest error "
              f"{1000 * stats['max_error_m']:.3f} mm")
    recorded = document.get("frames_sha256")
    if recorded:
        print(f"  frames {'identical to' if recorded == digest else 'DIFFERENT from'} the recording's "
              f"(sha256 {digest[:16]}...)")
    for note in frames.notes:
        print(f"  note: {note}")
    return 0 if not recorded or recorded == digest else 1


def _runs(nodes):
    """The nodes in order of appearance, repeats collapsed: walk, jump, stand, walk."""
    out = []
    for node in nodes:
        if not out or out[-1] != node:
            out.append(node)
    return out
