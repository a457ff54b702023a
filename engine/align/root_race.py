"""The root raced: the two best candidates of the root trial each align the capture, the more
confident alignment wins.

The trial (:mod:`engine.align.root_trial`) judges a candidate root by a few probe frames aligned
straight from it. That is cheap, and it ranks candidates poorly: on the studio's martial-arts take
sampled one frame in 9, the probes' true error itself (not just their badness, which follows it
closely) ranked eight roots against the error of their whole alignments at a rank correlation of
0.45, because a whole alignment reaches every frame along the tree, not straight from the root.
The whole alignment's own mean confidence ranked the same eight roots almost exactly. So the
trial's ``RACE_FINALISTS`` best candidates each align the capture along their own tree (with
repair, as the final run does) and the alignment with the higher mean confidence over the frames
other than its root is kept.

A capture of at most ``2 * RACE_FRAMES`` frames is raced whole, and the winner's alignment is
the result: the race costs one more whole alignment (racing a subset and then aligning the whole
capture again would cost as much or more). A longer capture races an evenly spaced subset of
``RACE_FRAMES`` frames (the finalists among them), and the winner then aligns the whole capture:
a fixed cost, like the trial's. On the studio dance's first 120 frames, a race of 64 frames each
kept the trial's root, as the whole race would have.
"""

from __future__ import annotations

import numpy as np

RACE_FINALISTS = 2   # the trial's best candidates that align the capture
RACE_FRAMES = 64     # a capture of more than twice this races an evenly spaced subset of this many frames
TRACKED_SHARE = 0.8  # a tree with at least this share of its steps between neighbours in time is a tracked take:
                     # "auto" does not race it when it is one sequence
                     # (dense takes 0.90-1.00, one frame in 9 or 14 of one: 0.05-0.16)


def finalists(trial, count=RACE_FINALISTS):
    """The ``count`` candidates of a trial report with the least mean badness, best first (ties:
    the earlier candidate, so the spread's choice); never one whose badness is not finite (a
    frame that could not be filled with tetrahedra), so fewer when those are all that is left."""
    mean = np.asarray(trial["mean"], dtype=np.float64)
    order = [k for k in np.argsort(mean, kind="stable") if np.isfinite(mean[k])][:int(count)]
    return [int(trial["candidates"][k]) for k in order]


def race_frames(n, keep, limit=None):
    """The frames a race aligns: all ``n`` when ``n <= 2 * limit`` (two finalists aligning
    ``limit`` frames each, then the winner all ``n``, would cost as much as racing all of them),
    else ``limit`` of them: every frame of ``keep`` and the rest spread evenly as the trial's
    probes are (:func:`engine.align.root_trial.trial_probes`). ``limit`` defaults to
    ``RACE_FRAMES`` as it is when called. Sorted frame indices."""
    from engine.align.root_trial import trial_probes

    limit = RACE_FRAMES if limit is None else int(limit)
    keep = sorted({int(k) for k in keep})
    if n <= 2 * limit:
        return list(range(n))
    return sorted(keep + trial_probes(n, keep, max(limit - len(keep), 0)))


def neighbour_share(parent, lengths):
    """The share of a tree's steps that join frames next to each other in one sequence.

    A densely captured take aligns as a chain (docs/evaluation.md, "A long take is a chain"):
    every frame from its neighbour in time, and there the race buys nothing over the trial (on the
    studio's dense dance and strikes slices it kept the trial's root, for 1.3-2.6 CPU s a frame
    more). Frames far apart in time (a few of a long take re-meshed) make a tree of jumps between
    poses, where the race has overturned the trial most.

    Parameters
    ----------
    parent : (N,) int array    each frame's parent in the tree, -1 for the root
    lengths : (S,) int array or None   frames per sequence (global indices run through them in
                                       order); None: one sequence

    Returns
    -------
    float in [0, 1]   (0 for a tree of one frame)
    """
    parent = np.asarray(parent, dtype=np.int64)
    n = len(parent)
    sequence = np.repeat(np.arange(len(lengths)), lengths) if lengths is not None else np.zeros(n, dtype=np.int64)
    child = np.flatnonzero(parent >= 0)
    if len(child) == 0:
        return 0.0
    near = (np.abs(child - parent[child]) == 1) & (sequence[child] == sequence[parent[child]])
    return float(near.mean())


def no_trial_reason(frames):
    """Why no trial (or race) runs on a capture of ``frames`` frames, or None when one may: fewer
    than ``TRIAL_MIN_FRAMES``. One line for a summary; the spread's choice (``apart``) stands."""
    from engine.align.root_trial import TRIAL_MIN_FRAMES

    if frames < TRIAL_MIN_FRAMES:
        return f"the spread's choice, `apart`: no trial or race on fewer than {TRIAL_MIN_FRAMES} frames"
    return None


def no_race_reason(parent, lengths, root_choice):
    """Why ``root_choice`` "auto" does not race the trial's finalists on this tree, or None when it
    does (and always None for "race"): one densely tracked take, :func:`neighbour_share` at least
    ``TRACKED_SHARE``, where the trial's choice stands. One line for a summary.

    A capture of several sequences is always raced, however densely each was tracked: the root
    decides which sequences lie near it, and on the studio's twelve the race overturned the trial
    (its choice, dance:425, aligned 64 frames at a mean confidence of 0.247 against jump:59's 0.356;
    docs/evaluation.md, sessions 30 and 32). Only single takes were measured to gain nothing."""
    if root_choice != "auto":
        return None
    if lengths is not None and np.count_nonzero(np.asarray(lengths)) > 1:
        return None
    share = neighbour_share(parent, lengths)
    if share >= TRACKED_SHARE:
        return (f"the trial's choice: no race on a densely tracked take ({100 * share:.0f}% of the tree's steps join "
                "neighbours in time; `race` races it anyway)")
    return None


def race_score(confidence, root):
    """The mean confidence of the frames other than ``root`` (higher is better)."""
    confidence = np.asarray(confidence, dtype=np.float64)
    others = np.ones(len(confidence), dtype=bool)
    others[int(root)] = False
    return float(confidence[others].mean()) if others.any() else 1.0


_RACE = {}


def race_in_processes(sub, lengths, similar, trees, tets, settings, progress):
    """Each finalist aligns ``sub`` along its tree (:func:`engine.align.captures._align_from`) in
    its own process (``settings["workers"]`` at most), with one worker each; the "race" stage's
    progress counts the frames of all of them."""
    import multiprocessing
    import queue as queue_module
    from concurrent.futures import ProcessPoolExecutor, wait

    context = multiprocessing.get_context("forkserver")
    ticks = context.Queue()
    shared = (sub, lengths, similar, dict(settings, workers=1))
    frames, total = {}, len(trees) * len(sub)
    with ProcessPoolExecutor(max_workers=min(int(settings["workers"]), len(trees)), mp_context=context,
                             initializer=_race_init, initargs=(shared, ticks)) as pool:
        futures = [pool.submit(_race_entry, (k, tree, t)) for k, (tree, t) in enumerate(zip(trees, tets))]
        pending = set(futures)
        while pending:
            _, pending = wait(pending, timeout=0.5)
            while True:
                try:
                    k, done = ticks.get_nowait()
                except queue_module.Empty:
                    break
                frames[k] = done
                if progress is not None:
                    progress("race", sum(frames.values()), total)
        results = [future.result() for future in futures]
    if progress is not None:
        progress("race", total, total)  # ticks a process sent after its result came back
    return results


def _race_init(shared, ticks):
    """Process-pool initializer of :func:`race_in_processes`."""
    _RACE["shared"], _RACE["ticks"] = shared, ticks


def _race_entry(job):
    """One finalist's alignment in a process of the race: ``job`` is (its index, tree, tets)."""
    from engine.align.captures import _align_from

    k, tree, tets = job
    sub, lengths, similar, settings = _RACE["shared"]
    ticks = _RACE["ticks"]

    def report(stage, done, _):
        if stage == "align":
            ticks.put((k, done))
    return _align_from(sub, lengths, similar, tree, "tree", tets=tets, progress=report, **settings)


def sub_similarity(similarity, frames):
    """A :class:`engine.align.similarity.ShapeSimilarity` of ``frames`` only (one sequence: the
    frames are not neighbours in time)."""
    from dataclasses import replace

    pick = np.ix_(frames, frames)
    return replace(similarity, histograms=similarity.histograms[frames], raw=similarity.raw[pick],
                   dissimilarity=similarity.dissimilarity[pick], yaw=similarity.yaw[pick],
                   lengths=np.array([len(frames)]))


__all__ = ["RACE_FINALISTS", "RACE_FRAMES", "TRACKED_SHARE", "finalists", "neighbour_share", "no_race_reason",
           "no_trial_reason", "race_frames", "race_in_processes", "race_score", "sub_similarity"]
