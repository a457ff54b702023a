"""The Godot 3 add-on (engine_clients/godot/) at 60 frames/s: decode and mesh update time per frame,
and whether it holds the rate (issue 16).

    .venv/bin/python benchmarks/godot_client.py                      # 3,000 vertices, 10 s per codec, ~2 min
    .venv/bin/python benchmarks/godot_client.py --tiny --out /tmp/godot_client.json   # smoke run, ~20 s

Builds a two-gait speed space of ``--vertices`` (default 3,000, the demo body's size) in a
temporary directory (or serves ``--space``), starts ``morphspace serve`` on 127.0.0.1 and runs
the headless Godot project of tests/engine_clients/ (copied with the add-on into the temporary
directory; HOME and the XDG directories point there) with Godot's target frame rate at
``--engine-fps``: a MorphspaceMesh streams ``--seconds`` at 60 frames/s in f32, then in q16,
then takes as many frames pulled on the engine's clock. Vertices are not recorded here (the
test checks them), only the add-on's own timings. Per run it reports

- decode (msgpack + vertex codec) and mesh update (ArrayMesh surface replaced, node placed)
  microseconds per frame: median, p95, max,
- frames applied per second, frames received per second, frames superseded by a newer one
  before the engine's next frame, frames the server dropped for this client, and Godot's own
  frames per second.

Godot's headless build renders with a dummy renderer: the mesh update is the CPU side
(Godot's surface packing) without a GPU upload. Results go to benchmarks/results/godot_client.json;
``--tiny`` uses 1,000 vertices and 2 s per run and needs ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import msgpack

from _tiny import TINY_VERTICES, build_tiny_speed_space, parse_arguments
from stream_load import free_port, stop_process_group

ROOT = Path(__file__).resolve().parents[1]
PROJECT = ROOT / "tests" / "engine_clients" / "godot_project"
ADDON = ROOT / "engine_clients" / "godot" / "addons"
GODOT = Path(os.environ.get("MORPHSPACE_TEST_GODOT", "/usr/bin/godot3-server"))
TINY = {"vertices": TINY_VERTICES, "seconds": 2.0}


def percentiles(values):
    ordered = sorted(values)
    return {"median": statistics.median(ordered), "p95": ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))],
            "max": ordered[-1]}


def start_server(data):
    import httpx

    port = free_port()
    server = subprocess.Popen([sys.executable, "-m", "server.cli", "serve", "--data-dir", str(data), "--host",
                               "127.0.0.1", "--port", str(port), "--log-level", "warning"], cwd=ROOT,
                              start_new_session=True)
    deadline = time.monotonic() + 60
    while True:
        if server.poll() is not None or time.monotonic() > deadline:
            stop_process_group(server)
            raise RuntimeError("morphspace serve did not come up")
        try:
            if httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=1).status_code == 200:
                return server, port
        except httpx.HTTPError:
            pass
        time.sleep(0.1)


def run_godot(work, port, space, args):
    project = work / "project"
    shutil.copytree(PROJECT, project)
    shutil.copytree(ADDON, project / "addons")
    out, home = work / "out", work / "home"
    out.mkdir()
    home.mkdir()
    env = dict(os.environ, HOME=str(home), XDG_DATA_HOME=str(home / "data"), XDG_CONFIG_HOME=str(home / "config"),
               XDG_CACHE_HOME=str(home / "cache"), LC_ALL="C.UTF-8")
    frames = max(4, round(args.seconds * 60))
    run = subprocess.run([str(GODOT), "--path", str(project), "--", f"--out={out}",
                          f"--url=ws://127.0.0.1:{port}/v1/stream", f"--space={space}", "--param=speed",
                          "--values=1.2,2.0", f"--frames={frames}", "--pulls=0.5", "--pull-value=1.5",
                          f"--engine-frames={frames}", f"--engine-fps={args.engine_fps}",
                          f"--timeout={30 + 6 * args.seconds}", "--record-vertices=0"],
                         cwd=work, env=env, capture_output=True, text=True, timeout=60 + 8 * args.seconds)
    error = out / "error.txt"
    if run.returncode != 0 or error.exists():
        raise RuntimeError(f"godot failed ({run.returncode}): {error.read_text() if error.exists() else ''}\n"
                           f"{run.stdout[-2000:]}\n{run.stderr[-2000:]}")
    with open(out / "records.msgpack", "rb") as f:
        records = list(msgpack.Unpacker(f, raw=False))
    return records, msgpack.unpackb((out / "summary.msgpack").read_bytes(), raw=False)


def figures(records, summary):
    rows = {}
    for key, run in sorted(summary["codecs"].items()):
        kind, codec = key.split("-")
        applied = [r for r in records if r["kind"] == kind and r["codec"] == codec][:run["frames"]]
        decode = [r["decode_usec"] for r in applied]
        update = [r["update_usec"] for r in applied]
        rows[key] = {
            "frames": run["frames"], "seconds": run["seconds"], "frames_per_second": run["frames_per_second"],
            "received_per_second": run["received_in_window"] / run["seconds"] if run["seconds"] > 0 else 0.0,
            "superseded": run["superseded"], "server_dropped": run["server_dropped"], "engine_fps": run["engine_fps"],
            "decode_us": percentiles(decode), "update_us": percentiles(update),
            "decode_update_us": percentiles([d + u for d, u in zip(decode, update)])}
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--space", type=Path, help="motion space with a 'speed' parameter to serve (default: a "
                                                   "two-gait speed space of --vertices built for the run)")
    parser.add_argument("--vertices", type=int, default=3000)
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds per run (f32, q16, pulled)")
    parser.add_argument("--engine-fps", type=int, default=60, help="Godot's target frames per second")
    parser.add_argument("--tiny", action="store_true", help="smoke run: 1,000 vertices, 2 s per run; needs --out")
    parser.add_argument("--out", type=Path, help="JSON results (default benchmarks/results/godot_client.json)")
    args = parse_arguments(parser, argv, TINY)
    if not GODOT.exists():
        parser.error(f"needs Debian's godot3-server at {GODOT} (apt-get install -y godot3-server; scripts/test installs it)")
    out = args.out or ROOT / "benchmarks" / "results" / "godot_client.json"
    work = Path(tempfile.mkdtemp(prefix="morphspace-godot-"))
    server = None
    try:
        spaces = work / "data" / "spaces"
        spaces.mkdir(parents=True)
        if args.space is None:
            started = time.monotonic()
            build_tiny_speed_space(spaces / "speed.mspace", args.vertices)
            print(f"built a {args.vertices}-vertex speed space in {time.monotonic() - started:.0f} s", flush=True)
            name = "speed"
        else:
            (spaces / args.space.name).symlink_to(args.space.resolve())
            name = args.space.stem
        from engine.motion_space import MotionSpace

        with MotionSpace.open(spaces / f"{name}.mspace", verify=False) as space:
            n_vertices = int(space.n_vertices)
        server, port = start_server(work / "data")
        load_before = os.getloadavg()[0]
        records, summary = run_godot(work, port, name, args)
        result = {"vertices": n_vertices, "seconds": args.seconds, "engine_fps_target": args.engine_fps,
                  "stream_rate": 60.0, "load_average": load_before, "load_average_after": os.getloadavg()[0],
                  "cpus": os.cpu_count(), "runs": figures(records, summary)}
    finally:
        if server is not None:
            stop_process_group(server)
        shutil.rmtree(work, ignore_errors=True)
    for key, row in result["runs"].items():
        print(f"{key}: {n_vertices} vertices, decode median {row['decode_us']['median']:.0f} us, mesh update median "
              f"{row['update_us']['median']:.0f} us, decode + update median {row['decode_update_us']['median']:.0f} us "
              f"p95 {row['decode_update_us']['p95']:.0f} us max {row['decode_update_us']['max']:.0f} us; applied "
              f"{row['frames_per_second']:.1f} frames/s, received {row['received_per_second']:.1f}/s, "
              f"{row['superseded']} superseded, {row['server_dropped']} dropped by the server, engine "
              f"{row['engine_fps']} fps", flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
