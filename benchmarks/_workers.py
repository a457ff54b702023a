"""Servers of one or several worker processes for the stream benchmark (benchmarks/stream_load.py):
start one, measure its process tree (CPU, memory), and the side-by-side capacity comparison of
``--compare-workers`` (a module, not a benchmark)."""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DELIVERED = 0.95  # a client count is held when the clients get this share of their frames on average


def json_in_tree(tree, script, arguments, what, timeout=1800):
    """Run ``benchmarks/<script> arguments`` (of this checkout) in a fresh interpreter with source
    tree ``tree``'s code first on the path and in ``tree`` as its working directory; returns the
    JSON object its last line prints. ``what`` names the run in the error when it fails."""
    import json

    env = dict(os.environ, PYTHONPATH=str(tree))
    command = [sys.executable, str(Path(__file__).resolve().parent / script)] + [str(a) for a in arguments]
    done = subprocess.run(command, env=env, cwd=str(tree), capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"{what} in {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def process_tree(pid):
    """``pid`` and every process descending from it (/proc/<pid>/task/*/children)."""
    out, todo = [], [pid]
    while todo:
        current = todo.pop()
        out.append(current)
        try:
            for task in os.listdir(f"/proc/{current}/task"):
                with open(f"/proc/{current}/task/{task}/children") as f:
                    todo.extend(int(child) for child in f.read().split())
        except OSError:
            continue
    return out


def tree_cpu_seconds(pid):
    """User + system CPU seconds of ``pid`` and its descendants now alive (a server's workers)."""
    return sum(tree_cpu_times(pid))


def tree_cpu_times(pid):
    """(user, system) CPU seconds of ``pid`` and its descendants now alive. System time is the
    kernel's work in the processes' own calls: on loopback it includes the receiving side of
    every TCP segment they send (the softirq runs in the sender's call), which a real network
    would do on the client's machine."""
    user = system = 0.0
    for each in process_tree(pid):
        try:
            with open(f"/proc/{each}/stat") as f:
                parts = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        user += int(parts[11]) / os.sysconf("SC_CLK_TCK")
        system += int(parts[12]) / os.sysconf("SC_CLK_TCK")
    return user, system


def run_and_wait_seconds(pids):
    """(seconds on a CPU, seconds runnable but waiting for one) summed over ``pids``
    (/proc/<pid>/schedstat). Waiting time is what a saturated host takes from a process."""
    run = wait = 0.0
    for each in pids:
        try:
            with open(f"/proc/{each}/schedstat") as f:
                fields = f.read().split()
        except OSError:
            continue
        run, wait = run + int(fields[0]) / 1e9, wait + int(fields[1]) / 1e9
    return run, wait


def tree_memory_mb(pid):
    """(RSS, PSS) MB summed over ``pid`` and its descendants. PSS splits each shared page between
    the processes mapping it, so it does not count a mapped space once per worker, RSS does."""
    rss = pss = 0.0
    for each in process_tree(pid):
        try:
            with open(f"/proc/{each}/smaps_rollup") as f:
                for line in f:
                    if line.startswith("Rss:"):
                        rss += int(line.split()[1]) / 1024.0
                    elif line.startswith("Pss:"):
                        pss += int(line.split()[1]) / 1024.0
        except OSError:
            continue
    return rss, pss


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(data, workers, max_clients, timeout=90.0, root=ROOT):
    """``morphspace serve --workers N`` on 127.0.0.1 over ``data`` (its own process group), once
    every worker answers; returns (process, port). ``root``: the source tree whose server runs
    (default this one; ``--baseline`` passes another checkout)."""
    import httpx

    port = free_port()
    env = dict(os.environ, MORPHSPACE_STREAM_MAX_CLIENTS=str(max_clients))
    server = subprocess.Popen([sys.executable, "-m", "server.cli", "serve", "--data-dir", str(data), "--host",
                               "127.0.0.1", "--port", str(port), "--workers", str(workers), "--log-level",
                               "warning"], cwd=root, env=env, start_new_session=True)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise RuntimeError(f"morphspace serve exited with status {server.returncode} before it answered")
        try:
            health = httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=1).json()
            if len(health["workers"]) == workers and all(w["alive"] for w in health["workers"]):
                return server, port
        except (httpx.HTTPError, ValueError, KeyError):
            pass
        time.sleep(0.2)
    raise RuntimeError(f"morphspace serve --workers {workers} did not come up in {timeout:.0f} s")


def warm_up(port, name):
    """Open (and verify) the space in every worker: new connections until each has answered."""
    import httpx

    answered = set()
    for _ in range(200):
        r = httpx.get(f"http://127.0.0.1:{port}/v1/spaces/{name}", timeout=30)
        answered.add(r.headers.get("x-morphspace-worker", "0"))
        workers = httpx.get(f"http://127.0.0.1:{port}/v1/health", timeout=30).json()["workers"]
        if len(answered) >= len(workers):
            return


def compare_workers(args, data, name, n_vertices, params, load_round, stop):
    """Each worker count of ``args.compare_workers`` gets its own server (all started first, so
    they share the host's conditions); at each client count of ``args.levels`` the servers take
    turns (the order alternating from level to level) with the same load. A server holds a level
    when its clients get >= 95% of their frames on average with no client failing; one that
    misses a level gets one more try there, then is done. Returns the record; prints a table."""
    import multiprocessing as mp

    counts, levels = args.compare_workers, args.levels
    servers = {}
    ctx = mp.get_context("spawn")
    rounds = {w: [] for w in counts}
    capacity = {w: 0 for w in counts}
    done = set()
    try:
        for w in counts:
            servers[w] = start_server(data, w, max(1000, 2 * max(levels)))
            warm_up(servers[w][1], name)
        for i, level in enumerate(levels):
            for w in (counts if i % 2 == 0 else counts[::-1]):
                if w in done:
                    continue
                for attempt in range(2):
                    print(f"{w} worker{'s' if w > 1 else ''}, {level} clients{' (again)' if attempt else ''}:")
                    process, port = servers[w]
                    memory_before = tree_memory_mb(process.pid)
                    record = load_round(argparse.Namespace(**{**vars(args), "clients": level}), port, name,
                                        n_vertices, params, process.pid, ctx, memory_before[0], 1000 * i + 17)
                    rss, pss = tree_memory_mb(process.pid)
                    record.update(workers=w, level=level, attempt=attempt + 1,
                                  server_memory_mb={"rss_sum": rss, "pss_sum": pss})
                    rounds[w].append(record)
                    held = record["delivered_mean"] >= DELIVERED and not record["failures"]
                    if held:
                        capacity[w] = level
                        break
                else:
                    done.add(w)
            if len(done) == len(counts):
                break
    finally:
        for process, _ in servers.values():
            stop(process)
    return summarise(counts, levels, rounds, capacity)


def summarise(counts, levels, rounds, capacity):
    """The comparison's record and its table on stdout."""
    base, other = counts[0], counts[-1]
    ratio = capacity[other] / capacity[base] if capacity[base] else float("nan")
    table = []
    print(f"\nworkers side by side ({', '.join(map(str, counts))}), {DELIVERED:.0%} of frames delivered to hold:")
    print("  workers  clients  delivered  server cores  clients' cores  server us/frame  client us/frame  "
          "machine busy  server waited")
    for w in counts:
        for r in rounds[w]:
            frames = r["frames_per_second_total"]
            row = {"workers": w, "clients": r["level"], "attempt": r["attempt"], "delivered_mean": r["delivered_mean"],
                   "server_cpu_cores": r["server_cpu_cores"], "clients_cpu_cores": r["clients_cpu_cores"],
                   "server_cpu_us_per_frame": 1e6 * r["server_cpu_cores"] / frames if frames else float("nan"),
                   "clients_cpu_us_per_frame": 1e6 * r["clients_cpu_cores"] / frames if frames else float("nan"),
                   "machine_busy_cores": r["machine_cores"]["busy"],
                   "server_runqueue_wait": r["server_runqueue_wait"]}
            table.append(row)
            print(f"  {w:7d}  {row['clients']:7d}  {100 * row['delivered_mean']:8.1f}%  {row['server_cpu_cores']:12.2f}  "
                  f"{row['clients_cpu_cores']:14.2f}  {row['server_cpu_us_per_frame']:15.0f}  "
                  f"{row['clients_cpu_us_per_frame']:15.0f}  {row['machine_busy_cores']:12.2f}  "
                  f"{row['server_runqueue_wait']:13.2f}")
    print(f"  held: {', '.join(f'{w} worker(s) {capacity[w]} clients' for w in counts)}; "
          f"{other} / {base} = {ratio:.2f}x (target >= 1.5x)")
    return {"workers": counts, "levels": levels, "delivered_to_hold": DELIVERED,
            "capacity": {str(w): capacity[w] for w in counts}, "ratio": ratio, "table": table,
            "rounds": {str(w): rounds[w] for w in counts}, "cpus": os.cpu_count(), "load_average": os.getloadavg()}
