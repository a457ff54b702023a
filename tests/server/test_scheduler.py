"""send_now runs a send in the caller when the transport takes it, and abandons it when it would wait;
the scheduler's ticks keep docs/protocol.md's timing (frames at most half a tick early, shared ticks)."""

import asyncio
import concurrent.futures

import pytest

from server.scheduler import TICK, FrameScheduler, send_now


def run(main):
    """asyncio.run(main()) on a thread of its own: the worker's main thread may hold another
    loop (Playwright's, from the browser tests)."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, main()).result(timeout=30)


def test_a_coroutine_that_does_not_wait_completes_in_the_call():
    async def main():
        done = []

        async def send():
            done.append(1)

        assert send_now(send()) is True
        assert done == [1]

    run(main)


def test_a_coroutine_that_would_wait_is_abandoned_and_closed():
    async def main():
        full = asyncio.Event()   # a transport above its high-water mark
        steps = []

        async def send():
            try:
                await full.wait()
                steps.append("written")
            finally:
                steps.append("closed")

        assert send_now(send()) is False
        assert steps == ["closed"]
        full.set()
        await asyncio.sleep(0.01)
        assert steps == ["closed"]   # nothing was left behind to write it later

    run(main)


def test_errors_reach_the_caller():
    async def main():
        async def fails_at_once():
            raise ConnectionResetError("gone")

        with pytest.raises(ConnectionResetError):
            send_now(fails_at_once())

    run(main)


class GridSession:
    """A connection on a 60 frames/s grid that records (tick time, due time) for each frame: the
    scheduler's side of a StreamSession, no player or transport behind it."""

    def __init__(self, scheduler, first_due, frames):
        self.scheduler, self.version, self.closed, self.payload = scheduler, 0, False, None
        self.player = self
        self.phase = 0.0
        self.due, self.frames = first_due, frames

    def advance(self, dt):
        pass

    def due_step(self, now):
        self.frames.append((now, self.due))
        return 0.0

    def frame_source(self):
        return None, "f32"

    def moving_source(self):
        return None

    def send_frame(self, payload):
        self.due += 1.0 / 60.0

    def next_frame_due(self):
        return self.due

    def after_frame(self):
        self.scheduler.schedule(self, self.due)

    def fail(self, exc):
        raise exc


def test_frames_leave_at_most_half_a_tick_early_in_shared_ticks():
    """docs/protocol.md, Rates: shared ticks at least ``TICK`` (2 ms) apart, a frame up to half a
    tick early: 40 connections at 60 frames/s, their grids spread over a period, get every frame
    no earlier than that, in ticks that serve several connections each."""

    async def main():
        loop = asyncio.get_running_loop()
        scheduler, frames, sessions = FrameScheduler(), [], []
        start = loop.time() + 0.02
        for k in range(40):
            session = GridSession(scheduler, start + k / 40 / 60.0, frames)
            sessions.append(session)
            scheduler.add(session)
            scheduler.schedule(session, session.due)
        await asyncio.sleep(0.5)
        for session in sessions:
            scheduler.remove(session)
        return frames

    frames = run(main)
    assert len(frames) >= 40 * 10  # (30 a connection on time; fewer, one a tick, on a starved host)
    earliest = min(now - due for now, due in frames)
    assert earliest >= -0.5 * TICK - 1e-6, f"a frame left {-1e3 * earliest:.2f} ms early"
    ticks = sorted({now for now, _ in frames})
    assert len(frames) / len(ticks) >= 2.5  # 40 grids over a period share about 8 ticks a period
