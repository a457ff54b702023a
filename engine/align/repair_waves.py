"""The repair's alignments run in waves (:func:`engine.align.repair.repair_alignment`).

A phase of the repair aligns each of its frames from the sources its plan names. Through a task
runner the alignments go out in waves: every remaining frame's alignments as the frames stand
now, all at once, then the frames applied in order while the sources the serial pass would pick
were aligned; in this process (no runner), one frame at a time. Either way the same result.
"""

from __future__ import annotations

from engine.align.matching import TargetSurface


class SerialRunner:
    """``runner.map`` in this process, one task after another (the repair without a runner)."""

    def __init__(self, aligner):
        self.aligner = aligner

    def map(self, fn, jobs, *, shared=None, sizes=None, progress=None):
        return [fn(self.aligner, job) for job in jobs]


def run_phase(frames, phase, plan, job, apply, runner, shared, versions, spent, done, total, progress):
    """Repair ``frames`` in order from ``plan(frame, spent, phase)``'s sources through ``runner``,
    in waves: every remaining frame's alignments as the frames stand now, all at once, then the
    frames applied in order while the sources the serial pass would pick were aligned (a frame
    repaired in this wave may change a later frame's sources: that one waits for the next wave).
    One frame a wave in this process (the serial pass itself). Returns (spent, done)."""
    serial = isinstance(runner, SerialRunner)
    found, k = {}, 0
    while k < len(frames):
        wanted, planned = {}, spent
        for frame in frames[k:k + 1] if serial else frames[k:]:
            sources = plan(frame, planned, phase)
            planned += len(sources)
            missing = [s for s in sources if (frame, s, versions.get(s, 0)) not in found]
            if missing:
                wanted[frame] = missing
        jobs = [job(f, sources) for f, sources in wanted.items()]
        # during a wave the bar moves with its alignments (a frame's share of them), so a wave of
        # every flagged frame at once (root first) does not sit at 0 for its whole length
        wave = None if progress is None else (
            lambda d, t, base=done, n=len(jobs): progress(base + (n * d) // max(t, 1), total))
        outs = runner.map(repair_task, jobs, shared=shared, sizes=[len(j[1]) for j in jobs], progress=wave)
        for (frame, sources), results in zip(wanted.items(), outs, strict=True):
            found.update({(frame, s, versions.get(s, 0)): r for s, r in zip(sources, results, strict=True)})
        while k < len(frames):
            frame = frames[k]
            sources = plan(frame, spent, phase)
            keys = [(frame, s, versions.get(s, 0)) for s in sources]
            if any(key not in found for key in keys):
                break
            spent += len(sources)
            apply(frame, sources, [found.pop(key) for key in keys])
            k += 1
            done += 1
            if progress is not None:
                progress(done, total)
    return spent, done


def forward_only(progress):
    """``progress`` called only when ``done`` grows (or ``total`` changes), or None."""
    if progress is None:
        return None
    shown = [-1, None]

    def report(done, total):
        if done > shown[0] or total != shown[1]:
            shown[:] = [done, total]
            progress(done, total)
    return report


def repair_task(shared, job):
    """Runner task: one frame aligned from several sources. ``job`` is ((V, F, colors), [(pose,
    yaw hint), ...]); returns a PairAlignment per source (each with its ``colour_distance``:
    NaN without colours)."""
    from engine.tasks import shared_value

    aligner = shared_value(shared)
    (V, F, C), starts = job
    target = TargetSurface(V, F, C)
    from engine.tasks import checkpoint

    results = []
    for pose, hint in starts:
        checkpoint()  # a task stops here when its runner says the work has ended
        results.append(aligner.align(pose, target, yaw=hint))
    return results


__all__ = ["SerialRunner", "forward_only", "repair_task", "run_phase"]
