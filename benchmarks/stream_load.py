"""Streaming load benchmark: many clients on one server process, latency, and a memory soak.

    .venv/bin/python benchmarks/stream_load.py                       # 200 clients x 60 fps, 20 s
    .venv/bin/python benchmarks/stream_load.py --repeat 3            # three rounds, and their median
    .venv/bin/python benchmarks/stream_load.py --soak 300            # + 5-minute connect/leave soak
    .venv/bin/python benchmarks/stream_load.py --tiny --out /tmp/stream_load.json   # smoke run, ~10 s

Starts ``morphspace serve`` (one process) on 127.0.0.1 over a data directory holding the space
(default data/spaces/locomotion.mspace, 3,000 vertices), then runs the clients in separate
processes (``--client-procs``), each an asyncio loop of plain websockets connections asking for
``--fps`` frames per second in the q16 codec. It reports

- frames delivered: received / (clients x fps x seconds) over the measuring window,
- latency: a share of the clients request new parameters every ``--update-every`` seconds; the
  time from sending to the first frame whose ``ack`` covers the request (median, p95, p99),
- the server's CPU and resident memory; with ``--soak``, resident memory sampled while clients
  connect and leave (start, end, max, and the slope of a line fitted to the second half).

Results go to benchmarks/results/stream_load.json. ``--tiny`` (the test suite's smoke run) builds a
1,000-vertex speed space in a temporary directory unless ``--space`` is given, and runs 4 clients
x 30 fps for 4 s (1.5 s of warm-up) in one client process, every client sending parameters; it
needs ``--out``. The server always binds 127.0.0.1 and is stopped (its whole process group) at
the end, whatever happens.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import json
import multiprocessing as mp
import os
import random
import signal
import socket
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgpack

ROOT = Path(__file__).resolve().parents[1]
TINY = {"clients": 4, "fps": 30.0, "seconds": 4.0, "warmup": 1.5, "client_procs": 1, "update_share": 1.0}


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


def rss_mb(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def reference_loop_ms():
    """Milliseconds of a fixed pure-Python loop (best of three): how fast the host runs Python
    right now. This machine's speed swings (31-55 ms here over one session), and with it how many
    frames one server process can produce."""
    best = float("inf")
    for _ in range(3):
        started = time.perf_counter()
        total = 0
        for i in range(1_000_000):
            total += i * i
        best = min(best, time.perf_counter() - started)
    return 1e3 * best


def machine_times():
    """(busy, idle, steal) seconds of all CPUs since boot (/proc/stat)."""
    with open("/proc/stat") as f:
        fields = [int(x) for x in f.readline().split()[1:]]
    tick = os.sysconf("SC_CLK_TCK")
    idle = fields[3] + fields[4]
    steal = fields[7] if len(fields) > 7 else 0
    return (sum(fields[:8]) - idle - steal) / tick, idle / tick, steal / tick


def cpu_seconds(pid):
    with open(f"/proc/{pid}/stat") as f:
        parts = f.read().rsplit(")", 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


class RawClient(asyncio.Protocol):
    """A minimal WebSocket client (RFC 6455) for load generation: it counts frames by their
    headers and decodes the msgpack body only of frames that may acknowledge a pending update,
    so that the load generator costs little beside the server on a 2-core machine."""

    def __init__(self, host, port, on_message):
        self.host, self.port, self.on_message = host, port, on_message
        self.buffer = bytearray()
        self.upgraded = asyncio.get_running_loop().create_future()
        self.closed = asyncio.get_running_loop().create_future()
        self.transport = None

    def connection_made(self, transport):
        self.transport = transport
        key = base64.b64encode(os.urandom(16)).decode()
        transport.write((f"GET /v1/stream HTTP/1.1\r\nHost: {self.host}:{self.port}\r\nUpgrade: websocket\r\n"
                         f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())

    def data_received(self, data):
        self.buffer += data
        if not self.upgraded.done():
            end = self.buffer.find(b"\r\n\r\n")
            if end < 0:
                return
            if not self.buffer.startswith(b"HTTP/1.1 101"):
                self.upgraded.set_exception(ConnectionError(bytes(self.buffer[:200]).decode(errors="replace")))
                return
            del self.buffer[:end + 4]
            self.upgraded.set_result(True)
        buf = self.buffer
        offset = 0
        while len(buf) - offset >= 2:
            opcode, length = buf[offset] & 0x0F, buf[offset + 1] & 0x7F
            header = 2
            if length == 126:
                if len(buf) - offset < 4:
                    break
                length, header = int.from_bytes(buf[offset + 2:offset + 4], "big"), 4
            elif length == 127:
                if len(buf) - offset < 10:
                    break
                length, header = int.from_bytes(buf[offset + 2:offset + 10], "big"), 10
            if len(buf) - offset < header + length:
                break
            self.on_message(opcode, buf, offset + header, length)
            offset += header + length
        del buf[:offset]

    def connection_lost(self, exc):
        if not self.closed.done():
            self.closed.set_result(exc)

    def send(self, payload, opcode=0x2):
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x80 | opcode]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + n.to_bytes(2, "big"))
        body = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.transport.write(head + mask + body)


async def one_client(host, port, space, fps, seconds, measure_from, measure_to, updates, update_every, params,
                     rng, out):
    loop = asyncio.get_running_loop()
    state = {"frames": 0, "latencies": [], "pending": {}, "transit": []}

    def on_message(opcode, buf, start, length):
        if opcode != 0x2:
            return
        received = time.monotonic()
        if state["pending"]:
            msg = msgpack.unpackb(bytes(buf[start:start + length]))
            if msg.get("type") != "frame":
                return
            for s in [s for s in state["pending"] if s <= msg["ack"]]:
                state["latencies"].append(received - state["pending"].pop(s))
                state["transit"].append(time.time() - msg["sent_at"])  # encoded -> read by the client
        elif b"\xa5frame" not in buf[start:start + 16]:
            return  # the map's first entry is its type: count frames only
        if measure_from <= received < measure_to:
            state["frames"] += 1

    transport, client = await loop.create_connection(lambda: RawClient(host, port, on_message), host, port)
    await client.upgraded
    client.send(msgpack.packb({"type": "hello", "space": space, "codec": "q16", "rate": fps, "seq": 0}))
    seq = 0
    stop = time.monotonic() + seconds
    next_update = time.monotonic() + rng.uniform(0.5, 0.5 + update_every)
    while time.monotonic() < stop:
        if updates and time.monotonic() >= next_update:
            seq += 1
            name, (lo, hi) = rng.choice(params)
            state["pending"][seq] = time.monotonic()
            client.send(msgpack.packb({"type": "params", "params": {name: rng.uniform(lo, hi)}, "seq": seq}))
            next_update += update_every
        wake = min(stop, next_update) if updates else stop
        await asyncio.sleep(max(0.0, wake - time.monotonic()))
    transport.close()
    out.append((state["frames"], state["latencies"], state["transit"]))


def client_process(host, port, space, n, fps, seconds, warmup, update_share, update_every, params, seed, queue):
    rng = random.Random(seed)

    async def main():
        out = []
        start = time.monotonic()
        measure_from, measure_to = start + warmup, start + seconds - 1.0
        tasks = []
        for i in range(n):
            tasks.append(asyncio.create_task(one_client(
                host, port, space, fps, seconds, measure_from, measure_to, rng.random() < update_share, update_every,
                params, random.Random(rng.random()), out)))
            await asyncio.sleep(0.005)  # do not open every connection in the same instant
        results = await asyncio.gather(*tasks, return_exceptions=True)
        failures = [repr(r) for r in results if isinstance(r, BaseException)]
        return out, failures, measure_to - measure_from

    out, failures, window = asyncio.run(main())
    queue.put({"frames": [f for f, _, _ in out], "latencies": [x for _, l, _ in out for x in l],
               "transit": [x for _, _, t in out for x in t],
               "failures": failures, "window": window})


async def soak_client(url, space, fps, hold, rng):
    import websockets
    async with websockets.connect(url, max_size=2**26, compression=None) as ws:
        await ws.send(msgpack.packb({"type": "hello", "space": space, "codec": rng.choice(["q16", "f32"]),
                                     "rate": fps, "mode": rng.choice(["hybrid", "linear"])}))
        stop = time.monotonic() + hold
        while time.monotonic() < stop:
            try:
                await asyncio.wait_for(ws.recv(), timeout=max(0.01, stop - time.monotonic()))
            except asyncio.TimeoutError:
                break


def soak_process(url, space, clients, fps, seconds, seed):
    rng = random.Random(seed)

    async def main():
        stop = time.monotonic() + seconds
        running = set()
        while time.monotonic() < stop:
            while len(running) < clients:
                running.add(asyncio.create_task(soak_client(url, space, fps, rng.uniform(1.0, 8.0), rng)))
            done, running = await asyncio.wait(running, timeout=0.5, return_when=asyncio.FIRST_COMPLETED)
        await asyncio.gather(*running, return_exceptions=True)

    asyncio.run(main())


def load_round(args, port, name, n_vertices, params, server_pid, ctx, rss_start, seed):
    """One measuring round: the clients connect, stream for ``args.seconds`` and leave; the
    server's counters are differences over the round."""
    import httpx

    before = httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=30).json()
    reference_before = reference_loop_ms()
    cpu_start, wall_start = cpu_seconds(server_pid), time.monotonic()
    machine_start = machine_times()
    queue = ctx.Queue()
    per = [args.clients // args.client_procs + (i < args.clients % args.client_procs)
           for i in range(args.client_procs)]
    procs = [ctx.Process(target=client_process, args=("127.0.0.1", port, name, n, args.fps, args.seconds, args.warmup,
                                                       args.update_share, args.update_every, params, seed + i,
                                                       queue)) for i, n in enumerate(per)]
    for p in procs:
        p.start()
    outputs = [queue.get(timeout=args.seconds + 120) for _ in procs]
    for p in procs:
        p.join(30)
    elapsed = time.monotonic() - wall_start
    cpu = (cpu_seconds(server_pid) - cpu_start) / elapsed
    busy, idle, steal = (b - a for a, b in zip(machine_start, machine_times()))
    health = httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=30).json()
    deadline = time.monotonic() + 15
    while health["connections"] and time.monotonic() < deadline:  # closed connections report their drops
        time.sleep(0.2)
        health = httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=30).json()
    reference_after = reference_loop_ms()  # once the server has closed every connection
    frames = [f for o in outputs for f in o["frames"]]
    latencies = [x * 1e3 for o in outputs for x in o["latencies"]]
    transit = [x * 1e3 for o in outputs for x in o["transit"]]
    window = min(o["window"] for o in outputs)
    expected = args.fps * window
    delivered = [f / expected for f in frames]
    result = {
        "failures": [f for o in outputs for f in o["failures"]][:10],
        "connected": len(frames),
        "delivered_mean": statistics.mean(delivered) if delivered else 0.0,
        "delivered_min": min(delivered) if delivered else 0.0,
        "delivered_p5": percentile(delivered, 5),
        "frames_per_second_total": sum(frames) / window,
        "latency_ms": {"count": len(latencies), "median": percentile(latencies, 50),
                       "p95": percentile(latencies, 95), "p99": percentile(latencies, 99),
                       "max": max(latencies) if latencies else float("nan")},
        # of which: from the server encoding the frame to the client reading it (socket
        # buffers and the load generator's own lag)
        "transit_ms": {"median": percentile(transit, 50), "p95": percentile(transit, 95),
                       "p99": percentile(transit, 99)},
        "server_cpu_cores": cpu,
        "server_rss_mb": {"start": rss_start, "after_load": rss_mb(server_pid)},
        "server_counters": dict({k: v - before["scheduler"].get(k, 0) for k, v in health["scheduler"].items()},
                                frames_dropped=health["frames_dropped"] - before["frames_dropped"]),
        # the whole machine over the run: cores busy (server, clients, kernel), idle, stolen by the host
        "machine_cores": {"busy": busy / elapsed, "idle": idle / elapsed, "steal": steal / elapsed},
        "load_average": os.getloadavg(),
        "reference_loop_ms": [reference_before, reference_after],
    }
    print(f"{args.clients} clients x {args.fps:g} fps, {name} ({n_vertices} vertices, q16), "
          f"{window:.1f} s measured:")
    print(f"  frames delivered: mean {100 * result['delivered_mean']:.1f}%, 5th percentile "
          f"{100 * result['delivered_p5']:.1f}%, min {100 * result['delivered_min']:.1f}% "
          f"({result['frames_per_second_total']:.0f} frames/s in total)")
    lat = result["latency_ms"]
    print(f"  params -> first frame reflecting them: median {lat['median']:.1f} ms, p95 {lat['p95']:.1f} ms, "
          f"p99 {lat['p99']:.1f} ms, max {lat['max']:.1f} ms ({lat['count']} updates)")
    tr = result["transit_ms"]
    print(f"    of which frame encoded -> read by the client: median {tr['median']:.1f} ms, p95 {tr['p95']:.1f} ms, "
          f"p99 {tr['p99']:.1f} ms")
    counters = result["server_counters"]
    print(f"  server: {cpu:.2f} cores, RSS {rss_start:.0f} -> {result['server_rss_mb']['after_load']:.0f} MB; "
          f"{counters.get('table_frames', 0)} of {counters.get('frames', 0)} frames from phase tables, "
          f"{counters.get('busy_sends', 0)} sends found a full transport, {counters['frames_dropped']} ticks "
          f"dropped (a frame more than a period late)")
    print(f"  machine: {busy / elapsed:.2f} cores busy, {idle / elapsed:.2f} idle, {steal / elapsed:.2f} stolen "
          f"by the host (of {os.cpu_count()}); reference Python loop {reference_before:.0f} ms before, "
          f"{reference_after:.0f} ms after (lower is a faster host)")
    if result["failures"]:
        print(f"  client failures: {result['failures']}")
    return result


def percentile(values, q):
    values = sorted(values)
    if not values:
        return float("nan")
    k = min(len(values) - 1, max(0, int(round(q / 100 * (len(values) - 1)))))
    return values[k]


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
    parser.add_argument("--update-every", type=float, default=0.5, help="seconds between their updates")
    parser.add_argument("--repeat", type=int, default=1, help="measuring rounds against the same server "
                                                               "(each reported; the median of their means)")
    parser.add_argument("--soak", type=float, default=0.0, help="seconds of connect/leave soak (0: none)")
    parser.add_argument("--soak-clients", type=int, default=50)
    parser.add_argument("--tiny", action="store_true",
                        help="smoke run: 4 clients x 30 fps for 4 s in one process, on a 1,000-vertex space "
                             "built for the run unless --space is given; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/stream_load.json)")
    args = parser.parse_args(argv)
    if args.tiny:
        if args.out is None:
            parser.error("--tiny needs --out (a tiny run never replaces the recorded results)")
        parser.set_defaults(**TINY)
        args = parser.parse_args(argv)  # options given on the command line still win
    out = args.out or ROOT / "benchmarks" / "results" / "stream_load.json"

    data = Path(tempfile.mkdtemp(prefix="morphspace-bench-"))
    try:
        (data / "spaces").mkdir()
        if args.space is None and args.tiny:
            from _tiny import build_tiny_speed_space

            space_path = data / "spaces" / "speed.mspace"
            build_tiny_speed_space(space_path)
        else:
            space_path = data / "spaces" / (args.space or ROOT / "data" / "spaces" / "locomotion.mspace").name
            space_path.symlink_to((args.space or ROOT / "data" / "spaces" / "locomotion.mspace").resolve())
        result = serve_and_measure(args, data, space_path)
    finally:
        shutil.rmtree(data, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return 0


def serve_and_measure(args, data, space_path):
    """Start ``morphspace serve`` on 127.0.0.1 over ``data``, run the rounds (and the soak), stop
    the server; returns the result record."""
    from engine.motion_space import MotionSpace  # here, not at the top: the client processes never need it

    with MotionSpace.open(space_path, verify=False) as space:
        name, n_vertices = space_path.stem, space.n_vertices
        pmap = space.parameter_map
        params = list(zip(pmap.names, pmap.domain()))
    port = free_port()
    url = f"ws://127.0.0.1:{port}/v1/stream"
    env = dict(os.environ, MORPHSPACE_STREAM_MAX_CLIENTS=str(max(1000, args.clients * 2)))
    server = subprocess.Popen([sys.executable, "-m", "server.cli", "serve", "--data-dir", str(data), "--host",
                               "127.0.0.1", "--port", str(port), "--log-level", "warning"], cwd=ROOT, env=env,
                              start_new_session=True)
    result = {"space": name, "n_vertices": n_vertices, "clients": args.clients, "fps": args.fps,
              "codec": "q16", "seconds": args.seconds, "cpus": os.cpu_count()}
    try:
        import httpx
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if server.poll() is not None:
                raise RuntimeError(f"morphspace serve exited with status {server.returncode} before it answered")
            try:
                if httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        httpx.get(f"http://127.0.0.1:{port}/v1/spaces/{name}", timeout=30)  # open (and verify) it once
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
            print(f"{args.repeat} rounds: frames delivered (mean per round) "
                  f"{', '.join(f'{100 * v:.1f}%' for v in values)}: median {100 * statistics.median(values):.1f}%; "
                  f"update -> frame p99 median {statistics.median(p99s):.1f} ms")
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
