"""``stream_load.py --baseline DIR``: this tree's server against another checkout's, side by side.

Both servers (the same space, the same data directory, one worker each) are started before the
first round and stay up, so they meet the same host; then ``--repeat`` times each server takes a
round under the same load, the order alternating from round to round. The record gives every
round and, per server, the median of its rounds' server CPU per delivered frame and frames
delivered, and their ratio. ``DIR`` is a source tree (e.g. ``git worktree add /tmp/before main``
or ``git archive main | tar -x -C /tmp/before``); its server runs with this interpreter, so its
dependencies must match this environment's.
"""

from __future__ import annotations

import multiprocessing as mp
import statistics
from pathlib import Path

from _workers import ROOT, start_server, tree_memory_mb, warm_up


def compare_code(args, data, name, n_vertices, params, load_round, stop):
    """Rounds alternating between the baseline tree's server and this one's; returns the record."""
    trees = {"baseline": Path(args.baseline).resolve(), "this tree": ROOT}
    servers = {}
    rounds = {label: [] for label in trees}
    ctx = mp.get_context("spawn")
    try:
        for label, root in trees.items():
            servers[label] = start_server(data, 1, max(1000, 2 * args.clients), root=root)
            warm_up(servers[label][1], name)
        for k in range(args.repeat):
            order = list(trees) if k % 2 == 0 else list(trees)[::-1]
            for label in order:
                print(f"{label} ({trees[label]}), round {k + 1} of {args.repeat}:")
                process, port = servers[label]
                record = load_round(args, port, name, n_vertices, params, process.pid, ctx,
                                    tree_memory_mb(process.pid)[0], 17 + 10 * k)
                rounds[label].append(record)
    finally:
        for process, _ in servers.values():
            stop(process)
    summary = {}
    for label in trees:
        per_frame = [r["server_cpu_us_per_frame"] for r in rounds[label]]
        delivered = [r["delivered_mean"] for r in rounds[label]]
        system = [r["server_system_us_per_frame"] for r in rounds[label]]
        summary[label] = {"tree": str(trees[label]), "server_cpu_us_per_frame": per_frame,
                          "server_cpu_us_per_frame_median": statistics.median(per_frame),
                          "server_system_us_per_frame_median": statistics.median(system),
                          "delivered_mean": delivered, "delivered_mean_median": statistics.median(delivered)}
    before, after = (summary[label]["server_cpu_us_per_frame_median"] for label in trees)
    print(f"\n{args.clients} clients, {args.repeat} rounds each, alternating:")
    for label in trees:
        s = summary[label]
        print(f"  {label}: server CPU per delivered frame {', '.join(f'{x:.1f}' for x in s['server_cpu_us_per_frame'])} us "
              f"(median {s['server_cpu_us_per_frame_median']:.1f}, of which kernel "
              f"{s['server_system_us_per_frame_median']:.1f}); delivered "
              f"{', '.join(f'{100 * x:.1f}%' for x in s['delivered_mean'])} (median {100 * s['delivered_mean_median']:.1f}%)")
    print(f"  this tree / baseline: {after / before:.2f}x the CPU per delivered frame")
    return {"clients": args.clients, "fps": args.fps, "space": name, "n_vertices": n_vertices,
            "repeat": args.repeat, "summary": summary, "ratio_cpu_per_frame": after / before,
            "rounds": rounds}
