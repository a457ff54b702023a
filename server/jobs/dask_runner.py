"""The engine's tasks (``engine.tasks``) as Dask tasks, submitted by a job's task on the cluster.

A job on Dask is one task (``server.jobs.tasks.dask_entry``): the coordinator. It reads the
inputs and calls the engine with ``runner=DaskRunner(...)``; the engine hands its split work
(histogram chunks, matrix blocks, tree pieces, source decompositions) to the runner, which
submits it to the same cluster and waits. While it waits the coordinator has seceded from its
worker's thread pool (``distributed.worker_client``), so a cluster of one single-threaded
worker runs the sub-tasks too instead of deadlocking. ``shared`` data is scattered once; the
tree's pieces are submitted together, each depending on its parent piece's future, so a piece
starts on whichever worker is free as soon as its parent is done, without a round trip through
the coordinator.

Progress comes back as tasks finish (``progress(done, total)``, weighted by ``sizes``), and from
within the running tasks, which report the ``engine.tasks.checkpoint`` calls they have passed (a
frame each, the units of ``sizes``) as events (``run_stoppable``); it goes to the job record
through the coordinator's reporter. The same checkpoints stop a task whose job run has ended. ``check()`` is called while waiting; when it
raises (the job was cancelled), the sub-tasks not yet finished are cancelled and the exception
goes on.
"""

from __future__ import annotations

import itertools

from engine.tasks import Stopped, check_parents
from server.jobs.tasks import JobCancelled, JobError

POLL = 0.25  # seconds between cancellation checks while waiting for sub-tasks
RERUNS = 2  # times a stage is run again after a lost worker took what its tasks needed


class DaskRunner:
    """Runs engine tasks on the Dask cluster the calling task runs on.

    Parameters
    ----------
    prefix : str                 task keys are ``<prefix>-<function>-<n>`` (one prefix per job
                                 run, so the dashboard shows whose tasks they are)
    check : callable() or None   raises to stop (e.g. ``Reporter.check``)
    log : callable(str) or None  a line for the job's log (e.g. ``Reporter.log``)
    reruns : int                 times a stage runs again after a lost worker took its inputs
    alive : str or None          a directory (the job run's staging directory): once it is gone,
                                 the tasks stop at their next ``engine.tasks.checkpoint`` (a
                                 running Dask task cannot be cancelled from outside)
    """

    def __init__(self, prefix, check=None, log=None, reruns=RERUNS, alive=None):
        self.prefix, self.alive = prefix, alive
        self.ticks = f"{prefix}-ticks"  # the event topic of the tasks' checkpoints (run_stoppable)
        self.check = check or (lambda: None)
        self.log = log or (lambda line: None)
        self.reruns = reruns
        self.counter = itertools.count()
        self.tasks = 0

    def map(self, function, jobs, *, shared=None, sizes=None, progress=None):
        jobs = list(jobs)

        def submit(client, shared_future):
            return [client.submit(run_stoppable, function, self.alive, self.ticks, shared_future, job,
                                  key=self._key(function), pure=False)
                    for job in client.scatter(jobs, hash=False)]

        return self._run(submit, shared, sizes, progress)

    def tree(self, function, jobs, parents, *, shared=None, sizes=None, progress=None):
        jobs = list(jobs)
        check_parents(parents)

        def submit(client, shared_future):
            futures = []
            for job, parent in zip(client.scatter(jobs, hash=False), parents, strict=True):
                futures.append(client.submit(run_stoppable, function, self.alive, self.ticks, shared_future, job,
                                             futures[parent] if parent >= 0 else None,
                                             key=self._key(function), pure=False))
            return futures

        return self._run(submit, shared, sizes, progress)

    def _run(self, submit, shared, sizes, progress):
        """Scatter, submit, wait; when a worker is lost with what the tasks needed, all of it again
        (up to ``reruns`` times: every task's result depends only on its inputs, so the stage's
        results are the same)."""
        from distributed import worker_client

        for rerun in itertools.count(1):
            with worker_client() as client:
                futures = submit(client, self._scatter(client, shared))
                try:
                    return self._gather(client, futures, sizes, progress)
                except WorkerGone as exc:
                    if rerun > self.reruns:
                        raise
                    self.log(f"{exc.loss}; running the stage's {len(futures)} tasks again "
                             f"({rerun} of at most {self.reruns})")

    def _key(self, function):
        self.tasks += 1
        return f"{self.prefix}-{function.__name__.replace('_', '-')}-{next(self.counter)}"

    @staticmethod
    def _scatter(client, shared):
        if shared is None:
            return None
        return client.scatter([shared], hash=False, broadcast=False)[0]

    def _gather(self, client, futures, sizes, progress):
        sizes = list(sizes) if sizes is not None else [1] * len(futures)
        index = {future.key: i for i, future in enumerate(futures)}
        total, done = int(sum(sizes)), 0
        pending = set(futures)
        within = {}  # a running task's key -> checkpoints it has passed (its reports on self.ticks)

        def heard(event):
            message = event[1] if isinstance(event, (tuple, list)) and len(event) == 2 else event
            if isinstance(message, dict) and message.get("key") in index:
                within[message["key"]] = max(within.get(message["key"], 0), int(message.get("done", 0)))

        listening = progress is not None and _listen(client, self.ticks, heard)
        try:
            reported = 0.0
            while pending:
                self.check()
                finished, pending = _first_finished(pending)
                for future in finished:
                    if future.status in ("error", "cancelled", "lost"):
                        future.result()  # raises the task's exception (or the loss) here
                    done += sizes[index[future.key]]
                if progress is not None:  # finished tasks, and the checkpoints of those still running
                    partial = sum(min(within.get(f.key, 0), sizes[index[f.key]] - 1) for f in pending)
                    if done + partial > reported:
                        reported = done + partial
                        progress(reported, total)
            return client.gather(futures)
        except BaseException as exc:
            client.cancel([f for f in futures if not f.done()])
            if isinstance(exc, Stopped):  # a task found the run's staging directory gone
                raise JobCancelled("cancelled: the server ended this run of the job (its staging directory is "
                                   "gone)") from None
            if _worker_lost(exc):
                loss = (f"a Dask worker was lost while this job's tasks ran, and with it what they needed "
                        f"({type(exc).__name__}: {_first_line(exc)})")
                raise WorkerGone(f"{loss}; the stage ran {self.reruns + 1} times, and lost a worker each time",
                                 loss) from None
            raise
        finally:
            if listening:
                _listen(client, self.ticks, None)


ALIVE_EVERY = 0.25  # seconds between a task's looks at its job's staging directory
TICK_EVERY = 0.5    # seconds between a task's reports of the checkpoints it has passed


def run_stoppable(function, alive, ticks, *args):
    """``function(*args)`` on a worker, watched at its ``engine.tasks.checkpoint`` calls (one per
    frame aligned or decomposed, or per start of a repair: the units of the task's size).

    - ``alive`` (a directory, or None): the task stops once it is gone (the server ended the job's
      run: cancelled, stopped, or started again), so a tree piece or a chunk of decompositions
      does not hold a worker's thread for minutes after its job ended.
    - ``ticks`` (a Dask event topic, or None): every ``TICK_EVERY`` seconds the task reports
      ``{"key": its key, "done": checkpoints passed}`` there, so the job's progress moves within
      a long task (a tree piece of hundreds of frames) and not only when it ends.
    """
    import os
    import time

    from engine.tasks import stop_when

    worker = key = None
    if ticks is not None:
        from distributed import get_worker

        worker = get_worker()
        key = worker.get_current_task()  # the key this runner gave the task (a str)
    state = {"looked": 0.0, "gone": False, "told": time.monotonic(), "passed": 0}

    def check():
        now = time.monotonic()
        state["passed"] += 1
        if alive is not None and now - state["looked"] >= ALIVE_EVERY:
            state["looked"], state["gone"] = now, not os.path.isdir(alive)
        if worker is not None and now - state["told"] >= TICK_EVERY:
            state["told"] = now
            try:
                worker.log_event(ticks, {"key": key, "done": state["passed"] - 1})
            except Exception:  # noqa: BLE001 - progress is best effort
                pass
        return state["gone"]

    with stop_when(check):
        return function(*args)


class WorkerGone(JobError):
    """A worker died under the job's tasks (killed, out of memory): their data went with it. The
    runner runs the stage again; when that keeps happening, the job fails with this message (no
    traceback). ``loss`` says what happened this time."""

    def __init__(self, message, loss):
        super().__init__(message)
        self.loss = loss


def _listen(client, topic, handler):
    """Subscribe ``handler`` to Dask events on ``topic`` (None: unsubscribe); False when the
    client cannot (progress then moves by whole tasks)."""
    try:
        if handler is None:
            client.unsubscribe_topic(topic)
        else:
            client.subscribe_topic(topic, handler)
    except Exception:  # noqa: BLE001 - progress is best effort
        return False
    return True


def _first_line(exc, limit=120):
    """The first line of ``exc``'s message, at most ``limit`` characters (Dask's own messages run
    over many lines, listing every future)."""
    line = (str(exc).strip().splitlines() or [""])[0].rstrip(":")
    return line if len(line) <= limit else line[:limit - 3] + "..."


def _worker_lost(exc):
    """Whether ``exc`` is Dask's way of saying a worker died under the tasks (not a task's error)."""
    from concurrent.futures import CancelledError

    from distributed.scheduler import KilledWorker

    return isinstance(exc, (KilledWorker, CancelledError))


def _first_finished(pending):
    """(finished, still pending) after waiting at most ``POLL`` seconds for one of ``pending``."""
    import asyncio

    from distributed import wait

    try:
        finished, still = wait(pending, timeout=POLL, return_when="FIRST_COMPLETED")
    except (TimeoutError, asyncio.TimeoutError):
        return set(), pending
    return set(finished), set(still)


__all__ = ["DaskRunner"]
