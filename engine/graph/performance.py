"""The graph against the generator's true continuous performance (walk, stop, jump, start, walk).

``engine.synthetic.transitions.performance`` makes the motion a motion graph imitates, in one
piece and with ground truth. ``performance_requests`` turns its events into the requests that make
a graph play the same script (stand when the true walk starts to stop, jump when the true jump
starts, walk again when the true start begins); ``performance_distance`` compares the frames
played (``evaluate.play_requests``) with the true ones:

- time-aligned: per frame, the mean per-vertex distance (world coordinates, so the path counts)
  to the true frame at the same time;
- with timing slack: per frame, the least such distance to a true frame within ``window`` seconds
  (the graph may leave a little earlier or later than the true performance did);
- the pose alone: the same with both frames moved so that their roots' horizontal positions
  coincide (these motions go straight along +Z, so no heading is removed);
- where the character ends: the distance between the final root positions.
"""

from __future__ import annotations

import numpy as np

from engine.graph.evaluate import Request


def performance_requests(events, fps, *, speed, jump_params, walk="walk", stand="stand", jump="jump",
                         walk_params=None):
    """[Request]: stand at ``stop_frame``, jump at ``jump_frame`` (at ``jump_params``), walk at
    ``start_frame`` (at ``speed``; ``walk_params`` adds others, e.g. turn_rate 0)."""
    again = {"speed": float(speed), **(walk_params or {})}
    return [Request(events["stop_frame"] / fps, stand, {}), Request(events["jump_frame"] / fps, jump, dict(jump_params)),
            Request(events["start_frame"] / fps, walk, again)]


def performance_distance(vertices, truth, *, fps, window=0.5, root=None, true_root=None):
    """Distances between played frames and the true performance's.

    Parameters
    ----------
    vertices : (F, n, 3) float array   the frames played, world coordinates
    truth : (T, n, 3) float array      the true performance's frames (same mesh structure)
    fps : float                        both at this rate, frame 0 at time 0
    window : float                     seconds of timing slack
    root, true_root : (F, 3), (T, 3) float arrays or None   root paths (for the end offset)

    Returns
    -------
    dict: ``aligned_m`` (F',) and ``slack_m`` (F',) per-frame mean per-vertex distances (m) over the
    frames both have; with the roots given also ``pose_aligned_m``, ``pose_slack_m`` (the roots'
    horizontal positions made to coincide) and ``end_offset_m`` (the final roots' horizontal
    distance; else None)
    """
    V = np.asarray(vertices, dtype=np.float32)
    T = np.asarray(truth, dtype=np.float32)
    count = min(len(V), len(T))
    reach = max(0, int(round(window * fps)))
    out = {"end_offset_m": None}
    variants = [("", V, T)]
    if root is not None and true_root is not None:
        flat = np.array([1.0, 0.0, 1.0], dtype=np.float32)
        variants.append(("pose_", V - (np.asarray(root, dtype=np.float32) * flat)[:, None],
                         T - (np.asarray(true_root, dtype=np.float32) * flat)[:, None]))
        a, b = np.asarray(root)[count - 1], np.asarray(true_root)[count - 1]
        out["end_offset_m"] = float(np.hypot(a[0] - b[0], a[2] - b[2]))
    for prefix, A, B in variants:
        aligned, slack = np.empty(count), np.empty(count)
        for k in range(count):
            lo, hi = max(0, k - reach), min(len(B), k + reach + 1)
            d = np.linalg.norm(B[lo:hi] - A[k][None], axis=2).mean(axis=1)
            aligned[k], slack[k] = d[k - lo], d.min()
        out[f"{prefix}aligned_m"], out[f"{prefix}slack_m"] = aligned, slack
    return out


def summarise_distance(distance, model_size):
    """Medians and tails (mm and % of the model size) of ``performance_distance``."""
    def stats(values):
        mm = values * 1e3
        return {"p50_mm": float(np.median(mm)), "p95_mm": float(np.percentile(mm, 95)), "max_mm": float(mm.max()),
                "p50_pct": float(100 * np.median(values) / model_size),
                "p95_pct": float(100 * np.percentile(values, 95) / model_size)}
    out = {key[:-2]: stats(distance[key]) for key in ("aligned_m", "slack_m", "pose_aligned_m", "pose_slack_m")
           if key in distance}
    return {**out, "end_offset_m": distance["end_offset_m"], "frames": int(len(distance["aligned_m"]))}
