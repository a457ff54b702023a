"""Steering clients blended together in one tick get exactly the frames they get blended one by one.

Two identical sets of stream sessions over a real space (the connection's transport replaced by a
recorder of the messages written): one set goes through the scheduler's tick as one batch (moving
weights blended together, q16 encoded together), the other frame by frame through the session's
own path (``send_frame(None)``: blend this one alone). Every frame must be the same message, byte
for byte, apart from its send time.
"""

import asyncio
import concurrent.futures

import msgpack
import numpy as np
from engine.player import Player
from server import protocol as P
from server.frames import joined
from server.registry import SpaceRegistry
from server.scheduler import FrameScheduler
from server.settings import Settings
from server.stream.session import StreamSession, StreamStats
from server.transport import GAUGE


class Recorder:
    """A transport that takes every message at once and keeps it."""

    def __init__(self):
        self.messages = []

    def ready(self):
        return True

    def held(self):
        return 0

    def held_above(self, floor):
        return None

    def write_message(self, parts):
        self.messages.append(msgpack.unpackb(joined(parts)))
        return True


class Socket:
    def __init__(self, recorder):
        self.scope = {"extensions": {GAUGE: recorder}}


def run(main):
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, main()).result(timeout=60)


# (mode, codec, first request, steered to): speeds of the speed space (0.9 .. 2.6 m/s)
CLIENTS = [("hybrid", "q16", 1.0, 2.4), ("hybrid", "f32", 2.5, 1.1), ("hybrid", "q16", 1.7, 1.8),
           ("linear", "q16", 1.2, 2.2), ("linear", "f32", 2.2, 1.0), ("hybrid", "f32", 1.3, 2.0),
           ("nonlinear", "q16", 1.1, 2.3), ("nonlinear", "f32", 2.0, 1.4)]


def _sessions(registry, scheduler, space):
    bounds = np.asarray(registry.describe("speed")["bounds"], dtype=np.float32)
    sessions = []
    for k, (mode, codec, start, target) in enumerate(CLIENTS):
        session = StreamSession(Socket(Recorder()), registry, Settings(), StreamStats(), scheduler)
        session.player = Player(space, mode=mode, smoothing=0.3, params={"speed": start})
        session.player.set_params({"speed": target})  # steering: the spring moves the weights every frame
        session.player.seek(0.13 * k)
        session.space_name, session.rate, session.codec, session.bounds = "speed", 60.0, codec, bounds
        session.quantiser = P.Quantiser(bounds, space.n_vertices) if codec == "q16" else None
        session.ready = True
        sessions.append(session)
    return sessions


def _frames(sessions):
    out = []
    for session in sessions:
        message = dict(session.gauge.messages[-1])
        del message["sent_at"]
        out.append(message)
    return out


def test_a_batch_of_steering_clients_gets_the_frames_they_get_one_by_one(built_spaces):
    registry = SpaceRegistry(built_spaces)
    space = registry.get("speed")

    async def main():
        batched_scheduler, alone_scheduler = FrameScheduler(), FrameScheduler()
        batched = _sessions(registry, batched_scheduler, space)
        alone = _sessions(registry, alone_scheduler, space)
        for step in range(6):
            now = 100.0 + step / 60.0
            for session in batched + alone:
                session.next_due = now
            batched_scheduler._produce(list(batched), now)
            for session in alone:  # the session's own path: blend and encode this one alone
                assert session.advance(now)
                table, _ = session.frame_source()
                assert table is None  # moving weights: no phase table
                session.send_frame(None)
                session.after_frame()
            one, other = _frames(batched), _frames(alone)
            for a, b, (mode, codec, _, _) in zip(one, other, CLIENTS):
                assert a["seq"] == b["seq"] == step + 1
                assert a == b, f"{mode} {codec}: the batched frame differs"
            assert not all(s.player.settled for s in batched)
        moving = sum(mode != "nonlinear" for mode, _, _, _ in CLIENTS)
        assert batched_scheduler.batched_frames == 6 * moving   # the non-linear ones blended alone
        assert batched_scheduler.frames == 6 * len(CLIENTS) and batched_scheduler.table_frames == 0
        # the frames are the blends: decoded, within the codec's step of the blender's frame
        for session, message in zip(batched, _frames(batched)):
            player = session.player
            expected = space.blender(player.mode).blend(player.weights, player.phase)
            vertices = P.decode_vertices(message["vertices"], session.codec, space.n_vertices,
                                         session.bounds[0], session.bounds[1])
            tolerance = 1e-5 if session.codec == "f32" else P.quantisation_error(session.bounds) + 1e-5
            assert np.linalg.norm(vertices - expected, axis=1).max() <= tolerance

    run(main)


def test_a_batch_that_fails_to_blend_falls_back_to_one_by_one(built_spaces, monkeypatch):
    """A failure in the batched blend is logged; its members are blended alone, and the stream goes on."""
    registry = SpaceRegistry(built_spaces)
    space = registry.get("speed")

    async def main():
        scheduler = FrameScheduler()
        sessions = _sessions(registry, scheduler, space)

        def broken(blender, members):
            raise RuntimeError("broken batch")

        monkeypatch.setattr(scheduler, "_blend_together", broken)
        for session in sessions:
            session.next_due = 100.0
        scheduler._produce(list(sessions), 100.0)
        assert scheduler.frames == len(sessions) and scheduler.batched_frames == 0
        assert all(len(s.gauge.messages) == 1 and not s.closed for s in sessions)

    run(main)


class RawRecorder(Recorder):
    """Keeps each message's wire bytes."""

    def write_message(self, parts):
        self.messages.append(joined(parts))
        return True


def test_streamed_frames_are_the_whole_maps_msgpack_packing(built_spaces):
    """A streamed frame is packed from cached pieces (server.frames.StreamedFrame): its bytes must
    be msgpack's packing of the whole map in Frame's field order, with the player's values, both
    while the parameters move and once they have settled (the cached pieces kept)."""
    registry = SpaceRegistry(built_spaces)
    space = registry.get("speed")
    order = ["type", "seq", "ack", "time", "phase", "mode", "requested", "realised", "clamped", "weights", "root",
             "heading", "dropped", "finished", "sent_at", "pull_id", "error_max", "error_seq", "node", "target",
             "progress", "error_um", "vertices"]

    async def main():
        scheduler = FrameScheduler()
        sessions = _sessions(registry, scheduler, space)
        for session in sessions:
            session.ws = Socket(RawRecorder())
            session.gauge = session.ws.scope["extensions"][GAUGE]
            session.ack, session.dropped = 3, 200
            session.player.smoothing = 0.05  # settled within the run
        settled = 0
        for step in range(60):
            now = 100.0 + step / 60.0
            for session in sessions:
                session.next_due = now
            scheduler._produce(list(sessions), now)
            for session in sessions:
                raw = session.gauge.messages[-1]
                message = msgpack.unpackb(raw)
                assert list(message) == order and msgpack.packb(message) == raw
                player = session.player
                assert message["seq"] == step + 1 and message["ack"] == 3 and message["dropped"] == 200
                assert message["weights"] == player.weights.tolist() and message["requested"] == player.requested.tolist()
                assert message["realised"] == player.realised.tolist() and message["phase"] == player.phase
                assert message["root"] == player.position.tolist() and message["mode"] == player.mode
                settled += player.settled
        assert settled > 0 and scheduler.table_frames > 0  # settled ones too (their pieces kept)

    run(main)


def test_frame_source_follows_the_weights_and_the_quantiser(built_spaces):
    """frame_source keeps the last (table, its q16 form) and the space's frame blender: a new
    request, a new quantiser or a new mode must give the table of now, never the kept one."""
    registry = SpaceRegistry(built_spaces)
    space = registry.get("speed")

    async def main():
        scheduler = FrameScheduler()
        session = _sessions(registry, scheduler, space)[0]  # hybrid, q16
        for speed in (1.2, 2.2, 1.2):
            session.player.set_params({"speed": speed}, immediate=True)
            blender = space.frame_blender(session.player.mode)
            for _ in range(blender.after):  # the table is built on the after-th request
                table, codec = session.frame_source()
            assert codec == "q16" and table is session.quantiser.table(blender.lookup(session.player.weights))
        session.quantiser = P.Quantiser(session.bounds * 2.0, space.n_vertices)
        table, _ = session.frame_source()
        assert table is session.quantiser.table(space.frame_blender("hybrid").lookup(session.player.weights))
        session.player.set_mode("linear")
        for _ in range(space.frame_blender("linear").after):
            table, _ = session.frame_source()
        assert table is session.quantiser.table(space.frame_blender("linear").lookup(session.player.weights))

    run(main)
