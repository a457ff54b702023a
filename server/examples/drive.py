"""Drive a motion space from a script, as a game-engine bridge would.

    python -m server.examples.drive --space locomotion --seconds 6 --obj last.obj

Connects to a running `morphspace serve`, steers the first parameter up and down (and the
second, if there is one, in a slow sine: a locomotion space weaves left and right), receives
frames as numpy arrays and reports per second what arrived: frames, dropped ticks, latency of the
newest parameter change, realised parameters and where the character is. Then it pulls one frame
at chosen parameters and time (how an engine with its own clock asks) and can write the last
frame, placed in the world, as OBJ.
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


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--url", default="ws://127.0.0.1:8000/v1/stream")
    parser.add_argument("--space", default="locomotion")
    parser.add_argument("--codec", default="q16", choices=["f32", "q16"])
    parser.add_argument("--rate", type=float, default=60.0)
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--token")
    parser.add_argument("--obj", help="write the last frame (world coordinates) to this OBJ file")
    args = parser.parse_args(argv)
    return asyncio.run(drive(args))


if __name__ == "__main__":
    sys.exit(main())
