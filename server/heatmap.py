"""Heatmaps off the event loop: per-vertex distances of streamed frames from the non-linear blend.

A heatmap frame needs the exact non-linear blend at the frame's weights and phase: about a
millisecond of solving for 3,000 vertices, far too much per frame on the event loop that serves
every client. ``HeatmapService`` computes the distances in one worker thread instead,
latest-wins: when a heatmap frame is written, its connection has no job in flight and the thread
has no other job waiting, a job for *that* frame (its weights, phase and vertices) goes to the
thread; every frame carries its connection's newest finished result, and ``error_seq`` names the
frame it describes (a viewer colours the mesh it shows with distances a few frames old, or a few
tenths of a second with dozens of heatmap viewers, and can tell). The frames themselves never
wait for it, and heatmap frames are produced like any other (from the phase tables when the
weights recur). The thread works at most a quarter of the time (``DUTY``: it rests three times
as long as each job took), so it never takes more than a quarter of a core from the event loop.

The worker thread has its own non-linear blender per space (built there on first use): blenders
keep scratch buffers, and the loop's serves non-linear streams and pulls meanwhile. Its numpy and
sparse solves release the GIL, so on a machine with a spare core the work runs beside the loop.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

log = logging.getLogger("morphspace.stream")
WAITING = 1   # jobs that may wait for the thread (latest-wins across connections)
DUTY = 0.25   # the share of the time the thread may work


def encode_distances(distance):
    """(error_um bytes: uint16 micrometres, saturating; error_max in metres) of (n,) distances."""
    return np.minimum(np.rint(distance * 1e6), 65535).astype("<u2").tobytes(), float(distance.max())


class HeatmapService:
    """Distances from the non-linear blend for heatmap frames (see the module docstring).

    ``service.frame_error(session, space, mode, weights, phase, seq)`` on the event loop returns
    ``(error_um, error_max, error_seq)`` for the frame ``seq`` about to be written, or None while
    its connection has no finished result yet. A session provides ``heatmap_job``,
    ``heatmap_last`` (both set here) and ``loop``.
    """

    def __init__(self):
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="morphspace-heatmap")
        self._blenders = {}   # worker thread only: id(space) -> (space, its own non-linear blender)
        self._pending = 0     # jobs submitted and not finished
        self.jobs = 0

    def close(self):
        self._pool.shutdown(wait=False, cancel_futures=True)

    def frame_error(self, session, space, mode, weights, phase, seq):
        if mode == "nonlinear":  # the frame is the non-linear blend: exact, at once
            return (*encode_distances(np.zeros(space.n_vertices, dtype=np.float32)), seq)
        if session.heatmap_job is None and self._pending <= WAITING:
            vertices = np.array(space.frame_blender(mode).blend(weights, phase), dtype=np.float32)  # the frame's, in metres
            job = self._pool.submit(self._distances, space, np.array(weights, dtype=np.float64), float(phase),
                                    vertices, seq)
            session.heatmap_job = job
            self._pending += 1
            job.add_done_callback(lambda job: session.loop.call_soon_threadsafe(self._finished, session, job))
            self.jobs += 1
        return session.heatmap_last

    def _finished(self, session, job):
        session.heatmap_job = None
        self._pending -= 1
        if job.cancelled():
            return
        if job.exception() is not None:
            log.error("stream: a heatmap job failed", exc_info=job.exception())
            return
        session.heatmap_last = job.result()

    # ------------------------------------------------------------ the worker thread's side

    def _distances(self, space, weights, phase, vertices, seq):
        started = time.perf_counter()
        entry = self._blenders.get(id(space))
        if entry is None:  # (the space is kept with it, so its id is not reused)
            entry = self._blenders[id(space)] = (space, space.new_blender("nonlinear"))
        reference = entry[1].blend(weights, phase)
        result = (*encode_distances(np.linalg.norm(vertices - reference, axis=1)), seq)
        busy = time.perf_counter() - started
        time.sleep(min(busy * (1 - DUTY) / DUTY, 0.2))  # a quarter of the time at most
        return result
