"""Time-warping sources onto a common phase (DESIGN.md step 5, paper section 4: t = f(t_u)).

Works on root-local frames (``engine.root_motion``), so only the body's own motion is compared.

Cyclic sources: the period is found as the lag at which the motion best repeats itself; every
source's cycle is matched to the first source's by the best circular shift and then by dynamic
time warping (DTW, monotone, band-limited), so key poses (heel strikes, toe-offs) share a phase
even when, say, a jog spends less of its cycle on the ground than a walk.

Non-cyclic sources: key events are found on the meshes (take-off and landing from the ground
clearance of a jump; the peak of a reach or any other one-shot motion as the frame where the
most-moving vertices are farthest from their start); sources are warped piecewise linearly so
their events land on common phases (the mean of the sources' normalised event times).

Every source keeps its real duration; a warp only says which source time goes with which phase.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _features(local, max_vertices=600, seed=0):
    """Subsampled vertex positions flattened per frame: (frames, 3 * m)."""
    local = np.asarray(local)
    n = local.shape[1]
    if n > max_vertices:
        index = np.sort(np.random.default_rng(seed).choice(n, max_vertices, replace=False))
        local = local[:, index]
    return local.reshape(len(local), -1)


def sample_frames(local, times):
    """Frames at fractional frame indices ``times`` by linear interpolation (clamped to the clip)."""
    local = np.asarray(local)
    t = np.clip(np.asarray(times, dtype=float), 0.0, len(local) - 1)
    k0 = np.minimum(np.floor(t).astype(int), len(local) - 2)
    a = (t - k0).reshape((-1,) + (1,) * (local.ndim - 1))
    return (1 - a) * local[k0] + a * local[k0 + 1]


def estimate_period(local, fps, *, min_seconds=0.35, max_seconds=2.5):
    """Cycle length in frames (fractional) of a cyclic motion's root-local frames.

    Parameters
    ----------
    local : (frames, n, 3) float array   at least about 1.2 cycles
    fps : float

    Returns
    -------
    period : float   the lag minimising the mean distance between frame k and frame k + lag,
                     refined to a fraction of a frame by a parabola through the best three lags

    Raises
    ------
    ValueError   when the clip is too short to contain a repeat
    """
    X = _features(local)
    frames = len(X)
    lo = max(2, int(np.floor(min_seconds * fps)))
    hi = min(int(np.ceil(max_seconds * fps)), frames - 3)
    if hi <= lo:
        raise ValueError(f"a clip of {frames} frames at {fps:g} fps is too short to find a cycle "
                         f"between {min_seconds} and {max_seconds} s")
    lags = np.arange(lo, hi + 1)
    cost = np.array([np.mean(np.sum((X[lag:] - X[:-lag]) ** 2, axis=1)) for lag in lags])
    # The first deep minimum is the period (multiples of it are minima too).
    best = int(np.argmin(cost))
    threshold = cost.min() + 0.15 * (np.median(cost) - cost.min())
    for i in range(1, len(cost) - 1):
        if cost[i] <= threshold and cost[i] <= cost[i - 1] and cost[i] <= cost[i + 1]:
            best = i
            break
    period = float(lags[best])
    if 0 < best < len(cost) - 1:
        c0, c1, c2 = cost[best - 1], cost[best], cost[best + 1]
        denom = c0 - 2 * c1 + c2
        if denom > 0:
            period += 0.5 * (c0 - c2) / denom
    return period


def cycle_at(local, start, period, n_phases):
    """(P, n, 3) one cycle sampled at P phases from fractional frame ``start``."""
    times = start + np.arange(n_phases) * (period / n_phases)
    if times[-1] > len(local) - 1 + 1e-9:
        raise ValueError(f"a cycle of {period:.2f} frames from frame {start:.2f} does not fit in "
                         f"{len(local)} frames")
    return sample_frames(local, times)


def best_circular_shift(reference, cycle):
    """Shift s (in phase samples, fractional) minimising sum_p |reference[p] - cycle[p + s]|^2."""
    A, B = _features(reference), _features(cycle)
    P = len(A)
    cost = np.array([np.sum((A - np.roll(B, -s, axis=0)) ** 2) for s in range(P)])
    s = int(np.argmin(cost))
    c0, c1, c2 = cost[(s - 1) % P], cost[s], cost[(s + 1) % P]
    denom = c0 - 2 * c1 + c2
    return s + (0.5 * (c0 - c2) / denom if denom > 0 else 0.0)


def dtw_warp(reference, cycle, *, band=0.15, cyclic=True, smoothing=2, return_cost=False):
    """Monotone warp matching ``cycle`` to ``reference`` (both (P, n, 3) on the same phase grid).

    Returns
    -------
    warp : (P,) float array   fractional sample of ``cycle`` matched to each reference sample
                              (0 at sample 0, increasing, within ``band`` * P of the diagonal)

    Notes
    -----
    Classic DTW on squared feature distances with the path pinned to (0, 0) and to the end
    ((P, P) for cycles, where sample P is sample 0 again; (P-1, P-1) for clips), then each
    reference sample takes the mean of its matched samples, lightly smoothed, kept monotone.
    """
    A, B = _features(reference), _features(cycle)
    P = len(A)
    if cyclic:  # close the loop: sample P of both is their sample 0
        A = np.concatenate([A, A[:1]])
        B = np.concatenate([B, B[:1]])
    m = len(A)
    cost = ((A[:, None, :] - B[None, :, :]) ** 2).sum(axis=2)
    width = max(2, int(np.ceil(band * P)))
    D = np.full((m, m), np.inf)
    D[0, 0] = cost[0, 0]
    for i in range(m):
        for j in range(max(0, i - width), min(m, i + width + 1)):
            if i == 0 and j == 0:
                continue
            best = min(D[i - 1, j] if i else np.inf, D[i, j - 1] if j else np.inf,
                       D[i - 1, j - 1] if i and j else np.inf)
            D[i, j] = cost[i, j] + best
    i, j = m - 1, m - 1
    path = [(i, j)]
    while i > 0 or j > 0:
        options = []
        if i and j:
            options.append((D[i - 1, j - 1], i - 1, j - 1))
        if i:
            options.append((D[i - 1, j], i - 1, j))
        if j:
            options.append((D[i, j - 1], i, j - 1))
        _, i, j = min(options)
        path.append((i, j))
    path = np.array(path[::-1])
    total = D[m - 1, m - 1] / len(path)
    warp = np.array([path[path[:, 0] == i, 1].mean() for i in range(m)])
    if smoothing > 0:
        kernel = np.ones(2 * smoothing + 1) / (2 * smoothing + 1)
        padded = np.concatenate([warp[:1] - (warp[smoothing:0:-1] - warp[0]), warp,
                                 warp[-1] + (warp[-1] - warp[-2:-smoothing - 2:-1])])
        smooth = np.convolve(padded, kernel, mode="valid")
        smooth[0], smooth[-1] = warp[0], warp[-1]
        warp = np.maximum.accumulate(smooth)
    return (warp[:P], total) if return_cost else warp[:P]


def align_cycle(reference, cycle, *, search=0.2, band=0.15):
    """Warp of a cycle onto a reference cycle: best start (circular shift) plus DTW.

    Parameters
    ----------
    reference, cycle : (P, n, 3) float arrays   one cycle each, sampled at P phases
    search : float    shifts within this fraction of a cycle of the best uniform shift are tried

    Returns
    -------
    warp : (P,) float array   for each reference phase sample, the matched sample of ``cycle``
                              (fractional, increasing, may exceed P: wrap modulo P)

    Notes
    -----
    Cycles are compared relative to their own mean poses (motion, not posture). The best uniform
    shift is a compromise when the cycles differ in timing (a jog's stance is shorter than a
    walk's), so the start is chosen among nearby shifts by the lowest DTW cost: key poses then
    match at the start as well as along the cycle.
    """
    P = len(reference)
    # Compare motions, not postures: each cycle relative to its own mean pose, so a jog's bent
    # elbows or forward lean do not outweigh where its legs are in their swing.
    reference = reference - reference.mean(axis=0)
    cycle = cycle - cycle.mean(axis=0)
    base = best_circular_shift(reference, cycle)
    best = None
    for offset in range(-int(search * P), int(search * P) + 1):
        start = int(round(base)) + offset
        shifted = np.roll(cycle, -start, axis=0)
        warp, cost = dtw_warp(reference, shifted, band=band, return_cost=True)
        if best is None or cost < best[1]:
            best = (warp + start, cost)
    return best[0]


def refine_offset(reference, sampler, warp, *, span=1.0, steps=41):
    """Sub-sample correction of a warp: the constant offset (in samples) best matching the poses.

    Parameters
    ----------
    reference : (P, n, 3) float array
    sampler : callable(positions (P,) in cycle samples) -> (P, n, 3)   the source at any phase
    warp : (P,) float array   the warp to refine (e.g. from ``align_cycle``)

    Returns
    -------
    warp + offset, with the offset in [-span, span] found on a grid and refined by a parabola
    """
    A = _features(reference - reference.mean(axis=0))
    offsets = np.linspace(-span, span, steps)
    costs = []
    for offset in offsets:
        B = sampler(warp + offset)
        B = _features(B - B.mean(axis=0))
        costs.append(np.sum((A - B) ** 2))
    costs = np.array(costs)
    k = int(np.argmin(costs))
    best = offsets[k]
    if 0 < k < steps - 1:
        c0, c1, c2 = costs[k - 1:k + 2]
        denom = c0 - 2 * c1 + c2
        if denom > 0:
            best += 0.5 * (c0 - c2) / denom * (offsets[1] - offsets[0])
    return warp + best


@dataclass(frozen=True)
class ClipEvents:
    """Key events of a one-shot clip, in (fractional) frames."""

    kind: str  # "jump" or "peak"
    times: tuple  # increasing frame times, excluding the first and last frame


def detect_events(local, *, model_size, clearance=0.02):
    """Key events of a non-cyclic clip from its root-local frames.

    A jump (the body's lowest point leaves the ground by more than ``clearance`` of the model
    size for at least two frames) gives take-off and landing; otherwise the peak is the frame
    where the 2% most-moving vertices are farthest from where they started.
    """
    local = np.asarray(local)
    lowest = local[:, :, 1].min(axis=1)
    ground = np.median(lowest[: max(1, min(5, len(lowest) // 4))])
    airborne = lowest > ground + clearance * model_size
    if airborne.sum() >= 2:
        first = int(np.argmax(airborne))
        after = np.flatnonzero(~airborne[first:])
        if len(after):
            last = first + int(after[0])
            threshold = ground + clearance * model_size

            def crossing(k0, k1):  # linear interpolation of the threshold crossing between frames
                a, b = lowest[k0], lowest[k1]
                return k0 + (threshold - a) / (b - a) if b != a else float(k0)

            take_off = crossing(first - 1, first) if first > 0 else float(first)
            landing = crossing(last - 1, last)
            if 0 < take_off < landing < len(local) - 1:
                return ClipEvents("jump", (float(take_off), float(landing)))
    displacement = np.linalg.norm(local - local[:1], axis=2)
    movers = np.argsort(displacement.max(axis=0))[-max(1, local.shape[1] // 50):]
    reach = displacement[:, movers].mean(axis=1)
    plateau = np.flatnonzero(reach >= 0.98 * reach.max())  # a held pose: take its middle
    peak = float(np.clip(0.5 * (plateau[0] + plateau[-1]), 1, len(local) - 2))
    return ClipEvents("peak", (peak,))


def piecewise_warp(events, frames, common):
    """Source frame times for common phases: events mapped onto ``common`` event phases.

    Parameters
    ----------
    events : sequence of float     the source's event frame times
    frames : int                   the source's frame count
    common : sequence of float     the common phases (in (0, 1)) the events go to

    Returns
    -------
    callable(phases) -> frame times
    """
    knots_phase = np.concatenate([[0.0], common, [1.0]])
    knots_time = np.concatenate([[0.0], events, [frames - 1.0]])
    return lambda phases: np.interp(phases, knots_phase, knots_time)
