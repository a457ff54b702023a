"""Aligning one piece of the similarity tree, in this process or in a worker process.

A piece is a connected part of the tree (:func:`engine.align.propagation.partition_tree`). Its
frames are aligned breadth first, each from its parent's aligned pose; a frame whose alignment
scores poorly, or whose step lost the root's colours (:func:`_colour_slipped`), is aligned again
from other already aligned frames of the piece, the most similar first, and the best result is
kept (:func:`better_alignment`). A worker process builds its aligner once
(:func:`init_worker`) and then aligns pieces (:func:`run_piece`).
"""

from __future__ import annotations

import time

import numpy as np

from engine.align.matching import TargetSurface
from engine.align.options import better_alignment
from engine.align.pairwise import PairAlignment, PairwiseAligner
from engine.tasks import checkpoint


_WORKER = {}
COLOUR_RETRY = 2.0  # colour disagreement (in units of the root's floor) beyond which a frame ...
COLOUR_STEP = 0.5   # ... that disagrees this much more than its parent is aligned again from other frames
RETRY_HISTORY = 10  # frames aligned before retries start (their median quality sets the retry limit)


def init_worker(state, ticks):
    """Process-pool initializer: build the aligner once per worker; ``ticks`` counts frames."""
    V, F, colors, tets, options, seed = state
    _WORKER["aligner"] = PairwiseAligner(V, F, colors, tets=tets, options=options, seed=seed)
    _WORKER["ticks"] = ticks


def run_piece(job):
    """Process-pool task: :func:`align_piece` with the worker's aligner, counting frames as they finish."""
    ticks = _WORKER.get("ticks")
    return align_piece(_WORKER["aligner"], job, tick=(lambda: ticks.put(1)) if ticks is not None else None)


def portable_aligner(aligner):
    """The aligner as an :class:`engine.tasks.Rebuilt`: it travels as its inputs and is built once
    per worker thread, exactly as the process pool's workers build theirs."""
    from engine.tasks import Rebuilt

    state = (aligner.V, aligner.F, aligner.colors, (aligner.V_tet, aligner.T), aligner.options, aligner.seed)
    return Rebuilt(_aligner_from_state, (state,), value=aligner)


def _aligner_from_state(state):
    V, F, colors, tets, options, seed = state
    return PairwiseAligner(V, F, colors, tets=tets, options=options, seed=seed)


def piece_task(shared, job, parent_out):
    """Runner task (:mod:`engine.tasks`, ``tree``): :func:`align_piece` of a piece that starts
    from its parent piece's output (the entry pose, and the qualities of all earlier pieces on its
    path to the root). Adds ``chain``: this piece's qualities, then its history, for its children."""
    from engine.tasks import shared_value

    if parent_out is not None:
        job = dict(job, entry_pose=parent_out["poses"][job["entry"]], history=parent_out["chain"])
    else:
        job = dict(job, entry_pose=None, history=[])
    out = align_piece(shared_value(shared), job)
    out["chain"] = out["quality"] + list(job["history"])
    return out


def align_piece(aligner, job, tick=None):
    """Align one piece of the tree: its frames in breadth-first order, from the head's parent.

    ``job`` holds: nodes (in order), parents (of each node), meshes (V, F, colors) per node,
    hints (yaw degrees per node w.r.t. its parent), entry (the head's parent index or -1),
    entry_pose (its tet pose or None), candidates (frame indices allowed as retry sources:
    the piece's frames and the entry), similarity (rows of the dissimilarity for the nodes over
    the candidates, or None), yaw_rows (same shape, yaw of node w.r.t. each candidate),
    retries, retry_factor, history (qualities from earlier pieces), and optionally momentum (per
    node, its grandparent when the three are consecutive in time, else -1) and momentum_weight:
    such a node starts from its parent's pose moved on by that share of the last step.
    """
    nodes, parents = job["nodes"], job["parents"]
    poses = {}
    if job["entry"] >= 0:
        poses[job["entry"]] = job["entry_pose"]
    candidates = np.asarray(job["candidates"])
    column = {int(c): i for i, c in enumerate(candidates)}
    aligned = np.zeros(len(candidates), dtype=bool)
    if job["entry"] >= 0:
        aligned[column[job["entry"]]] = True
    qualities = list(job["history"])
    floor = aligner.retry_floor
    colour_of = {}  # node -> its colour disagreement (this piece's frames)
    out = {"nodes": nodes, "V": [], "residual": [], "residual_max": [], "distortion": [], "tail": [], "colour": [],
           "seconds": [], "cpu_seconds": [], "parent": [], "retried": [], "pulled": [], "quality": [], "poses": {}}
    for i, node in enumerate(nodes):
        checkpoint()  # a task stops here when its runner says the work has ended
        node = int(node)
        cpu_started = time.process_time()
        if parents[i] < 0:  # the root: its own mesh
            poses[node] = aligner.V_tet.copy()
            result = PairAlignment(V=aligner.V.copy(), X=poses[node], residual=0.0, residual_max=0.0,
                                   colour_mean=aligner.colour_floor)
            p, retried = -1, False
        else:
            V, F, C = job["meshes"][i]
            target = TargetSurface(V, F, C)
            p = int(parents[i])
            start = poses[p]
            behind = job.get("momentum", [-1] * len(nodes))[i]
            if behind >= 0 and behind in poses:  # the grandparent is in this piece or is its entry
                start = poses[p] + job["momentum_weight"] * (poses[p] - poses[behind])
            result = aligner.align(start, target, yaw=job["hints"][i])
            spent = result.seconds
            limit = job["retry_factor"] * np.median(qualities) if len(qualities) >= RETRY_HISTORY else np.inf
            retried = False
            if job["similarity"] is not None and job["retries"] > 0 and (
                    result.quality > limit or _colour_slipped(result, colour_of.get(p), floor)):
                retried = True
                row = job["similarity"][i]
                usable = np.flatnonzero(aligned & (candidates != p))
                for j in usable[np.argsort(row[usable], kind="stable")][:job["retries"]]:
                    source = int(candidates[j])
                    other = aligner.align(poses[source], target, yaw=float(job["yaw_rows"][i][j]))
                    spent += other.seconds
                    if better_alignment(other, result, floor):
                        result, p = other, source
                    if result.quality <= limit and not _colour_slipped(result, colour_of.get(p), floor):
                        break
            result.seconds = spent
            poses[node] = result.X
            qualities.append(result.quality)
        colour_of[node] = result.colour_mean
        aligned[column[node]] = True
        out["V"].append(result.V.astype(np.float64))
        out["residual"].append(result.residual)
        out["residual_max"].append(result.residual_max)
        out["distortion"].append(result.distortion)
        out["tail"].append(result.distortion_tail)
        out["colour"].append(result.colour_mean)
        out["seconds"].append(result.seconds)
        out["cpu_seconds"].append(time.process_time() - cpu_started)
        out["parent"].append(p)
        out["retried"].append(retried)
        out["pulled"].append(result.pulled)
        if parents[i] >= 0:
            out["quality"].append(result.quality)
        out["poses"][node] = result.X  # every pose: the repair pass starts frames from trusted ones
        if tick is not None:
            tick()
    return out


def _colour_slipped(result, parent_colour, floor):
    """The step itself lost the root's appearance: the frame's colours disagree more than
    ``COLOUR_RETRY`` times the floor, and more than its parent's by ``COLOUR_STEP`` times it
    (a parent outside the piece: the first test alone). False without colours."""
    if not np.isfinite(floor) or not np.isfinite(result.colour_mean):
        return False
    if result.colour_mean <= COLOUR_RETRY * floor:
        return False
    return parent_colour is None or not np.isfinite(parent_colour) or \
        result.colour_mean - parent_colour > COLOUR_STEP * floor


__all__ = ["align_piece", "init_worker", "piece_task", "portable_aligner", "run_piece"]
