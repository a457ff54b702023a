"""Export time and size of a steered clip (issue 16): glTF (int16 and float32), USD, a PLY sequence, a VAT.

A speed space (a slow walk and a jog of the procedural body at ``--vertices``, built into a
temporary directory unless ``--space`` names one) plays a clip of ``--seconds`` at ``--fps``
(speed 1.3 m/s, 2.5 from a third of the way, 1.8 from two thirds), and each format is written
``--repeat`` times into a temporary directory. Reported per format: the median time to write,
the total from request to file (play + write; the player's time is measured on its own), the
file size, and the issue's targets (10 s at 60 frames/s of a 3k-vertex space: glTF <= 5 s and
<= 20 MB, USD <= 5 s).

    .venv/bin/python benchmarks/export.py [--vertices 3000] [--seconds 10] [--fps 60] [--repeat 3]
    .venv/bin/python benchmarks/export.py --space data/spaces/locomotion.mspace
    .venv/bin/python benchmarks/export.py --tiny --out /tmp/export.json    # a few seconds

``--graph GRAPH.mgraph`` measures a motion-graph performance instead (results in
benchmarks/results/export_graph.json): from the first cyclic node, the script asks in turn for
the nodes named jump, the start node, reach and the start node (those the graph has), evenly
over ``--seconds``, at each node's default parameters; it is replayed (engine.export.
play_performance, the median of ``--repeat`` is "play") and written as glTF (int16, float32) and
USD. ``--tiny --graph tiny`` builds the tiny graph with a reach (engine.graph.tiny) in a
temporary directory (about 10 CPU seconds).

    .venv/bin/python benchmarks/export.py --graph data/spaces/demo.mgraph      # 10 s at 60 frames/s
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

from _tiny import build_tiny_speed_space, parse_arguments
from engine.export import Clip, play_clip, write_export

TARGETS = {"glb_seconds": 5.0, "glb_megabytes": 20.0, "usd_seconds": 5.0}
FORMATS = [("glb int16", "glb", "clip.glb", {"precision": "int16"}),
           ("glb float32", "glb", "clip32.glb", {"precision": "float32"}),
           ("usd", "usd", "clip.usd", {}),
           ("ply sequence", "ply", "ply", {}),
           ("vat", "vat", "vat.zip", {})]


def steered_clip(space, seconds, fps):
    names = list(space.parameter_map.names)
    lo, hi = space.parameter_map.domain()[names.index("speed")]
    at = lambda v: min(max(v, lo), hi)  # noqa: E731 - the requested speeds, within the space
    return Clip(params={"speed": at(1.3)}, track=((seconds / 3, {"speed": at(2.5)}),
                                                  (2 * seconds / 3, {"speed": at(1.8)})),
                duration=seconds, rate=fps)


def measure(space, clip, repeat, scratch):
    play_times, frames = [], None
    for _ in range(repeat):
        started = time.perf_counter()
        frames = play_clip(space, clip)
        play_times.append(time.perf_counter() - started)
    play_s = statistics.median(play_times)
    results = {}
    for label, fmt, name, options in FORMATS:
        times, stats = [], None
        for i in range(repeat):
            target = scratch / f"{i}-{name}"
            started = time.perf_counter()
            stats = write_export(target, frames, fmt, **options)
            times.append(time.perf_counter() - started)
        write_s = statistics.median(times)
        results[label] = {"write_s": write_s, "total_s": play_s + write_s, "bytes": stats["bytes"],
                          "megabytes": stats["bytes"] / 1e6, "max_error_mm": 1000 * stats.get("max_error_m", 0.0),
                          "runs": repeat}
    return play_s, len(frames), results


GRAPH_FORMATS = FORMATS[:3]
GRAPH_SCRIPT = ("jump", None, "reach", None)  # None: back to the start node


def graph_recording(graph, seconds, fps):
    """The benchmark's scripted performance on ``graph`` (a recording document)."""
    from engine.export import scripted_recording

    start = next(n.name for n in graph.nodes if n.cyclic)
    names = {n.name for n in graph.nodes}
    script = [name or start for name in GRAPH_SCRIPT if name is None or name in names]
    requests = [{"time": seconds * (i + 1) / (len(script) + 1), "node": node, "params": {}}
                for i, node in enumerate(script)]
    return scripted_recording(graph, start=start, requests=requests, fps=fps, seconds=seconds)


def measure_graph(graph, seconds, fps, repeat, scratch):
    from engine.export import play_performance

    document = graph_recording(graph, seconds, fps)
    play_times = []
    for _ in range(repeat):
        started = time.perf_counter()
        frames, _ = play_performance(graph, document)
        play_times.append(time.perf_counter() - started)
    play_s = statistics.median(play_times)
    results = {}
    for label, fmt, name, options in GRAPH_FORMATS:
        times, stats = [], None
        for i in range(repeat):
            started = time.perf_counter()
            stats = write_export(scratch / f"{i}-{name}", frames, fmt, **options)
            times.append(time.perf_counter() - started)
        write_s = statistics.median(times)
        results[label] = {"write_s": write_s, "total_s": play_s + write_s, "bytes": stats["bytes"],
                          "megabytes": stats["bytes"] / 1e6, "max_error_mm": 1000 * stats.get("max_error_m", 0.0),
                          "runs": repeat}
    visited = [n for i, n in enumerate(frames.nodes) if i == 0 or frames.nodes[i - 1] != n]
    return play_s, len(frames), results, visited, document["requests"]


def main_graph(args, out, scratch):
    from engine.graph import MotionGraph

    path = args.graph
    if args.tiny and str(path) == "tiny":
        from engine.graph.tiny import build_tiny_graph, build_tiny_spaces

        started = time.perf_counter()
        build_tiny_spaces(scratch, reach=True)
        build_tiny_graph(scratch, scratch / "tiny.mgraph", reach=True)
        path = scratch / "tiny.mgraph"
        print(f"built the tiny graph in {time.perf_counter() - started:.1f} s")
    with MotionGraph.open(path) as graph:
        play_s, n_frames, results, visited, requests = measure_graph(graph, args.seconds, args.fps, args.repeat,
                                                                     scratch)
        n_vertices, name = int(graph.nodes[0].space.n_vertices), graph.name
    load = os.getloadavg()[0]
    glb, usd = results["glb int16"], results["usd"]
    record = {"graph": name, "path": str(args.graph), "vertices": n_vertices, "seconds": args.seconds, "fps": args.fps,
              "frames": n_frames, "requests": requests, "visited": visited, "play_s": play_s, "formats": results,
              "load_average": load, "targets": TARGETS,
              "met": {"glb_seconds": glb["total_s"] <= TARGETS["glb_seconds"],
                      "glb_megabytes": glb["megabytes"] <= TARGETS["glb_megabytes"],
                      "usd_seconds": usd["total_s"] <= TARGETS["usd_seconds"]}}
    print(f"graph {name}: {n_frames} frames ({args.seconds:g} s at {args.fps:g} frames/s) of {n_vertices} vertices, "
          f"nodes {' -> '.join(visited)}; replay {play_s:.3f} s; median of {args.repeat}, load average {load:.1f}")
    for label, row in results.items():
        print(f"  {label:13s} write {row['write_s']:7.3f} s  total {row['total_s']:7.3f} s  {row['megabytes']:8.2f} MB"
              + (f"  max error {row['max_error_mm']:.4f} mm" if row["max_error_mm"] else ""))
    print("targets (the clip's): " + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in record["met"].items()))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2) + "\n")
    return 0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--space", type=Path, help="an existing .mspace with a speed parameter (default: build one)")
    parser.add_argument("--vertices", type=int, default=3000, help="body resolution of the built space")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--fps", type=float, default=60.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/export.json)")
    parser.add_argument("--graph", type=Path, help="a .mgraph: export a scripted graph performance instead "
                                                   "(with --tiny: 'tiny' builds the tiny graph)")
    parser.add_argument("--tiny", action="store_true", help="1,000 vertices, 2 s at 30 frames/s, 1 run (needs --out)")
    args = parse_arguments(parser, argv, {"vertices": 1000, "seconds": 2.0, "fps": 30.0, "repeat": 1})
    results_name = "export_graph.json" if args.graph else "export.json"
    out = args.out or Path(__file__).parent / "results" / results_name
    if args.graph:
        with tempfile.TemporaryDirectory(prefix="morphspace-export-bench-") as scratch:
            return main_graph(args, out, Path(scratch))
    from engine.motion_space import MotionSpace

    with tempfile.TemporaryDirectory(prefix="morphspace-export-bench-") as scratch:
        scratch = Path(scratch)
        path = args.space
        if path is None:
            path = scratch / "speed.mspace"
            started = time.perf_counter()
            build_tiny_speed_space(path, args.vertices, fps=30.0)
            print(f"built a {args.vertices}-vertex speed space in {time.perf_counter() - started:.1f} s")
        with MotionSpace.open(path) as space:
            clip = steered_clip(space, args.seconds, args.fps)
            play_s, n_frames, results = measure(space, clip, args.repeat, scratch)
            n_vertices = int(space.n_vertices)
    load = os.getloadavg()[0]
    glb, usd = results["glb int16"], results["usd"]
    record = {"space": str(args.space) if args.space else f"built speed space, {args.vertices} vertices",
              "vertices": n_vertices, "seconds": args.seconds, "fps": args.fps, "frames": n_frames,
              "play_s": play_s, "formats": results, "load_average": load, "targets": TARGETS,
              "met": {"glb_seconds": glb["total_s"] <= TARGETS["glb_seconds"],
                      "glb_megabytes": glb["megabytes"] <= TARGETS["glb_megabytes"],
                      "usd_seconds": usd["total_s"] <= TARGETS["usd_seconds"]}}
    print(f"{n_frames} frames ({args.seconds:g} s at {args.fps:g} frames/s) of {n_vertices} vertices; "
          f"player {play_s:.3f} s; median of {args.repeat}, load average {load:.1f}")
    for label, row in results.items():
        print(f"  {label:13s} write {row['write_s']:7.3f} s  total {row['total_s']:7.3f} s  {row['megabytes']:8.2f} MB"
              + (f"  max error {row['max_error_mm']:.4f} mm" if row["max_error_mm"] else ""))
    print(f"targets: glTF <= {TARGETS['glb_seconds']:g} s and <= {TARGETS['glb_megabytes']:g} MB, USD <= "
          f"{TARGETS['usd_seconds']:g} s: " + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in record["met"].items()))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
