"""What an alignment's error is made of: per part, per frame, per tree depth, and whether the
per-frame confidence finds the bad frames (issue 12).

``error_breakdown(errors, root, model_size, labels=..., depth=..., confidence=...)`` takes the
per-frame, per-vertex correspondence errors of :func:`engine.align.evaluation.score_alignment`
and says where the 95th percentile comes from: which part of the body (a studio body's skirt,
each sleeve) holds how much of the error tail (the vertex-frames above the overall 95th
percentile), what the percentile would be without each part, which frames are worst, how the
error grows with the depth in the tree, and the precision and recall of the confidence's flag
against frames whose mean error is truly over a threshold.
"""

from __future__ import annotations

import numpy as np

from engine.align.evaluation import part_labels

DEPTH_BINS = (1, 2, 5, 17, 65)   # depth ranges [1], [2, 4], [5, 16], [17, 64], [65, ...)
BAD_FRAME_PCT = (2.0, 3.0)       # a frame is bad when its mean error is over this % of the model size


def flag_calibration(frame_mean_pct, flagged, thresholds=BAD_FRAME_PCT):
    """Precision and recall of a per-frame flag against frames truly over each threshold.

    Parameters
    ----------
    frame_mean_pct : (N,) float array   each frame's mean error, % of the model size
    flagged : (N,) bool array
    thresholds : sequence of float      % of the model size

    Returns
    -------
    dict "over_<t>pct" -> {bad, flagged, flagged_bad, precision, recall}
        precision: flagged frames that are bad (None with nothing flagged); recall: bad frames
        that are flagged (None with no bad frame)
    """
    frame_mean_pct = np.asarray(frame_mean_pct, dtype=np.float64)
    flagged = np.asarray(flagged, dtype=bool)
    out = {}
    for t in thresholds:
        bad = frame_mean_pct > t
        hit = int(np.sum(bad & flagged))
        out[f"over_{t:g}pct"] = {
            "bad": int(bad.sum()), "flagged": int(flagged.sum()), "flagged_bad": hit,
            "precision": round(hit / int(flagged.sum()), 3) if flagged.any() else None,
            "recall": round(hit / int(bad.sum()), 3) if bad.any() else None}
    return out


def error_breakdown(errors, root, model_size, *, labels=None, names=None, depth=None, confidence=None,
                    trusted=0.5, worst=5):
    """Where the error of an alignment lies.

    Parameters
    ----------
    errors : (N, n) float array       per frame and root vertex (metres), as ``score_alignment``
    root : int                        the root frame (left out of every figure)
    model_size : float
    labels : (n,) int array or None   each vertex's part (:func:`part_labels`)
    names : list of str or None       the parts' names (default "part0", ...)
    depth : (N,) int array or None    each frame's depth in the tree it was aligned along
    confidence : (N,) float array or None   per-frame confidence; below ``trusted`` is flagged
    worst : int                       how many of the worst frames to list

    Returns
    -------
    dict with
        p95_pct : the overall 95th percentile (% of the model size)
        per_part : name -> {vertices, share_of_vertices, mean_pct, p95_pct, share_of_tail,
                   p95_without_pct}: ``share_of_tail`` is the fraction of the vertex-frames over the
                   overall 95th percentile that lie on the part; ``p95_without_pct`` the 95th
                   percentile of the other parts
        worst_frames : [{frame, mean_pct, p95_pct, depth, confidence}] worst frame means first
        per_depth : [{depths, frames, mean_pct, p95_pct}]
        confidence : :func:`flag_calibration` of ``confidence < trusted`` (with ``confidence``)
    """
    errors = np.asarray(errors, dtype=np.float64)
    scale = 100.0 / float(model_size)
    others = np.arange(len(errors)) != int(root)
    E = errors[others] * scale
    if E.size == 0:
        raise ValueError("no frames besides the root")
    p95 = float(np.percentile(E, 95))
    out = {"p95_pct": round(p95, 3), "mean_pct": round(float(E.mean()), 3)}
    if labels is not None:
        labels = np.asarray(labels)
        names = list(names) if names is not None else [f"part{k}" for k in range(int(labels.max()) + 1)]
        tail = E > p95
        tail_total = max(int(tail.sum()), 1)
        parts = {}
        for k, name in enumerate(names):
            mine = labels == k
            if not mine.any():
                continue
            rest = E[:, ~mine]
            parts[name] = {"vertices": int(mine.sum()), "share_of_vertices": round(float(mine.mean()), 3),
                           "mean_pct": round(float(E[:, mine].mean()), 3),
                           "p95_pct": round(float(np.percentile(E[:, mine], 95)), 3),
                           "share_of_tail": round(float(tail[:, mine].sum()) / tail_total, 3),
                           "p95_without_pct": round(float(np.percentile(rest, 95)), 3) if rest.size else None}
        out["per_part"] = parts
    frame_mean = errors.mean(axis=1) * scale
    frame_p95 = np.percentile(errors, 95, axis=1) * scale
    frames = np.flatnonzero(others)
    order = frames[np.argsort(-frame_mean[frames], kind="stable")][:worst]
    out["worst_frames"] = [{"frame": int(f), "mean_pct": round(float(frame_mean[f]), 3),
                            "p95_pct": round(float(frame_p95[f]), 3),
                            **({"depth": int(depth[f])} if depth is not None else {}),
                            **({"confidence": round(float(confidence[f]), 3)} if confidence is not None else {})}
                           for f in order]
    if depth is not None:
        depth = np.asarray(depth)
        bins = []
        edges = list(DEPTH_BINS) + [np.inf]
        for lo, hi in zip(edges[:-1], edges[1:]):
            pick = others & (depth >= lo) & (depth < hi)
            if pick.any():
                label = f"{lo}" if hi == lo + 1 else (f"{lo}+" if not np.isfinite(hi) else f"{lo}-{int(hi) - 1}")
                bins.append({"depths": label, "frames": int(pick.sum()),
                             "mean_pct": round(float(errors[pick].mean() * scale), 3),
                             "p95_pct": round(float(np.percentile(errors[pick], 95) * scale), 3)})
        out["per_depth"] = bins
    if confidence is not None:
        flagged = np.asarray(confidence) < trusted
        out["confidence"] = flag_calibration(frame_mean[others], flagged[others])
    return out


def tree_depth(parent, root):
    """Edges from the root to every frame along ``parent`` (-1 or the root's own index at the root)."""
    parent = np.asarray(parent)
    depth = np.full(len(parent), -1, dtype=np.int64)
    depth[int(root)] = 0
    for _ in range(len(parent)):
        todo = depth < 0
        if not todo.any():
            break
        known = todo & (depth[np.maximum(parent, 0)] >= 0) & (parent >= 0)
        depth[known] = depth[parent[known]] + 1
    return depth


__all__ = ["BAD_FRAME_PCT", "DEPTH_BINS", "error_breakdown", "flag_calibration", "part_labels", "tree_depth"]
