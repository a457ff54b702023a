"""Beyond the paper: blends of synthetic gaits against the generator's own motion at the
in-between parameters (the ground truth a capture cannot give)."""

from __future__ import annotations

import numpy as np

from engine.evaluation.table import BlendCache, _noop, weight_grid
from engine.motion_space import SourceClip, warp_cycle_onto
from engine.root_motion import turned_reference
from engine.surface import enclosed_volume
from engine.synthetic import animate, gait


def gait_truth(body, speeds, *, turn_rates=None, fps=30.0, start_phases=None):
    """The generator's true motion for weights of a space of synthetic gaits.

    Parameters
    ----------
    body : Body
    speeds : (N,) float array         each source's speed (m/s)
    turn_rates : (N,) float or None   each source's turn rate (deg/s; default straight)
    fps : float
    start_phases : (N,) float or None gait phase of each source's first cycle frame (0 = left
                                      heel strike); default 0

    Returns
    -------
    true_motion : callable(weights) -> Motion
        the gait at speed sum_i w_i v_i (turn rate likewise), starting at the weighted mean
        start phase, one cycle plus two frames long (``gait(..., cycles=1 + 2 / N)``)
    """
    speeds = np.asarray(speeds, dtype=np.float64)
    turns = np.zeros_like(speeds) if turn_rates is None else np.asarray(turn_rates, dtype=np.float64)
    starts = np.zeros_like(speeds) if start_phases is None else np.asarray(start_phases, dtype=np.float64)
    starts = (starts + 0.5) % 1.0 - 0.5  # circular mean about the heel strike

    def true_motion(weights):
        w = np.asarray(weights, dtype=np.float64)
        w = w / w.sum()
        speed, turn, start = float(w @ speeds), float(w @ turns), float(w @ starts) % 1.0
        return gait(body.skeleton, speed, turn_rate=turn, fps=fps, cycles=2.0, start_phase=start)

    return true_motion


def true_samples(space, body, motion):
    """(P, n, 3) a true cyclic motion put on the space's phase grid exactly like its sources:
    root-local, one cycle, key poses aligned to the space's first source (``warp_cycle_onto``)."""
    V = animate(body, motion)
    clip = SourceClip(name=motion.name, vertices=V, fps=motion.fps, cyclic=True,
                      frames_per_cycle=motion.frames_per_cycle)
    rest = np.asarray(space.container["rest"])
    turn = np.radians(float(space.metadata.get("heading_turn_deg", 0.0)))  # the sources' heading reference
    rest = turned_reference(rest, turn) if turn else rest
    return warp_cycle_onto(clip, np.asarray(space.faces, dtype=np.int64), rest,
                           np.asarray(space.sources[:, 0], dtype=np.float64))


def mesh_edges(F):
    """(e, 2) unique undirected edges of a triangle mesh."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return np.unique(np.sort(E, axis=1), axis=0)


def truth_errors(V, T, F, E):
    """How (P, n, 3) frames V differ from true frames T: positions (mm), edge lengths and
    enclosed volume (% of the true ones); ``E`` from ``mesh_edges(F)``."""
    e = np.linalg.norm(V - T, axis=2)
    length = np.linalg.norm(V[:, E[:, 0]] - V[:, E[:, 1]], axis=2)
    true_length = np.linalg.norm(T[:, E[:, 0]] - T[:, E[:, 1]], axis=2)
    volume, true_volume = enclosed_volume(V, F), enclosed_volume(T, F)
    return {"mean_mm": 1000.0 * float(e.mean()), "max_mm": 1000.0 * float(e.max()),
            "edge_error_percent": 100.0 * float(np.abs(length - true_length).sum() / true_length.sum()),
            "volume_error_percent": 100.0 * float(np.mean(np.abs(volume - true_volume) / true_volume))}


_RATIOS = {"ratio_mean": "mean_mm", "ratio_max": "max_mm", "ratio_edge": "edge_error_percent",
           "ratio_volume": "volume_error_percent"}


def _add_ratios(entry):
    if "linear" in entry and "nonlinear" in entry:
        for ratio, key in _RATIOS.items():
            entry[ratio] = entry["linear"][key] / max(entry["nonlinear"][key], 1e-12)


def ground_truth_comparison(space, body, true_motion_fn, weights_list=None, *,
                            methods=("linear", "hybrid", "nonlinear"), cache=None, progress=None):
    """Blends against the true motion the generator makes at the in-between parameters.

    Parameters
    ----------
    space : MotionSpace                built from synthetic cyclic captures of ``body``
    body : Body                        the generator's body (same vertices as the space)
    true_motion_fn : callable(weights) -> Motion   e.g. ``gait_truth``; at the unit weights it
                                       must reproduce the sources
    weights_list : (k, N) or None      default 0.25/0.5/0.75 (two sources) or ``weight_grid(N, 2)``
    methods : sequence of str          among ``METHODS``
    cache : BlendCache or None
    progress : callable(stage, done, total) or None

    Returns
    -------
    result : dict
        sources: per source, how well its true motion reproduces it (a check of the set-up:
        near zero) and the root offset found. rows: per weight vector, for each method over all
        phase samples: mean_mm and max_mm per-vertex distance, edge_error_percent (summed
        |edge length - true edge length| over summed true lengths) and volume_error_percent
        (mean |enclosed volume - true volume| / true volume); ratio_mean, ratio_max, ratio_edge,
        ratio_volume = linear / non-linear of each. summary: means over the rows (max for
        max_mm) and their ratios.

    Notes
    -----
    The sources sit on the phase grid in their own root frame, which may keep a horizontal
    offset (where the root was at the cycle's first frame). The offset c_i of each source is
    measured against its true motion and the target of a blend is the true motion at the blended
    parameters moved by sum_i w_i c_i, the offset of every blend of the sources.
    The true motion may differ from every blend (cadence, duty factor and stride change with
    speed in ways no blend of two gaits reproduces): positions measure that as well, while edge
    lengths and volume measure the shape alone, where linear blending's shrinking of rotating
    limbs shows.
    """
    progress = progress or _noop
    cache = cache or BlendCache(space, progress)
    N = space.n_sources
    if len(body.V) != space.n_vertices:
        raise ValueError(f"{space.name}: the body has {len(body.V)} vertices, the space {space.n_vertices}")
    if weights_list is None:
        weights_list = (np.array([[0.75, 0.25], [0.5, 0.5], [0.25, 0.75]]) if N == 2 else weight_grid(N, 2))
    W = np.asarray(weights_list, dtype=np.float64)
    F = np.asarray(space.faces, dtype=np.int64)
    E = mesh_edges(F)
    sources = np.asarray(cache.sources, dtype=np.float64)
    offsets, report_sources = [], []
    for i in range(N):
        truth = true_samples(space, body, true_motion_fn(np.eye(N)[i]))
        offset = (sources[:, i] - truth).reshape(-1, 3).mean(axis=0)
        offset[1] = 0.0
        offsets.append(offset)
        report_sources.append({"name": space.source_names[i], "offset_m": offset.tolist(),
                               **truth_errors(sources[:, i], truth + offset, F, E)})
        progress("ground truth", i + 1, N + len(W))
    offsets = np.array(offsets)
    rows = []
    for k, w in enumerate(W):
        w = w / w.sum()
        motion = true_motion_fn(w)
        target = true_samples(space, body, motion) + w @ offsets
        row = {"weights": w.tolist(),
               "params": {key: motion.params[key] for key in ("speed", "turn_rate") if key in motion.params}}
        for method in methods:
            row[method] = truth_errors(cache.blend(method, w), target, F, E)
        _add_ratios(row)
        rows.append(row)
        progress("ground truth", N + k + 1, N + len(W))
    summary = {m: {key: float(np.max([r[m][key] for r in rows]) if key == "max_mm" else
                              np.mean([r[m][key] for r in rows])) for key in rows[0][m]} for m in methods}
    _add_ratios(summary)
    return {"space": space.name, "sources": report_sources, "rows": rows, "summary": summary}
