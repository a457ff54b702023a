"""`morphspace eval-align`'s scores: one method's alignment against the ground truth (the report's
record: overall, per sequence, per part of a studio body, the confidence against the true error)
and frames.csv's rows."""

from __future__ import annotations

import numpy as np

from engine.align import error_summary, score_alignment
from engine.align.breakdown import error_breakdown
from engine.align.evaluation import part_errors, part_labels
from engine.align.repair import TRUSTED

def score_method(method, aligned_vertices, root, root_vertices, truth, faces, size, lengths, names, *, residual=None,
                 residual_max=None, seconds=None, retried=None, cpu_seconds=None, confidence=None, repaired=None,
                 part_counts=None, depth=None, pulled=None, frame_labels=None):
    """One method's report record (``tree`` or ``sequential``: its errors overall, per sequence and per
    part, fit, times, confidence against the true error, breakdown) and every frame's per-vertex errors."""
    errors, summary = score_alignment(aligned_vertices, root, root_vertices, truth, faces, size)
    frames = len(aligned_vertices)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    per_sequence = {}
    for name, start, n in zip(names, starts, lengths):
        # all frames but the root, as the summary (a sequence of the root alone: the root)
        picked = [f for f in range(start, start + n) if f != root] or [root]
        per_sequence[name] = {k: round(v, 3) for k, v in error_summary(errors[picked], size).items()}
    record = {"method": method, "frames": int(frames), **{k: round(v, 4) for k, v in summary.items()},
              "per_sequence": per_sequence}
    if part_counts:  # a studio body: the body and each garment apart
        record["per_part"] = part_errors(errors, root, root_vertices, truth, faces, part_counts, size)
    if residual is not None:
        record["residual_mean_mm"] = round(1000 * float(np.mean(residual)), 3)
        record["residual_max_mm"] = round(1000 * float(np.max(residual_max)), 2)
        record["residual_mean_pct"] = round(100 * float(np.mean(residual)) / size, 4)
        record["residual_max_pct"] = round(100 * float(np.max(residual_max)) / size, 3)
    if seconds is not None:
        record["seconds_per_frame"] = round(float(np.sum(seconds)) / max(frames - 1, 1), 3)
    if cpu_seconds is not None:
        record["cpu_seconds_per_frame"] = round(float(np.sum(cpu_seconds)) / max(frames - 1, 1), 3)
    if retried is not None:
        record["retried_frames"] = int(np.sum(retried))
    if pulled is not None:  # frames whose kept alignment pulled a limb onto what nothing covered
        record["pulled_frames"] = int(np.sum(np.asarray(pulled) > 0))
    frame_mean = errors.mean(axis=1)
    if confidence is not None:
        record["repaired_frames"] = int(np.sum(repaired))
        record["flagged_frames"] = int(np.sum(confidence < TRUSTED))
        # does the confidence find the bad frames? frames over 3% mean error, and how many are flagged
        bad = frame_mean > 0.03 * size
        record["frames_over_3pct"] = int(bad.sum())
        record["frames_over_3pct_flagged"] = int(np.sum(bad & (confidence < TRUSTED)))
    record["worst_frame_mean_mm"] = round(1000 * float(frame_mean.max()), 2)
    record["worst_frame_mean_pct"] = round(100 * float(frame_mean.max()) / size, 3)
    if len(errors) > 1:  # where the error lies (engine.align.breakdown)
        labels = names_of_parts = None
        if part_counts:
            labels = part_labels(root_vertices, truth[root], faces, part_counts)
            names_of_parts = list(part_counts)
        breakdown = error_breakdown(errors, root, size, labels=labels, names=names_of_parts, depth=depth,
                                    confidence=confidence, trusted=TRUSTED)
        breakdown.pop("mean_pct")
        breakdown.pop("p95_pct")
        if frame_labels is not None:  # the global index and the capture's own SEQUENCE:FRAME, as frames.csv's
            for entry in breakdown["worst_frames"]:
                entry["label"] = frame_labels[entry["frame"]]
        record["breakdown"] = breakdown
    return record, errors


# the pictures a run may write
PICTURES = ("aligned_pattern.png", "aligned_pattern_sequential.png", "similarity.png", "tree.png")
FRAME_COLUMNS = ("method", "sequence", "frame", "mean_pct", "p95_pct", "max_pct", "depth", "parent", "confidence",
                 "flagged", "repaired")


def csv_rows(method, errors, size, names, picks, *, depth=None, parent=None, confidence=None, repaired=None):
    """One row per aligned frame (``FRAME_COLUMNS``): its sequence and frame number in the capture
    (``picks``: the frames of each sequence that were aligned), its error's mean, 95th percentile
    and max in % of the model size, its depth in the tree, the frame it was finally aligned from
    (``sequence:frame``; empty for the root), its confidence, whether that is flagged (below
    ``TRUSTED``) and whether the repair aligned it again. Unknown values are empty."""
    frame_errors = np.asarray(errors) / size * 100.0
    labels = [(name, int(f)) for name, pick in zip(names, picks) for f in pick]

    def cell(values, k, text):
        return "" if values is None else text(values[k])
    rows = []
    for k, (name, frame) in enumerate(labels):
        e = frame_errors[k]
        up = None if parent is None or parent[k] < 0 else labels[int(parent[k])]
        rows.append([method, name, frame, f"{e.mean():.4f}", f"{np.percentile(e, 95):.4f}", f"{e.max():.4f}",
                     cell(depth, k, lambda v: str(int(v))), "" if up is None else f"{up[0]}:{up[1]}",
                     cell(confidence, k, lambda v: f"{float(v):.4f}"),
                     cell(confidence, k, lambda v: str(int(float(v) < TRUSTED))),
                     cell(repaired, k, lambda v: str(int(bool(v))))])
    return rows


def kept_frame_labels(names, picks):
    """``SEQUENCE:FRAME`` (the capture's own frame numbering, as frames.csv's) of every frame
    aligned, in the global order."""
    return [f"{name}:{int(f)}" for name, pick in zip(names, picks) for f in pick]


__all__ = ["FRAME_COLUMNS", "PICTURES", "csv_rows", "kept_frame_labels", "score_method"]
