"""Stalled clients: how soon a client that stopped reading gets a fresh frame, and what the server
holds for it meanwhile (issue 13).

    .venv/bin/python benchmarks/stream_stall.py                       # 5 s and 30 s stalls, ~40 s
    .venv/bin/python benchmarks/stream_stall.py --tiny --out /tmp/stream_stall.json   # smoke run, ~10 s

Starts ``morphspace serve`` on 127.0.0.1 over a data directory holding the space (default
data/spaces/locomotion.mspace, 3,000 vertices). Clients are raw sockets with a 4 KiB receive
buffer (``SO_RCVBUF``, as in the issue) asking for 60 frames/s in each codec (f32, q16), without
and with a window of 2 acks, ``--per-variant`` of each; they stream for ``--read-before``
seconds, read nothing for each ``--stalls`` length (all stall lengths side by side), then read
for a second. It reports

- first fresh frame: the time from resuming to reading the first frame the server encoded after
  the client resumed (median and max per stall length; target <= 100 ms), and the stale frames
  and bytes read before it,
- bytes the server held for one connection: the server's own figure (``transport_bytes_max`` in
  /v1/health: the asyncio buffer plus the kernel's send queue, after every frame written), and
  the kernel's send queue of the server's sockets sampled with ``ss`` every 50 ms (target:
  <= 256 KB at all times),
- the ``dropped`` count of the first fresh frame against the ticks the stall skipped.

Results go to benchmarks/results/stream_stall.json. ``--tiny`` builds a 1,000-vertex speed space
in a temporary directory (unless ``--space`` is given) and stalls for 0.5 and 1 s, one client per
variant; it needs ``--out``. The server binds 127.0.0.1 and is stopped at the end, whatever happens.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import msgpack

from _raw_websocket import RawWebSocket
from _tiny import parse_arguments
from stream_load import free_port, served_space, stop_process_group

ROOT = Path(__file__).resolve().parents[1]
TINY = {"stalls": [0.5, 1.0], "per_variant": 1}
VARIANTS = [("f32", 0), ("q16", 0), ("f32", 2), ("q16", 2)]  # codec, window
HELD_TARGET = 256 * 1024


def stall_once(port, space, codec, window, fps, stall, read_for, read_before):
    """Connect, read for ``read_before`` seconds, read nothing for ``stall`` seconds, then read
    for ``read_for`` seconds."""
    client = RawWebSocket(port, {"type": "hello", "space": space, "rate": fps, "codec": codec,
                                 "window": window})
    try:
        started = time.monotonic()
        while time.monotonic() - started < read_before:
            client.sock.settimeout(max(0.01, read_before - (time.monotonic() - started)))
            try:
                opcode, payload = client.receive_frame()
            except TimeoutError:
                break
            finally:
                client.sock.settimeout(10.0)
            if window and opcode == 0x2 and b"\xa5frame" in payload[:16]:
                client.send(msgpack.packb({"type": "ack", "frame": msgpack.unpackb(payload)["seq"]}))
        time.sleep(stall)
        resumed, resumed_wall = time.monotonic(), time.time()
        record = {"codec": codec, "window": window, "stall_s": stall, "stale_frames": 0, "stale_bytes": 0,
                  "first_fresh_ms": None, "frames_after": 0, "closed": None}
        while time.monotonic() - resumed < read_for:
            opcode, payload = client.receive_frame()
            if opcode == 0x8:
                record["closed"] = struct.unpack("!H", payload[:2])[0] if len(payload) >= 2 else None
                break
            message = msgpack.unpackb(payload)
            if message["type"] != "frame":
                continue
            if window:
                client.send(msgpack.packb({"type": "ack", "frame": message["seq"]}))
            if record["first_fresh_ms"] is None:
                if message["sent_at"] >= resumed_wall:  # encoded after the client resumed reading
                    record["first_fresh_ms"] = 1e3 * (time.monotonic() - resumed)
                    record["dropped"] = message["dropped"]
                else:
                    record["stale_frames"] += 1
                    record["stale_bytes"] += len(payload)
                    record["stale_age_max_s"] = max(record.get("stale_age_max_s", 0.0),
                                                    time.time() - message["sent_at"])
            else:
                record["frames_after"] += 1
        return record
    finally:
        client.sock.close()


def kernel_queue_sampler(port, stop, peaks):
    """Sample the Send-Q of the server's established sockets on ``port`` every 50 ms (``ss``)."""
    while not stop.is_set():
        try:
            out = subprocess.run(["ss", "-tnH", "state", "established", f"( sport = :{port} )"],
                                 capture_output=True, text=True, timeout=5).stdout
        except (OSError, subprocess.SubprocessError):
            return
        for line in out.splitlines():
            fields = line.split()
            if len(fields) >= 2 and fields[1].isdigit():
                peaks.append(int(fields[1]))
        stop.wait(0.05)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--space", type=Path, help="motion space to serve (default data/spaces/locomotion.mspace; "
                                                   "with --tiny a 1,000-vertex speed space built for the run)")
    parser.add_argument("--stalls", type=float, nargs="+", default=[5.0, 30.0], help="stall lengths (s)")
    parser.add_argument("--per-variant", type=int, default=2, help="clients per codec x window variant")
    parser.add_argument("--fps", type=float, default=60.0)
    parser.add_argument("--read-for", type=float, default=1.0, help="seconds each client reads after its stall")
    parser.add_argument("--read-before", type=float, default=0.5,
                        help="seconds each client streams normally before it stalls")
    parser.add_argument("--tiny", action="store_true", help="smoke run: 0.5 and 1 s stalls on a tiny space; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/stream_stall.json)")
    args = parse_arguments(parser, argv, TINY)
    out = args.out or ROOT / "benchmarks" / "results" / "stream_stall.json"
    data = Path(tempfile.mkdtemp(prefix="morphspace-stall-"))
    try:
        (data / "spaces").mkdir()
        result = serve_and_stall(args, data, served_space(data, args.space, args.tiny))
    finally:
        shutil.rmtree(data, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return 0


def serve_and_stall(args, data, space_path):
    import httpx

    from engine.motion_space import MotionSpace

    with MotionSpace.open(space_path, verify=False) as space:
        name, n_vertices = space_path.stem, space.n_vertices
    port = free_port()
    server = subprocess.Popen([sys.executable, "-m", "server.cli", "serve", "--data-dir", str(data), "--host",
                               "127.0.0.1", "--port", str(port), "--log-level", "warning"], cwd=ROOT,
                              start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while True:
            if server.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("morphspace serve did not come up")
            try:
                if httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        httpx.get(f"http://127.0.0.1:{port}/v1/spaces/{name}", timeout=60)  # open it once
        jobs = [(port, name, codec, window, args.fps, stall, args.read_for, args.read_before)
                for stall in args.stalls for codec, window in VARIANTS for _ in range(args.per_variant)]
        stop, kernel_peaks = threading.Event(), []
        sampler = threading.Thread(target=kernel_queue_sampler, args=(port, stop, kernel_peaks), daemon=True)
        sampler.start()
        with concurrent.futures.ThreadPoolExecutor(len(jobs)) as pool:
            records = list(pool.map(lambda job: stall_once(*job), jobs))
        stop.set()
        sampler.join()
        health = httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=30).json()
    finally:
        stop_process_group(server)
    result = {"space": name, "n_vertices": n_vertices, "fps": args.fps, "stalls": args.stalls,
              "per_variant": args.per_variant, "records": records,
              "transport_bytes_max": health["scheduler"]["transport_bytes_max"],
              "kernel_send_queue_max": max(kernel_peaks, default=0), "kernel_samples": len(kernel_peaks),
              "load_average": os.getloadavg(), "by_stall": {}}
    print(f"{len(records)} clients, {name} ({n_vertices} vertices), {args.fps:g} fps, SO_RCVBUF 4096, "
          f"f32/q16 x window 0/2; load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores:")
    for stall in args.stalls:
        mine = [r for r in records if r["stall_s"] == stall]
        fresh = [r["first_fresh_ms"] for r in mine if r["first_fresh_ms"] is not None]
        summary = {"clients": len(mine), "recovered": len(fresh), "closed": sum(r["closed"] is not None for r in mine),
                   "first_fresh_ms_median": statistics.median(fresh) if fresh else None,
                   "first_fresh_ms_max": max(fresh) if fresh else None,
                   "stale_frames_max": max(r["stale_frames"] for r in mine),
                   "stale_bytes_max": max(r["stale_bytes"] for r in mine),
                   "dropped_min_share": min((r.get("dropped", 0) / (stall * args.fps) for r in mine), default=0.0)}
        result["by_stall"][str(stall)] = summary
        print(f"  {stall:g} s stall: {summary['recovered']} of {summary['clients']} got a fresh frame; first fresh frame "
              f"after reading resumes: median {summary['first_fresh_ms_median'] or float('nan'):.1f} ms, max "
              f"{summary['first_fresh_ms_max'] or float('nan'):.1f} ms (target <= 100 ms); at most "
              f"{summary['stale_frames_max']} stale frames ({summary['stale_bytes_max'] / 1024:.0f} KB) before it; "
              f"'dropped' >= {100 * summary['dropped_min_share']:.0f}% of the skipped ticks")
    print(f"  bytes held for one connection: at most {result['transport_bytes_max'] / 1024:.0f} KB by the server's "
          f"count (asyncio buffer + kernel send queue), kernel send queue at most "
          f"{result['kernel_send_queue_max'] / 1024:.0f} KB in {len(kernel_peaks)} samples by ss (target <= 256 KB)")
    return result


if __name__ == "__main__":
    sys.exit(main())
