"""``stream_load.py --frames-hash``: the frames of a deterministic scheduler run, hashed.

A change to the streaming hot path must leave every frame byte for byte as it was (issue 13's
sessions 21-23 checked it by hand with a script kept outside the tree). This is that run: N real
StreamSessions on the space, every kind of frame the scheduler makes (hybrid and linear, q16 and
f32, smoothing 0 to 0.6; steering players, settled ones, many at the same parameters, requests
beyond what the space can do), ``seconds`` of frames at 60 fps in ticks of the tree's
``MAX_BATCH`` through ``FrameScheduler._produce``, the phase tables' clock simulated (their
builds and evictions land on the same frames in every run), random requests from ``seed``; each
connection's frames hashed in order with ``sent_at`` zeroed (the wall clock), the connections'
hashes hashed together. Two trees with the same hash for the same (N, seconds, seed) made the
same bytes.

Run as a script in a tree (``python _load_hash.py --json N seconds seed`` with that tree first on
the path), so ``--baseline DIR`` hashes DIR's frames the same way.
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import json
import random
from pathlib import Path

from _offline import _Socket
from _workers import json_in_tree

RUNS = ((60, 6.0, 1), (100, 8.0, 2))  # (sessions, seconds, seed): 21,600 and 48,000 frames
_SENT_AT = b"\xa7sent_at\xcb"  # the key and float64 marker before a frame's send time


class _Hasher:
    """A transport that takes every frame at once and hashes it, ``sent_at`` zeroed."""

    def __init__(self):
        self.hash = hashlib.sha256()
        self.frames = 0

    def ready(self):
        return True

    def held(self):
        return 0

    def held_above(self, floor):
        return None

    def write_message(self, parts):
        data = bytearray(b"".join(bytes(part) for part in parts))
        at = data.find(_SENT_AT) + len(_SENT_AT)
        if at < len(_SENT_AT):
            raise ValueError("a frame without sent_at")
        data[at:at + 8] = bytes(8)
        self.hash.update(data)
        self.frames += 1
        return True

    def write_frame(self, head, vertices, floor):  # (TransportGauge.write_frame, where a tree has it)
        self.write_message([head, vertices])
        return 0


async def _run(space_path, n, seconds, seed):
    import numpy as np

    from engine.player import Player
    from server import protocol as P
    from server.registry import SpaceRegistry
    from server.scheduler import MAX_BATCH, FrameScheduler
    from server.settings import Settings
    from server.stream.session import StreamSession, StreamStats

    registry = SpaceRegistry(space_path.parent)
    name = space_path.stem
    space = registry.get(name)
    bounds = np.asarray(registry.describe(name)["bounds"], dtype=np.float32)
    scheduler, stats, settings = FrameScheduler(), StreamStats(), Settings()
    rng = random.Random(seed)
    domain = space.parameter_map.domain()
    sessions, kinds = [], []
    for k in range(n):
        session = StreamSession(_Socket(_Hasher()), registry, settings, stats, scheduler)
        session.player = Player(space, mode=("hybrid", "linear")[k % 2], smoothing=(0.25, 0.1, 0.0, 0.6)[k % 4])
        session.player.seek(rng.random())
        session.space_name, session.rate, session.bounds = name, 60.0, bounds
        session.codec = "q16" if k % 3 else "f32"
        session.quantiser = P.Quantiser(bounds, space.n_vertices)
        session.ready = True
        kind = ("steer", "settled", "shared", "clamp", "steer")[k % 5]
        if kind == "shared":
            session.player.set_params([1.5, 10.0], immediate=True)
        sessions.append(session)
        kinds.append(kind)
    from engine.blend.compiled import warm_up
    warm_up()
    clock = [1000.0]  # the phase tables' clock: the simulated time
    for mode in ("hybrid", "linear"):
        space.frame_blender(mode).clock = lambda: clock[0]
    period = 1.0 / 60.0
    next_request = [rng.uniform(0.0, 0.5) if kind in ("steer", "clamp") else float("inf") for kind in kinds]
    for step in range(1, int(round(seconds * 60)) + 1):
        now = 1000.0 + step * period + rng.uniform(0.0, 0.004)
        for k, session in enumerate(sessions):
            if now - 1000.0 >= next_request[k]:
                if kinds[k] == "clamp":
                    session.player.set_params({"speed": rng.uniform(0, 5), "turn_rate": rng.uniform(-120, 120)})
                else:
                    i = rng.randrange(len(domain))
                    session.player.set_params({session.player.names[i]: rng.uniform(*domain[i])})
                next_request[k] += rng.uniform(0.3, 0.9)
        clock[0] = now
        order = sessions[:]
        rng.shuffle(order)
        for first in range(0, n, MAX_BATCH):
            batch = order[first:first + MAX_BATCH]
            for session in batch:
                session.next_due = now
            scheduler._produce(batch, now)
        scheduler._heap.clear()
    total = hashlib.sha256()
    for session in sessions:
        total.update(session.gauge.hash.digest())
    return {"sessions": n, "seconds": seconds, "seed": seed, "frames": sum(s.gauge.frames for s in sessions),
            "hash": total.hexdigest(), "table_frames": scheduler.table_frames,
            "batched_frames": getattr(scheduler, "batched_frames", 0)}


def hash_in(tree, space_path, n, seconds, seed):
    """One hashed run in a fresh interpreter running ``tree``'s server code; returns its record."""
    return json_in_tree(tree, "_load_hash.py", ["--json", space_path, n, seconds, seed], "hashed run")


def frames_hashes(args, space_path, root):
    """``--frames-hash``: the runs of ``RUNS`` in this tree (and in ``--baseline``'s); the record,
    with ``same`` when a baseline was hashed too."""
    trees = {"this tree": root} if args.baseline is None else {"baseline": Path(args.baseline).resolve(),
                                                                "this tree": root}
    runs = {label: [hash_in(tree, space_path, *run) for run in RUNS] for label, tree in trees.items()}
    for label, records in runs.items():
        for record in records:
            print(f"  {label}: {record['sessions']} sessions, {record['seconds']:g} s, seed {record['seed']}: "
                  f"{record['frames']} frames ({record['table_frames']} from phase tables), sha256 {record['hash']}")
    result = {"runs": runs}
    if args.baseline is not None:
        result["same"] = [a["hash"] for a in runs["baseline"]] == [b["hash"] for b in runs["this tree"]]
        print(f"  every frame the same as the baseline's: {'yes' if result['same'] else 'NO'}")
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="one hashed run, printed as JSON (see the module docstring)")
    parser.add_argument("--json", action="store_true", required=True)
    parser.add_argument("space", type=Path)
    parser.add_argument("sessions", type=int)
    parser.add_argument("seconds", type=float)
    parser.add_argument("seed", type=int)
    a = parser.parse_args()
    print(json.dumps(asyncio.run(_run(a.space, a.sessions, a.seconds, a.seed))))
