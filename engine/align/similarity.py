"""Shape dissimilarity between all frames of all sequences (Casas et al. 2012, section 3.1).

``histograms = frame_histograms(meshes)`` computes one volumetric shape histogram per frame
(``engine.align.shape_histogram``), ``D, yaw = dissimilarity_matrix(histograms)`` compares every
pair at its best rotation about the vertical axis, and ``temporal_filter(D, lengths)``
averages each pair over a window of neighbouring frame pairs so that the measure reflects
motion as well as shape (Huang et al. 2010, the paper's ref [31]). :func:`shape_dissimilarity`
does all three. Work is split into chunks that can run in worker processes.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from engine.align.shape_histogram import (
    correlation_over_rotations,
    best_rotation,
    histogram_norm2,
    is_closed,
    refine_rotation,
    shape_centre,
    shape_histogram,
)

HISTOGRAM_DEFAULTS = dict(shells=10, elevations=8, harmonics=12, subdivisions=1)


@dataclass(frozen=True)
class ShapeSimilarity:
    """Shape histograms and dissimilarities of N frames.

    Attributes
    ----------
    histograms : (N, shells, elevations, harmonics + 1) complex array
    raw : (N, N) float array        histogram distance at the best vertical rotation (symmetric,
                                    zero diagonal)
    dissimilarity : (N, N) float array   ``raw`` after temporal filtering (what the tree uses)
    yaw : (N, N) float32 array      degrees about +Y that best rotate frame j onto frame i
                                    (antisymmetric)
    radius : float                  outer shell radius used for every frame (metres)
    lengths : (S,) int array        frames per sequence, in order (frames are concatenated)
    window : int                    temporal filter half-width in frames
    """

    histograms: np.ndarray
    raw: np.ndarray
    dissimilarity: np.ndarray
    yaw: np.ndarray
    radius: float
    lengths: np.ndarray
    window: int


def histogram_radius(meshes, margin=1.05):
    """A common outer radius: the largest centre-to-vertex distance over all frames, plus 5%.

    Parameters
    ----------
    meshes : sequence of (V, F) pairs or objects with ``.vertices`` and ``.faces``

    Returns
    -------
    radius : float
    """
    radius = 0.0
    for V, F in map(_vf, meshes):
        c = shape_centre(V, F)
        radius = max(radius, float(np.sqrt(np.max(np.einsum("ij,ij->i", V - c, V - c)))))
    if not radius > 0:
        raise ValueError("all frames are single points; no shape to compare")
    return margin * radius


def _vf(mesh):
    if hasattr(mesh, "vertices"):
        return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    V, F = mesh[0], mesh[1]
    return np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)


def _histogram_chunk(job):
    frames, radius, options, mode = job
    return np.stack([shape_histogram(V, F, radius=radius, mode=mode, **options) for V, F in frames])


def histogram_task(shared, frames):
    """Runner task: histograms of a chunk of (V, F) frames; ``shared`` is (radius, options, mode)."""
    return _histogram_chunk((frames,) + tuple(shared))


def frame_histograms(meshes, *, radius=None, workers=1, chunk=32, progress=None, runner=None, **options):
    """Shape histogram of every frame (all with the same bins).

    Parameters
    ----------
    meshes : sequence of (V, F) pairs or Mesh-like objects
    radius : float or None   outer shell radius (default :func:`histogram_radius`)
    workers : int            worker processes (1: compute here)
    chunk : int              frames per task
    progress : callable(done, total) or None
    runner : task runner or None   run the chunks as tasks of this runner (:mod:`engine.tasks`)
                             instead of ``workers``; the result is the same
    **options                shells, elevations, harmonics, subdivisions (see
                             ``engine.align.shape_histogram.shape_histogram``)

    Returns
    -------
    histograms : (N, shells, elevations, harmonics + 1) complex array
    radius : float

    Notes
    -----
    Every frame is binned by volume when all frames are closed surfaces and by area otherwise,
    so that all histograms measure the same thing.
    """
    frames = [_vf(m) for m in meshes]
    if not frames:
        raise ValueError("no frames")
    options = {**HISTOGRAM_DEFAULTS, **options}
    if radius is None:
        radius = histogram_radius(frames)
    mode = "volume" if all(is_closed(F) for _, F in frames) else "surface"
    if runner is not None:
        chunks = [frames[i:i + chunk] for i in range(0, len(frames), chunk)]
        parts = runner.map(histogram_task, chunks, shared=(radius, options, mode), sizes=[len(c) for c in chunks],
                           progress=progress)
        return np.concatenate(parts), float(radius)
    jobs = [(frames[i:i + chunk], radius, options, mode) for i in range(0, len(frames), chunk)]
    parts = _run(_histogram_chunk, jobs, workers, progress, [len(j[0]) for j in jobs])
    return np.concatenate(parts), float(radius)


_SHARED = {}


def _init_shared(histograms, norms, steps):
    _SHARED.update(histograms=histograms, norms=norms, steps=steps)


def _distance_block(job):
    """Rows start..stop against columns start..N: distances and best rotations."""
    return distance_task((_SHARED["histograms"], _SHARED["norms"], _SHARED["steps"]), job)


def distance_task(shared, rows):
    """Runner task: the block of rows (start, stop) against columns start..N; ``shared`` is
    (histograms, norms, steps)."""
    H, norms, steps = shared
    start, stop = rows
    return (start, stop) + _block(H[start:stop], H[start:], norms[start:stop], norms[start:], steps)


def _block(H_rows, H_cols, norm_rows, norm_cols, steps):
    r, c = len(H_rows), len(H_cols)
    K = H_rows.shape[-1]
    A = H_rows.reshape(r, -1, K).transpose(2, 0, 1)  # (K, r, cells)
    B = H_cols.reshape(c, -1, K).transpose(2, 0, 1)
    cross = np.matmul(A, np.conj(B).transpose(0, 2, 1)).transpose(1, 2, 0)  # (r, c, K)
    correlation = correlation_over_rotations(cross, steps)
    degrees, _ = best_rotation(correlation)
    degrees, peak = refine_rotation(cross, degrees, max_step=360.0 / steps)
    squared = norm_rows[:, None] + norm_cols[None, :] - 2.0 * peak
    return np.sqrt(np.maximum(squared, 0.0)), degrees.astype(np.float32)


def dissimilarity_matrix(histograms, *, steps=48, chunk=64, workers=1, parallel_from=3000, progress=None,
                         runner=None):
    """Histogram distance of every pair of frames at its best rotation about the vertical axis.

    Parameters
    ----------
    histograms : (N, shells, elevations, harmonics + 1) complex array
    steps : int      rotations sampled over the full turn, refined by a parabola at the best
    chunk : int      rows per task (the block of rows i against columns >= i)
    workers : int    worker processes (1: compute here)
    parallel_from : int   use the workers only from this many frames on: below it, starting the
                     processes and shipping the histograms costs more than it saves (the block
                     products already use every core through BLAS; 1,500 frames take about 2.5 s
                     here, 5,000 frames 29 s serially and 23 s with 2 processes)
    progress : callable(done, total) or None   in rows
    runner : task runner or None   run the blocks as tasks of this runner (:mod:`engine.tasks`),
                     whatever the number of frames; the same blocks, so the same result

    Returns
    -------
    D : (N, N) float64 array     symmetric, zero diagonal
    yaw : (N, N) float32 array   degrees about +Y best rotating frame j onto frame i
                                 (``yaw[j, i] == -yaw[i, j]``)

    Notes
    -----
    For each pair, ``|H_i|^2 + |H_j|^2 - 2 max_theta <H_i, R_theta H_j>``; the correlation over
    theta comes from one product per azimuthal harmonic (all pairs at once, as matrix
    products) and an inverse FFT (Casas et al. 2012, section 3.1).
    """
    H = np.ascontiguousarray(histograms, dtype=np.complex128)
    if H.ndim != 4:
        raise ValueError(f"histograms must have shape (N, shells, elevations, harmonics + 1), got {H.shape}")
    N = len(H)
    norms = histogram_norm2(H)
    D = np.zeros((N, N))
    yaw = np.zeros((N, N), dtype=np.float32)
    # Blocks of rows against the columns from their first row on: the upper triangle only.
    # Rows are grouped so that every block costs about the same.
    bounds = _balanced_row_blocks(N, chunk)
    jobs = list(zip(bounds[:-1], bounds[1:]))
    sizes = [b - a for a, b in jobs]
    if runner is not None:
        results = runner.map(distance_task, jobs, shared=(H, norms, steps), sizes=sizes, progress=progress)
    elif workers > 1 and len(jobs) > 1 and N >= parallel_from:
        results = _run(_distance_block, jobs, workers, progress, sizes,
                       initializer=_init_shared, initargs=(H, norms, steps))
    else:
        _init_shared(H, norms, steps)
        try:
            results = _run(_distance_block, jobs, 1, progress, sizes)
        finally:
            _SHARED.clear()
    for start, stop, block, degrees in results:
        D[start:stop, start:] = block
        yaw[start:stop, start:] = degrees
    upper = np.triu_indices(N, 1)
    D[(upper[1], upper[0])] = D[upper]
    yaw[(upper[1], upper[0])] = -yaw[upper]
    np.fill_diagonal(D, 0.0)
    np.fill_diagonal(yaw, 0.0)
    return D, yaw


def _balanced_row_blocks(N, chunk):
    """Row boundaries so that blocks of the upper triangle have about chunk * N / 2 entries."""
    target = max(1, chunk) * max(N, 1) / 2.0
    bounds, start = [0], 0
    while start < N:
        stop, area = start, 0.0
        while stop < N and (area == 0.0 or area + (N - stop) <= target):
            area += N - stop
            stop += 1
        bounds.append(stop)
        start = stop
    return np.array(bounds)


def temporal_filter(D, lengths, window=2):
    """Average each pair's dissimilarity over neighbouring frame pairs of the same two sequences.

    Parameters
    ----------
    D : (N, N) float array      frames of all sequences concatenated in order
    lengths : (S,) int array    frames per sequence (sum N)
    window : int                half-width k: pairs (i + t, j + t) for |t| <= k, both inside
                                their sequences

    Returns
    -------
    D_filtered : (N, N) float array   symmetric; the diagonal stays zero

    Notes
    -----
    Huang et al. 2010 (the paper's ref [31]): temporal filtering makes the measure sensitive to
    motion, so that frames of similar shape moving in opposite directions are told apart.
    """
    D = np.asarray(D, dtype=np.float64)
    lengths = np.asarray(lengths, dtype=np.int64)
    if D.ndim != 2 or D.shape[0] != D.shape[1]:
        raise ValueError(f"D must be square, got {D.shape}")
    if lengths.sum() != len(D) or np.any(lengths < 1):
        raise ValueError(f"sequence lengths {lengths.tolist()} do not add up to {len(D)} frames")
    if window <= 0:
        return D.copy()
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    out = np.empty_like(D)
    for a, (sa, na) in enumerate(zip(starts, lengths)):
        for b, (sb, nb) in enumerate(zip(starts, lengths)):
            block = D[sa:sa + na, sb:sb + nb]
            total = np.zeros_like(block)
            count = np.zeros_like(block)
            for t in range(-window, window + 1):
                i0, i1 = max(0, -t), min(na, na - t)  # rows i with 0 <= i + t < na
                j0, j1 = max(0, -t), min(nb, nb - t)
                if i1 <= i0 or j1 <= j0:
                    continue
                total[i0:i1, j0:j1] += block[i0 + t:i1 + t, j0 + t:j1 + t]
                count[i0:i1, j0:j1] += 1.0
            out[sa:sa + na, sb:sb + nb] = total / count
    out = 0.5 * (out + out.T)
    np.fill_diagonal(out, 0.0)
    return out


def shape_dissimilarity(meshes, lengths, *, window=2, workers=1, progress=None, runner=None, **options):
    """Histograms, raw and temporally filtered dissimilarities of all frames of all sequences.

    Parameters
    ----------
    meshes : sequence of (V, F) or Mesh-like, all frames of all sequences concatenated
    lengths : (S,) int array   frames per sequence
    window : int               temporal filter half-width (frames)
    workers : int              worker processes
    progress : callable(stage, done, total) or None   stage is "histograms" or "dissimilarity"
    runner : task runner or None   runs the histogram chunks and matrix blocks (:mod:`engine.tasks`)
    **options                  histogram options (shells, elevations, harmonics, subdivisions,
                               radius) and ``steps`` for the rotation search

    Returns
    -------
    ShapeSimilarity
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    if lengths.sum() != len(meshes):
        raise ValueError(f"sequence lengths add up to {lengths.sum()} frames, got {len(meshes)} meshes")
    steps = options.pop("steps", 48)
    stage = (lambda name: (lambda done, total: progress(name, done, total))) if progress else (lambda name: None)
    H, radius = frame_histograms(meshes, workers=workers, progress=stage("histograms"), runner=runner, **options)
    raw, yaw = dissimilarity_matrix(H, steps=steps, workers=workers, progress=stage("dissimilarity"), runner=runner)
    filtered = temporal_filter(raw, lengths, window)
    return ShapeSimilarity(histograms=H, raw=raw, dissimilarity=filtered, yaw=yaw, radius=radius,
                           lengths=lengths, window=int(window))


def _run(function, jobs, workers, progress, sizes, initializer=None, initargs=()):
    """Results of ``function`` over ``jobs`` in order, in worker processes when workers > 1."""
    total, done = int(sum(sizes)), 0
    results = [None] * len(jobs)
    if workers <= 1 or len(jobs) <= 1:
        for i, job in enumerate(jobs):
            results[i] = function(job)
            done += sizes[i]
            if progress is not None:
                progress(done, total)
        return results
    import multiprocessing

    context = multiprocessing.get_context("forkserver" if os.name == "posix" else "spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=initializer,
                             initargs=initargs) as pool:
        futures = {pool.submit(function, job): i for i, job in enumerate(jobs)}
        from concurrent.futures import as_completed

        for future in as_completed(futures):
            i = futures[future]
            results[i] = future.result()
            done += sizes[i]
            if progress is not None:
                progress(done, total)
    return results


__all__ = ["HISTOGRAM_DEFAULTS", "ShapeSimilarity", "dissimilarity_matrix", "distance_task", "frame_histograms",
           "histogram_radius", "histogram_task", "shape_dissimilarity", "temporal_filter"]
