"""``stream_load.py --offline``: the scheduler's work for N sessions, the sockets replaced by a counter.

A loaded host makes the server's CPU per delivered frame swing by tens of percent from round to
round (docs/evaluation.md). This measures the part the server's code decides, without sockets,
an event loop's waiting or a load generator: N real StreamSessions on the space (q16, 60 frames/s,
``--update-share`` of them steering: new random parameters every 0.5 s of simulated time, moved
there by the player's spring), each simulated frame period every session due once, taken in
ticks of the scheduler's batch size and produced by ``FrameScheduler._produce``; a counter takes
each frame's message. It reports the process CPU (``time.process_time``) of the ticks per frame.
The parameter requests themselves (a cold solve each) are not timed.

With ``--offline-grid`` the ticks are the online scheduler's instead: the sessions say hello at
points spread evenly over the first period (as connections arriving at random times do), so
their first frames are urgent; after that each session's next frame falls due where the tree's
own rule puts it (``FrameOutput.due_step``: a grid per connection in trees before session 33,
one grid shared by every connection at a rate since), and the simulated ticks follow the tree's
``server.scheduler`` rule (a tick half a tick (``TICK``) before the next frame falls due, at
least a tick after the last; every frame due within half a tick of it, in batches of
``MAX_BATCH``). The frames per tick are then what the tree gives 200 clients online, and their
per-tick cost counts as it does there; the loop's sleeps and wake-ups between ticks are still
not in the figure.

Run as a script in a tree (``python _offline.py --json ...`` with that tree first on the path),
so ``--baseline DIR`` measures DIR's scheduler the same way, in alternating rounds.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import os
import random
import statistics
import time
from pathlib import Path

from _workers import json_in_tree



class _Counter:
    """Takes every frame at once (a transport that never fills), counting frames and bytes."""

    def __init__(self):
        self.frames = self.bytes = 0

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
        return True

    def write_frame(self, head, vertices, floor):  # (TransportGauge.write_frame, where a tree has it)
        self.frames += 1
        self.bytes += head.nbytes + vertices.nbytes
        return 0


class _Socket:
    def __init__(self, counter):
        self.scope = {"extensions": {"morphspace.transport": counter}}


async def _measure(space_path, clients, seconds, share, seed, grid=False):
    import numpy as np

    from engine.player import Player
    from server import protocol as P
    from server.registry import SpaceRegistry
    from server.scheduler import MAX_BATCH, TICK, FrameScheduler
    from server.settings import Settings
    from server.stream.session import StreamSession, StreamStats

    registry = SpaceRegistry(space_path.parent)
    name = space_path.stem
    space = registry.get(name)
    bounds = np.asarray(registry.describe(name)["bounds"], dtype=np.float32)
    scheduler, stats, settings = FrameScheduler(), StreamStats(), Settings()
    rng = random.Random(seed)
    domain = space.parameter_map.domain()
    sessions, steering = [], []
    for _ in range(clients):
        session = StreamSession(_Socket(_Counter()), registry, settings, stats, scheduler)
        session.player = Player(space, mode="hybrid")
        session.player.seek(rng.random())
        session.space_name, session.rate, session.codec, session.bounds = name, 60.0, "q16", bounds
        session.quantiser = P.Quantiser(bounds, space.n_vertices)
        session.ready = True
        sessions.append(session)
        steering.append(rng.random() < share)
    for module in ("engine.blend.compiled", "engine.player_steps", "server.frames"):  # as the server before it serves
        try:  # (trees before it had no compiled loops)
            warm_up = __import__(module, fromlist=["warm_up"]).warm_up
        except (ImportError, AttributeError):
            continue
        warm_up()
    gc.freeze()
    period = 1.0 / 60.0
    next_request = [rng.uniform(0.0, 0.5) if s else float("inf") for s in steering]
    if grid:
        cpu, ticks = _grid_ticks(scheduler, sessions, seconds, period, next_request, rng, domain, TICK, MAX_BATCH)
        frames = sum(s.gauge.frames for s in sessions)
        return {"clients": clients, "steering": sum(steering), "simulated_seconds": seconds, "frames": frames,
                "cpu_s": cpu, "us_per_frame": 1e6 * cpu / max(frames, 1), "table_frames": scheduler.table_frames,
                "batched_frames": getattr(scheduler, "batched_frames", 0), "ticks": ticks,
                "tick_seconds": TICK, "max_batch": MAX_BATCH}
    cpu = 0.0
    for step in range(1, int(round(seconds * 60)) + 1):
        now = 1000.0 + step * period
        for k, session in enumerate(sessions):
            if now - 1000.0 >= next_request[k]:
                name_k = rng.randrange(len(domain))
                session.player.set_params({session.player.names[name_k]: rng.uniform(*domain[name_k])})
                next_request[k] += 0.5
        start = time.process_time()
        for first in range(0, clients, MAX_BATCH):
            batch = sessions[first:first + MAX_BATCH]
            for session in batch:
                session.next_due = now
            scheduler._produce(batch, now)
        cpu += time.process_time() - start
        scheduler._heap.clear()  # the next frames the sessions asked for: every one is due next period anyway
    frames = sum(s.gauge.frames for s in sessions)
    return {"clients": clients, "steering": sum(steering), "simulated_seconds": seconds, "frames": frames,
            "cpu_s": cpu, "us_per_frame": 1e6 * cpu / max(frames, 1), "table_frames": scheduler.table_frames,
            "batched_frames": getattr(scheduler, "batched_frames", 0)}


def _grid_ticks(scheduler, sessions, seconds, period, next_request, rng, domain, tick, max_batch):
    """``--offline-grid``'s ticks (see the module docstring): returns (process CPU, ticks)."""
    start_at = 1000.0 + period
    due = [start_at + k * period / len(sessions) for k in range(len(sessions))]  # each one's hello
    for session in sessions:
        session.urgent = True  # a hello's frame: urgent (FrameOutput.due_step sets the grid from it)
    end, now, cpu, ticks = start_at + seconds, start_at - 0.5 * tick, 0.0, 0
    while now < end:
        taken = sorted((d, k) for k, d in enumerate(due) if d <= now + 0.5 * tick)
        for _, k in taken:  # requests that fell due by this frame (not timed, as above)
            if now - 1000.0 >= next_request[k]:
                name_k = rng.randrange(len(domain))
                sessions[k].player.set_params({sessions[k].player.names[name_k]: rng.uniform(*domain[name_k])})
                next_request[k] += 0.5
        start = time.process_time()
        for first in range(0, len(taken), max_batch):
            scheduler._produce([sessions[k] for _, k in taken[first:first + max_batch]], now)
        cpu += time.process_time() - start
        scheduler._heap.clear()  # (the frames the sessions asked for next: their next_due, read below)
        ticks += 1 if taken else 0
        for _, k in taken:
            due[k] = sessions[k].next_due
        now = max(min(due) - 0.5 * tick, now + tick)
    return cpu, ticks


def measure(space_path, clients, seconds, share, seed=1, grid=False):
    """One offline round in this process (this tree's server code); returns its record."""
    return asyncio.run(_measure(Path(space_path), clients, seconds, share, seed, grid))


def measure_in(tree, space_path, clients, seconds, share, seed=1, grid=False):
    """One offline round in a fresh interpreter running ``tree``'s server code."""
    return json_in_tree(tree, "_offline.py", ["--json", space_path, clients, seconds, share, seed]
                        + (["--grid"] if grid else []), "offline round")


def offline_rounds(args, space_path, root):
    """``--offline``: ``--repeat`` rounds of this tree (and of ``--baseline``'s, alternating)."""
    trees = {"this tree": root} if args.baseline is None else {"baseline": Path(args.baseline).resolve(),
                                                                "this tree": root}
    rounds = {label: [] for label in trees}
    print(f"offline: {args.clients} sessions, {100 * args.update_share:.0f}% steering, {args.seconds:g} s of "
          f"frames at 60 fps per round, sockets replaced by a counter (process CPU of the scheduler's ticks"
          f"{': the online ticks of each tree' if args.offline_grid else ''})")
    for k in range(args.repeat):
        for label in (list(trees) if k % 2 == 0 else list(trees)[::-1]):
            record = measure_in(trees[label], space_path, args.clients, args.seconds, args.update_share,
                                grid=args.offline_grid)
            rounds[label].append(record)
            ticks = f", {record['frames'] / record['ticks']:.1f} a tick" if record.get("ticks") else ""
            print(f"  {label}, round {k + 1}: {record['us_per_frame']:.1f} us per frame ({record['frames']} frames{ticks}, "
                  f"{record['steering']} steering, {record['table_frames']} from phase tables, "
                  f"{record['batched_frames']} blended together)")
    summary = {label: statistics.median(r["us_per_frame"] for r in rounds[label]) for label in trees}
    result = {"clients": args.clients, "update_share": args.update_share, "seconds": args.seconds,
              "grid": args.offline_grid, "rounds": rounds, "us_per_frame_median": summary,
              "load_average": os.getloadavg()}
    line = ", ".join(f"{label} median {value:.1f} us" for label, value in summary.items())
    if args.baseline is not None:
        result["ratio"] = summary["this tree"] / summary["baseline"]
        line += f": {result['ratio']:.2f}x"
    print(f"  offline CPU per frame: {line} (load average {os.getloadavg()[0]:.1f})")
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="one offline round, printed as JSON (see the module docstring)")
    parser.add_argument("--json", action="store_true", required=True)
    parser.add_argument("space", type=Path)
    parser.add_argument("clients", type=int)
    parser.add_argument("seconds", type=float)
    parser.add_argument("share", type=float)
    parser.add_argument("seed", type=int)
    parser.add_argument("--grid", action="store_true", help="the online scheduler's ticks (--offline-grid)")
    a = parser.parse_args()
    print(json.dumps(measure(a.space, a.clients, a.seconds, a.share, a.seed, a.grid)))
