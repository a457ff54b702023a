"""Blend timings: frames per second of each blend mode on one core.

Timings here are for benchmarks (``morphspace bench``, ``benchmarks/``), never for unit tests.
"""

from __future__ import annotations

import time

import numpy as np


class BlendRequests:
    """Random (weights, phase) requests: Dirichlet weights, phases between grid samples. A sequence
    of (weights (n_sources,), phase) pairs kept as two arrays, (n_sources + 1) floats a request
    (a million requests of a 3-source space: 32 MB, not the ~250 MB of a tuple and an array each)."""

    def __init__(self, n_sources, count, seed=0):
        rng = np.random.default_rng(seed)
        self.weights = rng.dirichlet(np.ones(n_sources), count)
        self.phases = rng.uniform(0, 1, count)

    def __len__(self):
        return len(self.phases)

    def __getitem__(self, k):
        return self.weights[k], float(self.phases[k])

    def __iter__(self):
        return ((w, float(p)) for w, p in zip(self.weights, self.phases))


def blend_requests(n_sources, count, seed=0):
    """``count`` random requests for ``n_sources`` sources (:class:`BlendRequests`)."""
    return BlendRequests(n_sources, count, seed)


def blend_speed(blender, requests, *, out=None, repeats=3):
    """Time ``blender.blend`` over ``requests``.

    Returns
    -------
    dict with median_us, p95_us (per call, over all calls of the fastest repeat),
    frames_per_second (calls / wall time of the fastest repeat) and cpu_frames_per_second
    (calls / this thread's CPU time in that repeat: what one core does when it is not shared,
    so other processes on a loaded machine do not count against it)
    """
    best = None
    for _ in range(repeats):
        times = np.empty(len(requests))
        started, cpu_started = time.perf_counter(), time.thread_time()
        for k, (w, phase) in enumerate(requests):
            t0 = time.perf_counter()
            blender.blend(w, phase, out=out)
            times[k] = time.perf_counter() - t0
        wall, cpu = time.perf_counter() - started, time.thread_time() - cpu_started
        if best is None or wall < best[1]:
            best = (times, wall, cpu)
    times, wall, cpu = best
    return {"median_us": float(np.median(times) * 1e6), "p95_us": float(np.percentile(times, 95) * 1e6),
            "frames_per_second": float(len(requests) / wall),
            "cpu_frames_per_second": float(len(requests) / max(cpu, 1e-9)), "calls": len(requests)}


def player_speed(player, steps, *, dt=1.0 / 60.0, out=None):
    """Time ``player.step(dt)`` (the per-frame path: clock, root, blend, placement).

    Returns
    -------
    dict with median_us and p95_us per step and frames_per_second (steps / wall time)
    """
    times = np.empty(steps)
    started = time.perf_counter()
    for k in range(steps):
        t0 = time.perf_counter()
        player.step(dt, out=out)
        times[k] = time.perf_counter() - t0
    wall = time.perf_counter() - started
    return {"median_us": float(np.median(times) * 1e6), "p95_us": float(np.percentile(times, 95) * 1e6),
            "frames_per_second": float(steps / wall), "steps": steps}


def single_core():
    """Context manager limiting BLAS/OpenMP pools to one thread (threadpoolctl)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1)
