"""Drive a motion space, or a motion graph, from a script, as a game-engine bridge would.

    python -m server.examples.drive --space locomotion --seconds 6 --obj last.obj
    python -m server.examples.drive --graph demo --script walk jump walk reach

Connects to a running `morphspace serve`, steers the first parameter up and down (and the
second, if there is one, in a slow sine: a locomotion space weaves left and right), receives
frames as numpy arrays and reports per second what arrived: frames, dropped ticks, latency of the
newest parameter change, realised parameters and where the character is. Then it pulls one frame
at chosen parameters and time (how an engine with its own clock asks) and can write the last
frame, placed in the world, as OBJ.

With ``--graph`` it plays a motion graph instead: it starts at the script's first node and sends
an ``action`` for each of the others in turn (each at the middle of its parameters unless
``--set NODE.NAME=VALUE`` says otherwise), waiting until the character has entered that node and,
for a one-shot (a jump, a reach), until it has landed back on a cyclic node. It prints the
server's plan for each action, the frames' node / target / progress as they change, how long
each request took to enter its node, and the root's fastest motion between frames (the character
keeps its place in the world across transitions: no jump of the root).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
import time

import numpy as np

from server.client import StreamClient


async def drive(args):
    async with StreamClient.connect(args.url, args.space, codec=args.codec, rate=args.rate, window=2,
                                    token=args.token) as client:
        t = client.topology
        print(f"{t.space}: {t.n_vertices} vertices, {t.n_faces} faces, codec {t.codec} "
              f"(max quantisation error {t.quantisation_error * 1e3:.3f} mm), parameters: "
              + ", ".join(f"{p['name']} [{p['min']:.3g}, {p['max']:.3g}] {p['unit']}" for p in t.parameters))
        params = t.parameters
        start = time.monotonic()
        report_at, frames, frame = start + 1.0, 0, None
        sent = {}
        latencies = []
        while time.monotonic() - start < args.seconds:
            elapsed = time.monotonic() - start
            request = {}
            for k, p in enumerate(params[:2]):
                wave = 0.5 + 0.5 * math.sin(2 * math.pi * elapsed / (4.0 + 3.0 * k))
                request[p["name"]] = p["min"] + wave * (p["max"] - p["min"])
            if frames % 10 == 0:
                seq = await client.set_params(request)
                sent[seq] = time.monotonic()
            frame = await client.next_frame()
            frames += 1
            for seq in [s for s in sent if s <= frame.ack]:
                latencies.append(time.monotonic() - sent.pop(seq))
            if time.monotonic() >= report_at:
                realised = ", ".join(f"{k} {v:.3g}" for k, v in frame.realised.items())
                latency = f"{1e3 * np.median(latencies):.1f} ms" if latencies else "-"
                print(f"  t={elapsed:4.1f} s  frames {frames:4d}  dropped {frame.dropped:3d}  update->frame {latency}"
                      f"  realised: {realised}  root ({frame.root[0]:+.2f}, {frame.root[2]:+.2f}) m", flush=True)
                report_at += 1.0
        middle = {p["name"]: (p["min"] + p["max"]) / 2 for p in params}
        pulled = await client.pull(middle, time=1.0)
        print(f"pulled the frame at {middle} after 1 s: phase {pulled.phase:.3f}, root {np.round(pulled.root, 3)}")
        if args.obj and frame is not None:
            from engine.mesh_io import write_obj
            write_obj(args.obj, frame.world_vertices(), client.faces)
            print(f"wrote {args.obj}")
    return 0


def _script_params(assignments, nodes):
    """{node: {name: value}} from ``NODE.NAME=VALUE`` strings; errors name the bad one."""
    out = {}
    for item in assignments:
        key, sep, value = item.partition("=")
        node, dot, name = key.partition(".")
        if not sep or not dot:
            raise SystemExit(f"--set: expected NODE.NAME=VALUE, got {item!r}")
        if node not in nodes or name not in [p["name"] for p in nodes[node]["parameters"]]:
            raise SystemExit(f"--set {item}: the graph has no node {node!r} with a parameter {name!r}")
        out.setdefault(node, {})[name] = float(value)
    return out


async def drive_graph(args):
    script = args.script
    async with StreamClient.connect(args.url, graph=args.graph, node=script[0], codec=args.codec, rate=args.rate,
                                    window=2, token=args.token) as client:
        t = client.topology
        nodes = {n["name"]: n for n in t.nodes}
        unknown = [name for name in script if name not in nodes]
        if unknown:
            raise SystemExit(f"the graph {t.graph!r} has no node(s) {', '.join(unknown)}; it has {', '.join(nodes)}")
        chosen = _script_params(args.set, nodes)
        print(f"graph {t.graph}: {len(nodes)} nodes ({', '.join(nodes)}), {len(t.edges)} edges, "
              f"{t.n_vertices} vertices, codec {t.codec}; starting at {script[0]}")
        frame = await client.next_frame()
        last, fastest, state, entered = frame, 0.0, None, []
        start = time.monotonic()

        async def until(done, what, timeout):
            nonlocal frame, last, fastest, state
            deadline = time.monotonic() + timeout
            while not done(frame):
                if time.monotonic() > deadline:
                    raise SystemExit(f"timed out waiting for {what}; last frame: node {frame.node}, "
                                     f"target {frame.target}")
                frame = await client.next_frame()
                if frame.time > last.time:  # the root's speed between frames received (on the server's clock)
                    step = float(np.linalg.norm((frame.root - last.root)[[0, 2]]))
                    fastest = max(fastest, step / (frame.time - last.time))
                last = frame
                now = (frame.node, frame.target, frame.progress is not None)
                if now != state:
                    state = now
                    progress = "" if frame.progress is None else f"  blending {frame.progress:.2f}"
                    print(f"  t={time.monotonic() - start:5.2f} s  node {frame.node:<8} target {frame.target or '-':<8}"
                          f"{progress}  root ({frame.root[0]:+.2f}, {frame.root[2]:+.2f}) m", flush=True)

        await until(lambda f: True, "the first frame", 10)
        for name in script[1:]:
            params = {p["name"]: chosen.get(name, {}).get(p["name"], p["default"]) for p in nodes[name]["parameters"]}
            sent = time.monotonic()
            seq = await client.action(name, params)
            print(f"action {name} {params or ''}", flush=True)
            await until(lambda f: f.ack >= seq, "the action's acknowledgement", 10)
            for notice in [n for n in client.notices if n.seq == seq]:
                print(f"  server: {notice.code}: {notice.message}")
            await until(lambda f: f.node == name and f.progress is None, f"entering {name}", 30)
            entered.append((name, time.monotonic() - sent))
            if not nodes[name]["cyclic"]:  # a one-shot: wait until it is back on a cyclic node
                await until(lambda f: nodes[f.node]["cyclic"] and f.progress is None, f"the end of {name}", 30)
            else:  # walk on a little
                hold = time.monotonic() + args.hold
                await until(lambda f: time.monotonic() >= hold, "walking on", args.hold + 10)
        for name, seconds in entered:
            print(f"entered {name} {seconds:.2f} s after its action")
        print(f"fastest root motion between frames: {fastest:.2f} m/s; ended at node {frame.node}, root "
              f"({frame.root[0]:+.2f}, {frame.root[2]:+.2f}) m, heading {np.degrees(frame.heading):+.1f} deg")
        if client.errors:
            print("errors: " + "; ".join(f"{e.code}: {e.message}" for e in client.errors))
            return 1
        if args.obj:
            from engine.mesh_io import write_obj
            write_obj(args.obj, frame.world_vertices(), client.faces)
            print(f"wrote {args.obj}")
    return 0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--url", default="ws://127.0.0.1:8000/v1/stream")
    parser.add_argument("--space", default="locomotion")
    parser.add_argument("--graph", help="drive this motion graph (GET /v1/graphs) instead of a space")
    parser.add_argument("--script", nargs="+", default=["walk", "jump", "walk", "reach"],
                        help="with --graph: the start node, then the node of each action in turn")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.NAME=VALUE",
                        help="with --graph: a parameter of a node's actions (default: the middle of its range)")
    parser.add_argument("--hold", type=float, default=1.0, help="with --graph: seconds to stay in a cyclic node")
    parser.add_argument("--codec", default="q16", choices=["f32", "q16"])
    parser.add_argument("--rate", type=float, default=60.0)
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--token")
    parser.add_argument("--obj", help="write the last frame (world coordinates) to this OBJ file")
    args = parser.parse_args(argv)
    return asyncio.run(drive_graph(args) if args.graph else drive(args))


if __name__ == "__main__":
    sys.exit(main())
