"""``HeatmapService``: heatmap jobs handed from the event loop to the helper process, latest-wins
(see server/heatmap/__init__.py)."""

from __future__ import annotations

import asyncio
import itertools
import logging
import sys
import time

import msgpack
import numpy as np

from server.heatmap.codec import encode_distances, framed

log = logging.getLogger("morphspace.stream")
WAITING = 1          # jobs that may wait for the helper besides the one it works on (across connections)
RESTART_AFTER = 5.0  # seconds before starting the helper again after it failed to start or ended


class HeatmapService:
    """Distances from the non-linear blend for heatmap frames, computed by a helper process.

    ``service.frame_error(session, space, mode, weights, phase, seq)`` on the event loop returns
    ``(error_um, error_max, error_seq)`` for the frame ``seq`` about to be written, or None while
    its connection has no finished result yet (the first call starts the helper). A session
    provides ``heatmap_job`` and ``heatmap_last`` (both set here). ``close()`` ends the helper.
    """

    def __init__(self):
        self._process = None
        self._starting = None
        self._failed_at = -float("inf")
        self._pending = {}          # job id -> session
        self._ids = itertools.count(1)
        self._spaces = {}           # id(space) -> (space, its job fields); the space kept so its id stays its own
        self.jobs = 0
        self.failures = 0

    def close(self):
        process, self._process = self._process, None
        if process is not None and process.returncode is None:
            process.stdin.close()  # the helper exits when it reads the end of its input

    def frame_error(self, session, space, mode, weights, phase, seq):
        if mode == "nonlinear":  # the frame is the non-linear blend: exact, at once
            return (*encode_distances(np.zeros(space.n_vertices, dtype=np.float32)), seq)
        if session.heatmap_job is None and len(self._pending) <= WAITING and self._ready():
            vertices = np.asarray(space.frame_blender(mode).blend(weights, phase), dtype="<f4")  # the frame's, in metres
            job = next(self._ids)
            try:
                self._process.stdin.write(framed({
                    **self._space_fields(space), "id": job, "weights": np.asarray(weights, dtype="<f8").tobytes(),
                    "phase": float(phase), "vertices": vertices.tobytes(), "seq": seq}))
            except (ConnectionError, RuntimeError):  # it has just ended; the reader cleans up
                return session.heatmap_last
            session.heatmap_job = job
            self._pending[job] = session
            self.jobs += 1
        return session.heatmap_last

    def _space_fields(self, space):
        entry = self._spaces.get(id(space))
        if entry is None:
            container, derived = space.container, space.derived
            entry = self._spaces[id(space)] = (space, {
                "space": str(container.path), "checksum": container.checksum,
                "derived": str(derived.directory) if derived is not None else None})
        return entry[1]

    def _ready(self):
        """True when the helper runs; else start it (unless it failed a moment ago)."""
        if self._process is not None and self._process.returncode is None:
            return True
        if (self._starting is None or self._starting.done()) and time.monotonic() - self._failed_at > RESTART_AFTER:
            self._starting = asyncio.get_running_loop().create_task(self._start())
        return False

    async def _start(self):
        try:
            process = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "server.heatmap.worker", stdin=asyncio.subprocess.PIPE,
                stdout=asyncio.subprocess.PIPE)
        except OSError as exc:
            self._failed_at = time.monotonic()
            log.error("stream: the heatmap helper did not start: %s", exc)
            return
        self._process = process
        await self._read(process)

    async def _read(self, process):
        """Take the helper's answers until it ends."""
        try:
            while True:
                head = await process.stdout.readexactly(4)
                reply = msgpack.unpackb(await process.stdout.readexactly(int.from_bytes(head, "little")), raw=False)
                session = self._pending.pop(reply.get("id"), None)
                if session is None:
                    continue
                session.heatmap_job = None
                if "error" in reply:
                    self.failures += 1
                    log.error("stream: a heatmap job failed: %s", reply["error"])
                    continue
                session.heatmap_last = (reply["error_um"], reply["error_max"], reply["seq"])
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            for session in self._pending.values():
                session.heatmap_job = None
            self._pending.clear()
            if self._process is process:
                self._process = None
            self._failed_at = time.monotonic()
            code = await process.wait()
            if code:
                log.error("stream: the heatmap helper ended with status %s", code)
