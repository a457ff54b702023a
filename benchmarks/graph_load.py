"""Motion graph streams without sockets: the server's CPU per frame of ``--clients`` graph streams.

``stream_load.py --graph`` measures the whole server (sockets, event loop, load generator) on a
host whose load makes its CPU per delivered frame swing by tens of percent from round to round.
This measures the part the graph's code decides, the way ``stream_load.py --offline`` does for
spaces: ``--clients`` real StreamSessions streaming the graph (``GraphStream``, q16, 60 frames/s,
hybrid), the first ``--actions`` share of them acting as ``stream_load.py --graph``'s clients do
(an ``action`` to a random other node of ``--action-nodes`` at random parameters every 0.5-1.5 x
``--action-every`` seconds of simulated time), every session due once per frame period, taken in
ticks of the scheduler's batch size and produced by ``FrameScheduler._produce``; a counter takes
each frame's message. It reports the process CPU (``time.process_time``) per frame of the ticks,
and of the actions (their transition searches) apart, with the frames' node changes.

``--baseline DIR`` runs DIR's server code (another checkout) the same way, in alternating rounds
(given more than once: each tree in turn, the order reversed every other round), and reports the
ratios of the medians. ``--check`` adds a digest of every frame's q16 vertices
(outside the timed part's figures: a round with it is not timed) to say whether the two trees
stream the same bytes.

    .venv/bin/python benchmarks/graph_load.py --graph /tmp/graph-d0/spaces/demo.mgraph --repeat 3
    .venv/bin/python benchmarks/graph_load.py --graph data/spaces/demo.mgraph --baseline /tmp/before --repeat 5
    .venv/bin/python benchmarks/graph_load.py --graph data/spaces/demo.mgraph --baseline /tmp/before --check
    .venv/bin/python benchmarks/graph_load.py --tiny --out /tmp/graph_load.json   # the tiny graph, ~20 s

Each round runs in a fresh interpreter with the tree first on the path (this tree's too), so
``--baseline`` measures DIR's code. Results go to benchmarks/results/graph_load.json.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import hashlib
import json
import os
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

from _tiny import parse_arguments
from _workers import json_in_tree

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
TINY = {"clients": 8, "seconds": 3.0, "repeat": 1, "action_every": 1.0}


class _Counter:
    """Takes every frame at once (a transport that never fills); with ``digest``, hashes the
    frame's vertices (the message's last part: server.frames.frame_parts, StreamedFrame.parts)."""

    def __init__(self, digest=None):
        self.frames = self.bytes = 0
        self.digest = digest

    def ready(self):
        return True

    def held(self):
        return 0

    def held_above(self, floor):
        return None

    def write_message(self, parts):
        self.frames += 1
        for part in parts:
            self.bytes += part.nbytes if isinstance(part, memoryview) else len(part)
        if self.digest is not None:
            self.digest.update(parts[-1])
        return True


class _Socket:
    def __init__(self, counter):
        self.scope = {"extensions": {"morphspace.transport": counter}}


async def _measure(graph_path, clients, seconds, share, every, nodes, seed, check):
    from server import protocol as P
    from server.graph_stream import GraphStream, prepare
    from server.graphs import GraphRegistry
    from server.registry import SpaceRegistry
    from server.scheduler import MAX_BATCH, FrameScheduler
    from server.settings import Settings
    from server.stream.session import StreamSession, StreamStats

    graph_path = Path(graph_path)
    registry = SpaceRegistry(graph_path.parent)
    graphs = GraphRegistry(registry)
    name = graph_path.stem
    graph = graphs.get(name)
    await prepare(graph, "hybrid")
    scheduler, stats, settings = FrameScheduler(), StreamStats(), Settings()
    rng = random.Random(seed)
    digest = hashlib.blake2b(digest_size=16) if check else None
    names = [n for n in nodes if n in {node.name for node in graph.nodes}]
    domains = {node.name: list(zip(node.space.parameter_map.names, node.space.parameter_map.domain()))
               if node.space.parameter_map is not None else [] for node in graph.nodes}
    sessions, acting = [], []
    for k in range(clients):
        session = StreamSession(_Socket(_Counter(digest)), registry, settings, stats, scheduler, graphs)
        stream = GraphStream(graph, name, mode="hybrid")
        stream.notify = lambda notice: None
        session.player = session.graph = stream
        session.space_name, session.rate, session.codec = f"graph {name}", 60.0, "q16"
        session.bounds = stream.bounds()
        session.quantiser = P.Quantiser(session.bounds, stream.space.n_vertices)
        session.ready = True
        sessions.append(session)
        acting.append(k < round(share * clients))
    gc.freeze()
    period = 1.0 / 60.0
    next_action = [rng.uniform(0.5, 0.5 + every) if a else float("inf") for a in acting]
    seqs = [0] * clients
    tick_cpu = action_cpu = 0.0
    actions = entered = 0
    shown = [s.graph.node for s in sessions]
    for step in range(1, int(round(seconds * 60)) + 1):
        now = 1000.0 + step * period
        started = time.process_time()
        for k, session in enumerate(sessions):
            if now - 1000.0 >= next_action[k]:
                choices = [n for n in names if n != session.graph.node]
                node = rng.choice(choices)
                params = {p: rng.uniform(lo, hi) for p, (lo, hi) in domains[node]}
                seqs[k] += 1
                session.graph.action(P.Action(node=node, params=params, seq=seqs[k]))
                session.ack = seqs[k]
                actions += 1
                next_action[k] += every * rng.uniform(0.5, 1.5)
        middle = time.process_time()
        for first in range(0, clients, MAX_BATCH):
            batch = sessions[first:first + MAX_BATCH]
            for session in batch:
                session.next_due = now
            scheduler._produce(batch, now)
        ended = time.process_time()
        action_cpu += middle - started
        tick_cpu += ended - middle
        scheduler._heap.clear()  # every session is due again next period anyway
        for k, session in enumerate(sessions):
            if session.graph.node != shown[k]:
                entered += 1
                shown[k] = session.graph.node
    frames = sum(s.gauge.frames for s in sessions)
    failed = stats.errors
    return {"clients": clients, "acting": sum(acting), "simulated_seconds": seconds, "frames": frames,
            "actions": actions, "transitions": entered, "errors": failed, "cpu_s": tick_cpu,
            "us_per_frame": 1e6 * tick_cpu / max(frames, 1), "action_cpu_s": action_cpu,
            "action_us_per_frame": 1e6 * action_cpu / max(frames, 1),
            "digest": digest.hexdigest() if digest is not None else None}


def measure(graph_path, clients, seconds, share, every, nodes, seed=1, check=False):
    """One round in this process (this interpreter's server code); returns its record."""
    return asyncio.run(_measure(graph_path, clients, seconds, share, every, nodes, seed, check))


def measure_in(tree, graph_path, clients, seconds, share, every, nodes, seed=1, check=False):
    """One round in a fresh interpreter running ``tree``'s server code."""
    return json_in_tree(tree, "graph_load.py", ["--round", graph_path, clients, seconds, share, every, ",".join(nodes),
                                                seed, "1" if check else "0"], "graph round", timeout=3600)


def tiny_graph(directory):
    """The tiny graph with a reach (engine.graph.tiny) built in ``directory``; its path."""
    from engine.graph.tiny import build_tiny_graph, build_tiny_spaces

    build_tiny_spaces(directory, reach=True)
    build_tiny_graph(directory, directory / "tiny.mgraph", reach=True)
    return directory / "tiny.mgraph"


def rounds(args, graph_path):
    """``--repeat`` rounds of this tree (and of ``--baseline``'s, alternating); with ``--check``,
    one untimed round of each comparing the frames' digests."""
    trees = {}
    for k, tree in enumerate(args.baseline or []):
        trees["baseline" if len(args.baseline) == 1 else f"baseline {k + 1} ({Path(tree).name})"] = Path(tree).resolve()
    trees["this tree"] = ROOT
    nodes = args.action_nodes.split(",")
    common = (graph_path, args.clients, args.seconds, args.actions, args.action_every, nodes)
    print(f"graph load offline: {args.clients} graph streams of {graph_path.name}, {100 * args.actions:.0f}% acting "
          f"(every {args.action_every:g} s x 0.5-1.5), {args.seconds:g} s of frames at 60 fps per round, q16, "
          f"sockets replaced by a counter (process CPU)")
    records = {label: [] for label in trees}
    for k in range(args.repeat):
        for label in (list(trees) if k % 2 == 0 else list(trees)[::-1]):
            r = measure_in(trees[label], *common)
            records[label].append(r)
            print(f"  {label}, round {k + 1}: {r['us_per_frame']:.1f} us per frame (+ actions "
                  f"{r['action_us_per_frame']:.1f} us), {r['frames']} frames, {r['actions']} actions, "
                  f"{r['transitions']} node changes, {r['errors']} errors")
    summary = {label: statistics.median(r["us_per_frame"] for r in records[label]) for label in trees}
    actions = {label: statistics.median(r["action_us_per_frame"] for r in records[label]) for label in trees}
    result = {"graph": graph_path.stem, "clients": args.clients, "actions": args.actions, "seconds": args.seconds,
              "rounds": records, "us_per_frame_median": summary, "action_us_per_frame_median": actions,
              "load_average": os.getloadavg()}
    line = ", ".join(f"{label} median {summary[label]:.1f} us (+ actions {actions[label]:.1f})" for label in trees)
    if args.baseline:
        result["ratios"] = {label: summary["this tree"] / summary[label] for label in trees if label != "this tree"}
        line += ": " + ", ".join(f"{ratio:.2f}x {label}" for label, ratio in result["ratios"].items())
    print(f"  CPU per frame: {line} (load average {os.getloadavg()[0]:.1f})")
    if args.check:
        digests = {label: measure_in(trees[label], *common, check=True)["digest"] for label in trees}
        result["digests"] = digests
        result["same_frames"] = len(set(digests.values())) == 1
        print(f"  frames' q16 vertices: {', '.join(f'{k} {v}' for k, v in digests.items())}"
              + (f" ({'the same' if result['same_frames'] else 'DIFFERENT'})" if len(digests) > 1 else ""))
    return result


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--graph", type=Path, help="the .mgraph file (its spaces beside it)")
    parser.add_argument("--clients", type=int, default=200)
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds of frames per round")
    parser.add_argument("--actions", type=float, default=0.25, help="share of the clients sending actions")
    parser.add_argument("--action-every", type=float, default=2.0, help="mean seconds between an acting client's "
                                                                         "actions (0.5-1.5 x this)")
    parser.add_argument("--action-nodes", default="walk,stand,jump,reach", help="the nodes actions ask for")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--baseline", type=Path, action="append",
                        help="another checkout whose server code is measured too (may be given more than once)")
    parser.add_argument("--check", action="store_true", help="also compare the frames' bytes (an untimed round each)")
    parser.add_argument("--tiny", action="store_true", help="smoke run: the tiny graph, 8 clients, 3 s; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/graph_load.json)")
    args = parse_arguments(parser, argv, TINY)
    if args.tiny:
        with tempfile.TemporaryDirectory(prefix="graph-load-") as tmp:
            args.check = True
            result = rounds(args, tiny_graph(Path(tmp)))
    else:
        if args.graph is None:
            parser.error("--graph is required (or --tiny)")
        if not args.graph.is_file():
            parser.error(f"--graph {args.graph}: no such file")
        result = rounds(args, args.graph.resolve())
    out = args.out or HERE / "results" / "graph_load.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"results: {out}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--round":
        g, c, s, a, e, n, seed, chk = sys.argv[2:10]
        print(json.dumps(measure(g, int(c), float(s), float(a), float(e), n.split(","), int(seed), chk == "1")))
    else:
        main()
