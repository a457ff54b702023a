"""Task runners: where the engine's split work runs.

The slow stages are cut into independent tasks (shape histograms of chunks of frames, blocks of
the dissimilarity matrix, pieces of the similarity tree, decompositions of chunks of source
frames). A function that accepts ``runner=`` hands its tasks to that runner instead of running
its own loop; the tasks are module-level functions of plain arguments, so a runner may run them
in this process (:class:`SerialRunner`) or ship them to other machines (the server's
``server.jobs.dask_runner.DaskRunner``; :class:`ProcessRunner` runs ``map``'s tasks in local
processes). Every task's result depends only on its arguments, so
every runner gives the same result, bit for bit, whatever the order in which the tasks run or
finish: results are placed by task index, never by arrival, and a task's set-up object
(:class:`Rebuilt`) is its thread's own, never used by two tasks at the same time.

A runner has two methods:

``map(function, jobs, *, shared=None, sizes=None, progress=None)``
    ``[function(shared, job) for job in jobs]``, in any order or at the same time; results in
    the order of ``jobs``. ``shared`` is sent once per machine rather than once per job.
``tree(function, jobs, parents, *, shared=None, sizes=None, progress=None)``
    ``results[t] = function(shared, jobs[t], results[parents[t]])`` (``None`` for a task whose
    parent is -1); ``parents[t] < t``. A task starts once its parent is done; tasks whose
    parents are done may run at the same time.

``sizes`` weigh the tasks for ``progress(done, total)``, called as tasks finish.

A long task calls :func:`checkpoint` between its steps (a frame aligned, a frame decomposed):
a runner that can learn that the work is no longer wanted (the server's Dask runner, when its
job has ended) sets a check with :func:`stop_when`, and the task then stops with
:class:`Stopped` instead of running to its end. Elsewhere ``checkpoint`` does nothing.
"""

from __future__ import annotations

import contextlib
import threading

_STOP = threading.local()


class Stopped(Exception):
    """A task was told to stop: the work it belongs to has ended and its result is not wanted."""


def checkpoint():
    """Raise :class:`Stopped` when this thread's task was told to stop (see :func:`stop_when`)."""
    check = getattr(_STOP, "check", None)
    if check is not None and check():
        raise Stopped("the work this task belongs to has ended")


@contextlib.contextmanager
def stop_when(check):
    """Within the block, :func:`checkpoint` on this thread raises when ``check()`` is true."""
    before = getattr(_STOP, "check", None)
    _STOP.check = check
    try:
        yield
    finally:
        _STOP.check = before


class SerialRunner:
    """Runs every task here, one after the other (the reference for every other runner)."""

    def map(self, function, jobs, *, shared=None, sizes=None, progress=None):
        sizes = list(sizes) if sizes is not None else [1] * len(jobs)
        total, done, results = int(sum(sizes)), 0, []
        for job, size in zip(jobs, sizes, strict=True):
            results.append(function(shared, job))
            done += size
            if progress is not None:
                progress(done, total)
        return results

    def tree(self, function, jobs, parents, *, shared=None, sizes=None, progress=None):
        check_parents(parents)
        sizes = list(sizes) if sizes is not None else [1] * len(jobs)
        total, done = int(sum(sizes)), 0
        results = [None] * len(jobs)
        for t, job in enumerate(jobs):
            results[t] = function(shared, job, None if parents[t] < 0 else results[parents[t]])
            done += sizes[t]
            if progress is not None:
                progress(done, total)
        return results


class ProcessRunner:
    """Runs tasks in ``workers`` processes of this machine (``map`` only; use it as a context
    manager, which stops the processes at the end).

    The processes start with the first ``map`` and are kept for the next calls that pass the
    same ``shared`` object (a repair's waves: the aligner is set up once per process, not once
    per wave); another ``shared`` starts them again with it. ``shared`` reaches each process
    once, when it starts. A call of one job, or a runner of one worker, runs here.
    """

    def __init__(self, workers):
        self.workers = max(1, int(workers))
        self._pool, self._shared = None, None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool, self._shared = None, None

    def map(self, function, jobs, *, shared=None, sizes=None, progress=None):
        if self.workers <= 1 or len(jobs) <= 1:
            return SerialRunner().map(function, jobs, shared=shared, sizes=sizes, progress=progress)
        import multiprocessing
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

        if self._pool is None or self._shared is not shared:
            self.close()
            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("forkserver"),
                                             initializer=_hold_shared, initargs=(shared,))
            self._shared = shared
        sizes = list(sizes) if sizes is not None else [1] * len(jobs)
        total, done = int(sum(sizes)), 0
        futures = {self._pool.submit(_with_shared, function, job): k for k, job in enumerate(jobs)}
        results, pending = [None] * len(jobs), set(futures)
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                k = futures[future]
                results[k] = future.result()   # placed by index, never by arrival
                done += sizes[k]
                if progress is not None:
                    progress(done, total)
        return results


_HELD = {}


def _hold_shared(shared):
    """Process-pool initializer of :class:`ProcessRunner`: keep the calls' ``shared``."""
    _HELD["shared"] = shared


def _with_shared(function, job):
    return function(_HELD.get("shared"), job)


def check_parents(parents):
    """Every task's parent comes before it (or is -1)."""
    for t, p in enumerate(parents):
        if not -1 <= int(p) < t:
            raise ValueError(f"task {t} has parent {int(p)}: a parent must be an earlier task or -1")


class Rebuilt:
    """Something expensive to set up that travels as its inputs and is set up once where it lands.

    ``Rebuilt(make, state)``: ``value`` is ``make(*state)``, built on first use by each thread
    that asks for it (a runner keeps one unpickled copy per worker and hands it to every task
    there; a worker with several threads, or a cluster whose workers are threads of one process,
    runs tasks at the same time). A task may therefore use and change the value (a solver's
    scratch buffers) without another task seeing it: a value shared between threads made the
    Dask build's ``nl_quaternions`` differ from the local run's now and then, two decompositions
    writing one solver's right-hand side at once. ``value=`` is the value of the thread that
    makes the Rebuilt (the caller's own, so a serial runner sets nothing up again). Pickling
    sends ``make`` and ``state`` only, never a built object.
    """

    def __init__(self, make, state, value=None):
        self.make, self.state = make, tuple(state)
        self._local = threading.local()
        if value is not None:
            self._local.value = value

    @property
    def value(self):
        value = getattr(self._local, "value", None)
        if value is None:
            value = self._local.value = self.make(*self.state)
        return value

    def __reduce__(self):
        return (Rebuilt, (self.make, self.state))


def shared_value(shared):
    """The object a task works with: ``shared.value`` for a :class:`Rebuilt`, else ``shared``."""
    return shared.value if isinstance(shared, Rebuilt) else shared


__all__ = ["ProcessRunner", "Rebuilt", "SerialRunner", "check_parents", "shared_value"]
