"""Blend timings: frames per second of each blend mode on one core.

Timings here are for benchmarks (``morphspace bench``, ``benchmarks/``), never for unit tests.
"""

from __future__ import annotations

import time

import numpy as np


def blend_requests(n_sources, count, seed=0):
    """Random (weights, phase) requests: Dirichlet weights, phases between grid samples."""
    rng = np.random.default_rng(seed)
    return [(w, float(p)) for w, p in zip(rng.dirichlet(np.ones(n_sources), count), rng.uniform(0, 1, count))]


def blend_speed(blender, requests, *, out=None, repeats=3):
    """Time ``blender.blend`` over ``requests``.

    Returns
    -------
    dict with median_us, p95_us (per call, over all calls of the fastest repeat) and
    frames_per_second (calls / wall time of the fastest repeat)
    """
    best = None
    for _ in range(repeats):
        times = np.empty(len(requests))
        started = time.perf_counter()
        for k, (w, phase) in enumerate(requests):
            t0 = time.perf_counter()
            blender.blend(w, phase, out=out)
            times[k] = time.perf_counter() - t0
        wall = time.perf_counter() - started
        if best is None or wall < best[1]:
            best = (times, wall)
    times, wall = best
    return {"median_us": float(np.median(times) * 1e6), "p95_us": float(np.percentile(times, 95) * 1e6),
            "frames_per_second": float(len(requests) / wall), "calls": len(requests)}


def single_core():
    """Context manager limiting BLAS/OpenMP pools to one thread (threadpoolctl)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1)
