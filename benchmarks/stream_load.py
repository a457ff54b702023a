"""Streaming load benchmark: many clients on one server process, latency, and a memory soak.

    .venv/bin/python benchmarks/stream_load.py                       # 200 clients x 60 fps, 20 s
    .venv/bin/python benchmarks/stream_load.py --repeat 3            # three rounds, and their median
    .venv/bin/python benchmarks/stream_load.py --soak 300            # + 5-minute connect/leave soak
    .venv/bin/python benchmarks/stream_load.py --compare-workers 1,2     # 1 and 2 worker processes side by side
    .venv/bin/python benchmarks/stream_load.py --heatmap-clients 50  # 50 of the 200 with the heatmap on
    .venv/bin/python benchmarks/stream_load.py --baseline /tmp/before --repeat 3   # against another checkout
    .venv/bin/python benchmarks/stream_load.py --offline --repeat 3        # the scheduler's CPU per frame, no sockets
    .venv/bin/python benchmarks/stream_load.py --offline --baseline /tmp/before --repeat 3
    .venv/bin/python benchmarks/stream_load.py --frames-hash --baseline /tmp/before   # every frame the same bytes?
    .venv/bin/python benchmarks/stream_load.py --tiny --out /tmp/stream_load.json   # smoke run, ~30 s
    .venv/bin/python benchmarks/stream_load.py --graph data/spaces/demo.mgraph --actions 0.25   # a motion graph
    .venv/bin/python benchmarks/stream_load.py --tiny --graph tiny --out /tmp/stream_load_graph.json

Starts ``morphspace serve`` (``--workers``, default one process) on 127.0.0.1 over a data directory holding the space
(default data/spaces/locomotion.mspace, 3,000 vertices), then runs the clients in separate
processes (``--client-procs``; benchmarks/_load_clients.py), each an asyncio loop of plain
websockets connections asking for ``--fps`` frames per second in the q16 codec. It reports

- frames delivered: received / (clients x fps x seconds) over the measuring window,
- latency: a share of the clients request new parameters every ``--update-every`` seconds; the
  time from sending to the first frame whose ``ack`` covers the request (median, p95, p99),
- the server's CPU (of all its processes) per delivered frame (its cores over the frames the
  clients received per second; benchmarks/_load_round.py) and of it the system time, the
  kernel's share (the socket writes; on loopback also the clients' receiving side, which the
  kernel runs in the sender's call), resident memory, and the CPU the client processes
  themselves used; with ``--heatmap-clients N``, the first N clients also ask for the heatmap
  and their frames delivered are reported apart; with ``--soak``, resident memory sampled while
  clients connect and leave (start, end, max, and the slope of a line fitted to the second half).

``--compare-workers 1,2`` replaces the rounds above by a capacity search (benchmarks/_workers.py):
a server of each worker count is started, then at each client count of ``--levels`` the servers
take turns under the same load (the order alternating from level to level), each until it misses
95% delivered twice at a level; it prints a table (delivered, server and client CPU, CPU per
frame) and the ratio of the client counts held. The clients share the machine with the server:
their CPU is reported so that the comparison can be read against it (docs/evaluation.md).

Results go to benchmarks/results/stream_load.json. ``--tiny`` (the test suite's smoke run) builds a
1,000-vertex speed space in a temporary directory unless ``--space`` is given, and runs 4 clients
x 30 fps for 4 s (1.5 s of warm-up) in one client process, every client sending parameters, then
the same 4 clients against a 1-worker and a 2-worker server side by side; it needs ``--out``.

``--graph GRAPH`` (a ``.mgraph`` file, or a name under data/spaces; with ``--tiny``, ``tiny``: the
tiny graph with a reach, engine.graph.tiny, built in a temporary directory) makes every client
stream that motion graph instead of a space, from its first cyclic node: the first ``--actions``
share of them (default 0.25) act as a player would, sending an ``action`` to a random other node of
``--action-nodes`` (default walk, stand, jump, reach: those the graph has) at random parameters
every 0.5-1.5 x ``--action-every`` seconds (default 2); the others watch. No client sends params
or asks for the heatmap. It reports frames delivered for the acting and the passive clients
apart, the actions sent, the notices and errors they got, the transitions carried out (changes of
the frames' ``node``, a one-shot's own return and a route's hops included), how many actions saw
their node entered and the time from sending to that (the transition's planned wait included),
and the time from an action to the first frame acknowledging it (``latency_ms``). ``--tiny
--graph tiny``: 4 clients x 30 fps for 6 s, 2 of them acting every second; no workers comparison.

``--baseline DIR`` replaces the rounds above by this tree's server against the server of the
source tree ``DIR`` (another checkout), one worker each, ``--repeat`` rounds each, alternating
(benchmarks/_baseline.py): the medians of their CPU per delivered frame and frames delivered.
``--frames-hash`` replaces the rounds by a deterministic scheduler run hashed frame by frame
(benchmarks/_load_hash.py: every kind of frame, ``sent_at`` zeroed), in this tree and, with
``--baseline DIR``, in DIR's: a change to the hot path must leave the hashes the same.
``--offline`` replaces the server and its clients by the scheduler's work alone
(benchmarks/_offline.py): ``--clients`` sessions, ``--update-share`` of them steering, ``--seconds``
of frames at 60 fps produced by the scheduler's ticks with the sockets replaced by a counter, the
process CPU per frame (``--repeat`` rounds; with ``--baseline``, DIR's scheduler too, alternating);
``--tiny`` runs it too, on its 4 clients, plain and with ``--offline-grid``. The server always binds 127.0.0.1 and is stopped (its whole process group) at
the end, whatever happens.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _baseline import compare_code
from _load_hash import frames_hashes
from _offline import offline_rounds
from _tiny import parse_arguments
from _load_clients import soak_process
from _load_round import CPU_TARGET_US, acting_clients, load_round, rss_mb
from _workers import compare_workers, start_server, warm_up

ROOT = Path(__file__).resolve().parents[1]
TINY = {"clients": 4, "fps": 30.0, "seconds": 4.0, "warmup": 1.5, "client_procs": 1, "update_share": 1.0,
        "compare_workers": [1, 2], "levels": [4], "heatmap_clients": 1}
TINY_GRAPH = dict(TINY, seconds=6.0, actions=0.5, action_every=1.0, compare_workers=None, heatmap_clients=0)
ACTION_NODES = ("walk", "stand", "jump", "reach")


def served_space(data, space, tiny):
    """Put the space to serve into ``data/spaces``: with ``tiny`` and no ``space``, a 1,000-vertex
    speed space built there; otherwise a link to ``space`` (default data/spaces/locomotion.mspace)."""
    if space is None and tiny:
        from _tiny import build_tiny_speed_space

        path = data / "spaces" / "speed.mspace"
        build_tiny_speed_space(path)
        return path
    source = Path(space or ROOT / "data" / "spaces" / "locomotion.mspace").resolve()
    path = data / "spaces" / source.name
    path.symlink_to(source)
    return path


def served_graph(data, graph, tiny):
    """Put the motion graph to serve into ``data/spaces`` with its nodes' spaces: with ``tiny`` and
    ``graph`` "tiny", the tiny graph (walk, stand, jump, reach) built there; otherwise links to the
    ``.mgraph`` file ``graph`` (or data/spaces/GRAPH.mgraph) and to its spaces."""
    from engine.graph import MotionGraph  # here, not at the top: the client processes never need it

    spaces = data / "spaces"
    if tiny and str(graph) == "tiny":
        from engine.graph.tiny import build_tiny_graph, build_tiny_spaces

        build_tiny_spaces(spaces, reach=True)
        build_tiny_graph(spaces, spaces / "tiny.mgraph", reach=True)
        return spaces / "tiny.mgraph"
    source = Path(graph)
    if source.suffix != ".mgraph" and not source.exists():
        source = ROOT / "data" / "spaces" / f"{graph}.mgraph"
    source = source.resolve()
    with MotionGraph.open(source, verify=False) as opened:
        records = opened.metadata["nodes"]
    for record in records:
        space = (source.parent / record["space"]).resolve()
        link = spaces / Path(record["space"]).name
        if not link.exists():
            link.symlink_to(space)
    (spaces / source.name).symlink_to(source)
    return spaces / source.name


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop_process_group(process, timeout=15.0):
    """SIGTERM the process group led by ``process`` (started with start_new_session), SIGKILL it
    after ``timeout`` seconds."""
    try:
        os.killpg(process.pid, signal.SIGTERM)
        process.wait(timeout)
    except ProcessLookupError:  # the group has already gone
        pass
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
    process.wait()
























def _counts(text):
    try:
        values = [int(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected positive integers separated by commas, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers separated by commas, got {text!r}")
    return values


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--space", type=Path,
                        help="motion space to serve (default data/spaces/locomotion.mspace; with --tiny a "
                             "1,000-vertex speed space built for the run)")
    parser.add_argument("--clients", type=int, default=200)
    parser.add_argument("--fps", type=float, default=60.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--warmup", type=float, default=4.0)
    parser.add_argument("--client-procs", type=int, default=2)
    parser.add_argument("--update-share", type=float, default=0.25, help="share of clients sending params")
    parser.add_argument("--heatmap-clients", type=int, default=0,
                        help="clients asking for the heatmap (distances from the non-linear blend) too")
    parser.add_argument("--update-every", type=float, default=0.5, help="seconds between their updates")
    parser.add_argument("--graph", help="stream this motion graph (a .mgraph file, or a name under data/spaces; "
                                        "with --tiny, 'tiny' builds one) instead of a space; no params, no heatmap")
    parser.add_argument("--actions", type=float, default=0.25,
                        help="with --graph: share of the clients sending actions (default 0.25)")
    parser.add_argument("--action-every", type=float, default=2.0,
                        help="with --graph: mean seconds between an acting client's actions (0.5-1.5 x this)")
    parser.add_argument("--action-nodes", default=",".join(ACTION_NODES),
                        help="with --graph: the nodes actions ask for (those the graph has; default "
                             "walk,stand,jump,reach)")
    parser.add_argument("--repeat", type=int, default=1, help="measuring rounds against the same server "
                                                               "(each reported; the median of their means)")
    parser.add_argument("--workers", type=int, default=1, help="server worker processes (morphspace serve --workers)")
    parser.add_argument("--compare-workers", type=_counts, metavar="A,B",
                        help="instead of the rounds above: servers of A and B workers side by side, each taking "
                             "the client counts of --levels in turn until it misses 95%% delivered")
    parser.add_argument("--levels", type=_counts, default=[100, 150, 200, 250, 300, 350, 400, 450, 500],
                        metavar="N,N,...", help="client counts of --compare-workers (default 100,150,...,500)")
    parser.add_argument("--baseline", type=Path, metavar="DIR",
                        help="instead of the rounds above: this tree's server against DIR's (another checkout of "
                             "the project), --repeat rounds each, alternating")
    parser.add_argument("--offline", action="store_true",
                        help="the scheduler's CPU per frame without sockets or a server (benchmarks/_offline.py)")
    parser.add_argument("--frames-hash", action="store_true",
                        help="hash every frame of a deterministic scheduler run, here and in --baseline's tree "
                             "(benchmarks/_load_hash.py)")
    parser.add_argument("--offline-grid", action="store_true",
                        help="with --offline: the sessions say hello spread over a period, then are served on the "
                             "tree's own grids and ticks (server.scheduler.TICK), as online, instead of full batches")
    parser.add_argument("--soak", type=float, default=0.0, help="seconds of connect/leave soak (0: none)")
    parser.add_argument("--soak-clients", type=int, default=50)
    parser.add_argument("--tiny", action="store_true",
                        help="smoke run: 4 clients x 30 fps for 4 s in one process, on a 1,000-vertex space "
                             "built for the run unless --space is given; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/stream_load.json)")
    given = sys.argv[1:] if argv is None else argv
    graph = any(a == "--graph" or a.startswith("--graph=") for a in given)
    args = parse_arguments(parser, argv, TINY_GRAPH if graph else TINY)
    if args.graph is not None:
        if args.baseline is not None or args.compare_workers and not args.tiny:
            parser.error("--graph measures one server: no --baseline or --compare-workers")
        if args.heatmap_clients:
            parser.error("--graph: heatmaps are for spaces (no --heatmap-clients)")
        if not 0.0 <= args.actions <= 1.0 or not args.action_every > 0:
            parser.error("--actions must be a share in [0, 1] and --action-every a positive number of seconds")
        args.update_share = 0.0
    out = args.out or ROOT / "benchmarks" / "results" / ("stream_load_graph.json" if args.graph else "stream_load.json")

    data = Path(tempfile.mkdtemp(prefix="morphspace-bench-"))
    try:
        (data / "spaces").mkdir()
        space_path = None if args.graph is not None else served_space(data, args.space, args.tiny)
        if args.graph is not None:
            result = serve_and_measure(args, data, served_graph(data, args.graph, args.tiny))
        elif args.frames_hash:
            result = {"frames_hash": frames_hashes(args, space_path, ROOT)}
        elif args.offline and not args.tiny:
            result = {"offline": offline_rounds(args, space_path, ROOT)}
        elif args.baseline is not None:
            name, n_vertices, params = space_figures(space_path)
            result = {"baseline_comparison": compare_code(args, data, name, n_vertices, params, load_round,
                                                          stop_process_group)}
        elif args.compare_workers and not args.tiny:
            result = {"workers_comparison": measure_workers(args, data, space_path)}
        else:
            result = serve_and_measure(args, data, space_path)
            if args.compare_workers:  # --tiny: the smoke run tries both
                result["workers_comparison"] = measure_workers(args, data, space_path)
            if args.tiny:  # and the offline measures, plain and on the online grids
                result["offline"] = offline_rounds(args, space_path, ROOT)
                args.offline_grid = True
                result["offline_grid"] = offline_rounds(args, space_path, ROOT)
    finally:
        shutil.rmtree(data, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return 0


def warm_up_graph(port, name, workers):
    """Stream the graph once per worker (a hello, its topology) so that the graph is open and its
    nodes' blenders set up before the clients come; needs a node the actions may ask for."""
    import asyncio

    import msgpack
    import websockets

    async def once():
        async with websockets.connect(f"ws://127.0.0.1:{port}/v1/stream", max_size=2**26, compression=None) as ws:
            await ws.send(msgpack.packb({"type": "hello", "graph": name, "codec": "q16", "rate": 1.0}))
            while True:
                msg = msgpack.unpackb(await asyncio.wait_for(ws.recv(), timeout=120))
                if msg["type"] == "error":
                    raise RuntimeError(f"graph {name}: {msg['code']}: {msg['message']}")
                if msg["type"] == "topology":
                    return

    for _ in range(4 * workers):  # connections land on workers as the kernel spreads them
        asyncio.run(once())


def space_figures(space_path):
    """(name, vertices, [(parameter, (min, max))]) of the space served (of a ``.mgraph``: its name,
    vertices, and no parameters: graph clients send actions, not params)."""
    from engine.motion_space import MotionSpace  # here, not at the top: the client processes never need it

    if space_path.suffix == ".mgraph":
        from engine.graph import MotionGraph

        with MotionGraph.open(space_path, verify=False) as graph:
            return space_path.stem, int(graph.metadata["n_vertices"]), []

    with MotionSpace.open(space_path, verify=False) as space:
        pmap = space.parameter_map
        return space_path.stem, space.n_vertices, list(zip(pmap.names, pmap.domain()))


def measure_workers(args, data, space_path):
    """--compare-workers: benchmarks/_workers.py's side-by-side capacity search."""
    name, n_vertices, params = space_figures(space_path)
    print(f"{name} ({n_vertices} vertices, q16) at {args.fps:g} fps, {args.seconds:g} s per round:")
    record = compare_workers(args, data, name, n_vertices, params, load_round, stop_process_group)
    return dict(record, space=name, n_vertices=n_vertices, fps=args.fps, seconds=args.seconds)


def serve_and_measure(args, data, space_path):
    """Start ``morphspace serve`` (``--workers``) on 127.0.0.1 over ``data``, run the rounds (and
    the soak), stop the server; returns the result record."""
    name, n_vertices, params = space_figures(space_path)
    server, port = start_server(data, args.workers, max(1000, args.clients * 2))
    url = f"ws://127.0.0.1:{port}/v1/stream"
    result = {"space": name, "n_vertices": n_vertices, "clients": args.clients, "fps": args.fps,
              "codec": "q16", "seconds": args.seconds, "cpus": os.cpu_count(), "workers": args.workers}
    if args.graph is not None:
        nodes = [n for n in args.action_nodes.split(",") if n]
        args.graph_settings = {"name": name, "every": args.action_every, "nodes": nodes}
        result.update(space=None, graph=name, acting_clients=acting_clients(args), action_every=args.action_every,
                      action_nodes=nodes)
    try:
        if args.graph is not None:
            warm_up_graph(port, name, args.workers)  # open it, and its nodes' blenders, in every worker
        else:
            warm_up(port, name)  # open (and verify) it once in every worker
        rss_start = rss_mb(server.pid)
        ctx = mp.get_context("spawn")
        rounds = []
        for k in range(args.repeat):
            if args.repeat > 1:
                print(f"round {k + 1} of {args.repeat}:")
            rounds.append(load_round(args, port, name, n_vertices, params, server.pid, ctx, rss_start, 17 + 10 * k))
        result.update(rounds[-1])
        if args.repeat > 1:
            values = [r["delivered_mean"] for r in rounds]
            p99s = [r["latency_ms"]["p99"] for r in rounds]
            result["rounds"] = rounds
            result["delivered_mean_median"] = statistics.median(values)
            result["latency_p99_ms_median"] = statistics.median(p99s)
            per_frame = [r["server_cpu_us_per_frame"] for r in rounds]
            result["server_cpu_us_per_frame_median"] = statistics.median(per_frame)
            print(f"{args.repeat} rounds: frames delivered (mean per round) "
                  f"{', '.join(f'{100 * v:.1f}%' for v in values)}: median {100 * statistics.median(values):.1f}%; "
                  f"update -> frame p99 median {statistics.median(p99s):.1f} ms; server CPU per delivered frame "
                  f"{', '.join(f'{v:.1f}' for v in per_frame)} us: median {statistics.median(per_frame):.1f} us "
                  f"(TARGET <= {CPU_TARGET_US:.0f} us at 200 clients: "
                  f"{'met' if statistics.median(per_frame) <= CPU_TARGET_US else 'NOT met'})")
        if args.soak > 0:
            per = [args.soak_clients // args.client_procs] * args.client_procs
            procs = [ctx.Process(target=soak_process, args=(url, name, n, args.fps, args.soak, 99 + i))
                     for i, n in enumerate(per)]
            for p in procs:
                p.start()
            samples = []
            start = time.monotonic()
            while any(p.is_alive() for p in procs) and time.monotonic() - start < args.soak + 60:
                samples.append((time.monotonic() - start, rss_mb(server.pid)))
                time.sleep(5.0)
            for p in procs:
                p.join(30)
            half = [s for s in samples if s[0] >= args.soak / 2]
            slope = float("nan")
            if len(half) >= 3:
                import numpy as np
                slope = float(np.polyfit([t for t, _ in half], [m for _, m in half], 1)[0] * 60.0)
            values = [m for _, m in samples]
            result["soak"] = {"seconds": args.soak, "clients": sum(per), "rss_mb_start": values[0],
                              "rss_mb_end": values[-1], "rss_mb_max": max(values),
                              "second_half_slope_mb_per_min": slope, "samples": samples}
            print(f"  soak {args.soak:.0f} s, {sum(per)} clients connecting and leaving: RSS {values[0]:.0f} -> "
                  f"{values[-1]:.0f} MB (max {max(values):.0f}), second-half slope {slope:+.2f} MB/min")
    finally:
        stop_process_group(server)
    return result


if __name__ == "__main__":
    sys.exit(main())
