"""The stream's socket path alone: what one frame's write costs the server, without the server.

    .venv/bin/python benchmarks/stream_socket.py                    # 200 clients x 60 fps, 18 KB frames, 10 s
    .venv/bin/python benchmarks/stream_socket.py --tiny --out /tmp/stream_socket.json   # smoke run, ~5 s

A uvloop event loop (what ``morphspace serve`` runs) accepts ``--clients`` TCP connections on
127.0.0.1 from ``--client-procs`` other processes (uvloop loops that read and drop everything),
then writes each connection a frame of ``--bytes`` bytes ``--fps`` times a second as the server's
scheduler does (server/scheduler.py, server/transport.py): ticks of at most 32 connections,
each frame one gathered ``writelines`` of a WebSocket header, the small fields and the vertex
bytes, only into a transport holding nothing, the kernel's unsent bytes bounded by
``TCP_NOTSENT_LOWAT`` and its send queue read (``SIOCOUTQ``) after each write. It reports the
writing process's user and system CPU per frame written (``os.times``) and the machine's load.

On loopback the kernel runs the receiving side of every segment (TCP receive, queueing, waking
the reading process) inside the sender's system call, so the system time here, and in the
server's figure, includes work that a real network would do on the client's machine.
Results go to benchmarks/results/stream_socket.json (``--tiny`` needs ``--out``).
"""

from __future__ import annotations

import argparse
import asyncio
import fcntl
import json
import multiprocessing as mp
import os
import socket
import sys
import termios
import time
from pathlib import Path

from _tiny import parse_arguments

ROOT = Path(__file__).resolve().parents[1]
TINY = {"clients": 8, "seconds": 2.0, "client_procs": 1}
BATCH = 32           # connections per tick at most (server/scheduler.py MAX_BATCH)
TICK = 0.002         # seconds between ticks (server/scheduler.py TICK)
UNSENT_LIMIT = 32 * 1024  # server/transport.py


def readers(port, count, seconds):
    """``count`` connections to ``port`` reading and dropping everything for ``seconds``."""
    import uvloop

    async def one():
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        while await reader.read(1 << 20):
            pass

    async def main():
        tasks = [asyncio.create_task(one()) for _ in range(count)]
        await asyncio.sleep(seconds)
        for task in tasks:
            task.cancel()

    uvloop.run(main())


async def write_frames(args):
    loop = asyncio.get_running_loop()
    transports = []

    class Accept(asyncio.Protocol):
        def connection_made(self, transport):
            sock = transport.get_extra_info("socket")
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NOTSENT_LOWAT, UNSENT_LIMIT)
            transports.append((transport, sock.fileno()))

    server = await loop.create_server(Accept, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    per = [args.clients // args.client_procs + (i < args.clients % args.client_procs) for i in range(args.client_procs)]
    procs = [mp.get_context("spawn").Process(target=readers, args=(port, n, args.seconds + 30)) for n in per]
    for p in procs:
        p.start()
    deadline = time.monotonic() + 30
    while len(transports) < args.clients and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    if len(transports) < args.clients:
        raise RuntimeError(f"only {len(transports)} of {args.clients} connections came")
    small = os.urandom(300)   # the frame's small fields (server/frames.py StreamedFrame: about 300 bytes)
    vertices = memoryview(bytearray(os.urandom(args.bytes)))
    length = len(small) + len(vertices)
    header = b"\x82\x7e" + length.to_bytes(2, "big") if length < 1 << 16 else b"\x82\x7f" + length.to_bytes(8, "big")
    word = bytearray(4)
    written = skipped = 0
    await asyncio.sleep(1.0)
    start, times = time.monotonic(), os.times()
    frame = 0
    while time.monotonic() - start < args.seconds:
        due = start + frame / args.fps
        await asyncio.sleep(max(0.0, due - time.monotonic()))
        for first in range(0, len(transports), BATCH):
            for transport, fd in transports[first:first + BATCH]:
                if transport.get_write_buffer_size():
                    skipped += 1
                    continue
                transport.writelines([header, small, vertices])
                fcntl.ioctl(fd, termios.TIOCOUTQ, word)
                written += 1
            await asyncio.sleep(TICK)
        frame += 1
    after = os.times()
    elapsed = time.monotonic() - start
    for transport, _ in transports:
        transport.abort()
    server.close()
    for p in procs:
        p.terminate()
        p.join(10)
    user, system = after.user - times.user, after.system - times.system
    return {"clients": args.clients, "fps": args.fps, "bytes": args.bytes, "seconds": elapsed, "frames": written,
            "skipped": skipped, "user_us_per_frame": 1e6 * user / max(written, 1),
            "system_us_per_frame": 1e6 * system / max(written, 1),
            "cpu_us_per_frame": 1e6 * (user + system) / max(written, 1), "load_average": os.getloadavg()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clients", type=int, default=200)
    parser.add_argument("--fps", type=float, default=60.0)
    parser.add_argument("--bytes", type=int, default=18000, help="vertex bytes a frame (3,000 vertices in q16: 18,000)")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--client-procs", type=int, default=2)
    parser.add_argument("--tiny", action="store_true", help="smoke run: 8 clients for 2 s in one process; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/stream_socket.json)")
    args = parse_arguments(parser, argv, TINY)
    import uvloop

    result = uvloop.run(write_frames(args))
    print(f"{result['clients']} loopback clients x {args.fps:g} fps, {args.bytes + 300} byte frames: "
          f"{result['frames']} written ({result['skipped']} skipped, the transport not empty), "
          f"{result['cpu_us_per_frame']:.1f} us of the writer's CPU a frame: {result['user_us_per_frame']:.1f} user, "
          f"{result['system_us_per_frame']:.1f} system (load average {result['load_average'][0]:.1f})")
    out = args.out or ROOT / "benchmarks" / "results" / "stream_socket.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
