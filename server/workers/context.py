"""What one server worker process knows of the others (``morphspace serve --workers N``).

``WorkerContext`` is handed to ``create_app`` in each worker: its index, the shared counter board
(server/workers/board.py) and the jobs' wake-up pipe. Worker 0 runs the job queue; the others
queue jobs in the shared store (``jobs.sqlite``) and write a byte to the pipe, which worker 0
watches, so it claims the job at once (it also polls the store every few seconds).
``server_counters(app.state)`` is what /v1/health reports, for one process or several.
"""

from __future__ import annotations

import asyncio
import os
import time

from server.workers.board import PUBLISH_EVERY


class WorkerContext:
    """Worker ``index`` of ``count``, sharing ``board`` and the pipe (``wake_read``, ``wake_write``)."""

    def __init__(self, index, count, board, wake_read, wake_write):
        self.index, self.count, self.board = index, count, board
        self.wake_read, self.wake_write = wake_read, wake_write
        self.pid = os.getpid()

    @property
    def runs_jobs(self):
        """True in the one worker that owns the job queue (index 0)."""
        return self.index == 0

    def publish(self, counters):
        self.board.publish(self.index, self.pid, counters)

    def wake_jobs(self):
        """Tell the job queue's worker that the store changed (a job queued or a cancel asked)."""
        try:
            os.write(self.wake_write, b"j")
        except (BlockingIOError, OSError):
            pass  # the pipe is full (the owner is restarting): it reads the store when it starts

    def on_wake(self, loop, callback):
        """Job queue's worker: call ``callback()`` on the loop whenever another worker wakes it."""
        def drain():
            try:
                while os.read(self.wake_read, 4096):
                    pass
            except (BlockingIOError, OSError):
                pass
            callback()
        loop.add_reader(self.wake_read, drain)
        return lambda: loop.remove_reader(self.wake_read)

    async def publish_forever(self, counters):
        """Publish ``counters()`` every PUBLISH_EVERY seconds (a task for the app's lifetime)."""
        while True:
            self.publish(counters())
            await asyncio.sleep(PUBLISH_EVERY)


class WorkerHeader:
    """ASGI middleware: every HTTP response names the worker that answered it
    (``X-Morphspace-Worker: <index>``)."""

    def __init__(self, app, index):
        self.app, self.value = app, str(index).encode()

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)

        async def send_named(message):
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []), (b"x-morphspace-worker", self.value)]}
            await send(message)

        return await self.app(scope, receive, send_named)


def local_counters(state):
    """This process's stream counters (app.state): connections, frames sent and dropped, stream
    errors and the frame scheduler's tally."""
    stats = state.stream_stats
    return {"connections": stats.connections, "frames_sent": stats.frames, "frames_dropped": stats.dropped,
            "stream_errors": stats.errors, "scheduler": state.frame_scheduler.counters()}


def server_counters(state):
    """(workers, totals, restarts) over every worker process of this server (one record when it
    runs as one process)."""
    counters = local_counters(state)
    worker = getattr(state, "worker", None)
    if worker is None:
        record = {"index": 0, "pid": os.getpid(), "alive": True, "jobs": True, "started_at": state.started_at,
                  "restarts": 0, "last_exit": None, "published_ago": 0.0, **counters}
        return [record], counters, 0
    worker.publish(counters)
    return worker.board.summary(time.time(), shape=counters)
