"""JobService: the server's job queue over the SQLite store and an executor.

Life of a job: ``create`` validates the request and stores it as *queued*; the dispatcher
(one asyncio task) claims queued jobs while the executor has room, runs each one with a
staging directory ``work/jobs/<id>/attempt-<n>-<run>/`` (one per run), streams its progress and log into the
record, and on success renames the output into ``spaces/`` or ``datasets/`` before marking
it *succeeded*. A failed or cancelled job's staging directory is deleted: nothing partial is
ever visible.

Crash recovery. Every running record names its owner (host, pid, a per-process id) and the
owner refreshes its heartbeat every few seconds. At start and every few seconds after, a
service looks for running jobs whose owner is gone: on this host a pid that no longer exists
(or is this very process under a new identity, e.g. pid 1 in a restarted container), else a
heartbeat older than ``STALE_AFTER``. Such a job is queued again if it has attempts left (two
in all), with the reason in its log, or marked failed with the reason. A local worker exits
when its server dies (it watches its stdin), so an interrupted job is never still running
when it is re-run. A worker that dies while its server lives (killed, out of memory) fails
the job with the signal and stage in the error; the server goes on serving. On Dask, a
scheduler that goes away under a running job queues it again (``Interrupted``: an attempt
counted), and while the scheduler does not answer nothing is claimed: jobs wait queued.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import os
import shutil
import socket
import time
import uuid

from server import uploads
from server.jobs.executors import DaskExecutor, Interrupted, LocalExecutor, WorkerLost
from server.jobs.store import FINAL, JobStore
from server.jobs.requests import JobRequestError, RequestCheck
from server.jobs.tasks import JobCancelled, JobError, _relative, publish

log = logging.getLogger("morphspace.jobs")

HEARTBEAT = 2.0  # seconds between heartbeats and orphan scans
STALE_AFTER = 60.0  # a running job whose owner has not been heard of for this long is recovered
FLUSH = 0.25  # seconds between progress writes of one job


def _pid_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class _Running:
    """In-memory state of a job this service runs: log tail, last stage and progress, flush timer."""

    def __init__(self, job):
        self.job = job
        self.log = collections.deque(job["log"], maxlen=200)
        self.stage, self.progress, self.worker = None, None, None
        self.dirty, self.flushed_at = False, 0.0
        self.task, self.timer = None, None


class JobService:
    """The job queue of one server process. ``runs_jobs=False`` (the other workers of
    ``morphspace serve --workers N``): create, list, read and cancel through the shared store
    only; ``wake_owner()`` then tells the process that runs the queue to look at the store."""

    def __init__(self, settings, registry, *, runs_jobs=True, wake_owner=None):
        self.settings, self.registry = settings, registry
        self.requests = RequestCheck(settings, registry)
        self.runs_jobs, self.wake_owner = runs_jobs, wake_owner
        self._check_cancels = False
        self.owner = uuid.uuid4().hex
        self.host = socket.gethostname()
        self.pid = os.getpid()
        self.store = None
        self.executor = None
        self.running = {}
        self._wake = None
        self._loop_task = None
        self._stopping = False
        self._published_status, self._published_at = None, 0.0

    # --- lifecycle ------------------------------------------------------------------------------
    async def start(self):
        settings = self.settings
        for directory in (settings.data_dir, settings.work_dir, self.jobs_dir):
            directory.mkdir(parents=True, exist_ok=True)
        self.store = JobStore(settings.jobs_db)
        if not self.runs_jobs:
            return
        if settings.dask_scheduler:
            self.executor = DaskExecutor(settings.dask_scheduler)
        else:
            self.executor = LocalExecutor(settings.job_workers)
        await self.executor.start()
        self._publish_executor()
        uploads.clean_stale(settings)
        self._recover_orphans()
        self._clean_work_dirs()
        self._wake = asyncio.Event()
        self._stopping = False
        self._loop_task = asyncio.create_task(self._dispatch_loop(), name="morphspace-jobs")

    async def stop(self):
        if self.store is None:
            return
        if not self.runs_jobs:
            self.store.close()
            self.store = None
            return
        self._stopping = True
        if self._loop_task is not None:
            self._loop_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._loop_task
        # queue our running jobs again (not counting this attempt), then stop their workers
        for job_id in list(self.running):
            job = self.store.get(job_id)
            if job and job["status"] == "running" and job["owner"] == self.owner:
                self.store.recover(job, f"the server (pid {self.pid}) stopped", consume=False)
        for state in list(self.running.values()):
            state.task.cancel()
        await asyncio.gather(*(s.task for s in self.running.values()), return_exceptions=True)
        await self.executor.stop()
        self.store.close()
        self.store = None

    @property
    def jobs_dir(self):
        return self.settings.work_dir / "jobs"

    # --- API operations -------------------------------------------------------------------------
    def create(self, request):
        """Check a validated request (models.JobRequest) against the data directory and queue it."""
        params = self.requests.params(request, self.store)
        job = self.store.create(params["kind"], params)
        self._kick()
        return job

    def get(self, job_id):
        return self.store.get(job_id)

    def list(self, **filters):
        return self.store.list(**filters)

    def dataset_in_use(self, name):
        """True when a queued or running job reads or writes dataset ``name``."""
        return any(self.store.active_using(key, name) for key in ("dataset", "datasets")) or any(
            job["params"].get("output_type") == "dataset" for job in self.store.active_using("output_name", name))

    async def cancel(self, job_id, wait=10.0):
        """Cancel a queued job at once, or stop a running one (waits up to ``wait`` s for it to end)."""
        job = self.store.get(job_id)
        if job is None:
            raise JobRequestError(404, f"no job {job_id!r}")
        if job["status"] in FINAL:
            raise JobRequestError(409, f"job {job_id} is already {job['status']}; only queued or running jobs "
                                       "can be cancelled")
        if self.store.cancel_queued(job_id):
            return self.store.get(job_id)
        self.store.request_cancel(job_id)
        state = self.running.get(job_id)
        if state is not None:
            await self._stop_job(job_id)
            with contextlib.suppress(asyncio.TimeoutError, asyncio.CancelledError):
                await asyncio.wait_for(asyncio.shield(state.task), wait)
        elif not self.runs_jobs:  # the queue's worker stops it: wait for the record to say so
            self._kick()
            deadline = time.monotonic() + wait
            while self.store.get(job_id)["status"] not in FINAL and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
        return self.store.get(job_id)

    async def _stop_job(self, job_id):
        cancel_file = self.jobs_dir / job_id / "CANCEL"
        with contextlib.suppress(OSError):
            cancel_file.write_text("cancelled\n")
        await self.executor.cancel(job_id)

    # --- the dispatcher -------------------------------------------------------------------------
    def _kick(self):
        if not self.runs_jobs:
            if self.wake_owner is not None:
                self.wake_owner()
        elif self._wake is not None:
            self._wake.set()

    def wake(self):
        """Another process changed the store (queued a job, asked for a cancel): look now."""
        self._check_cancels = True
        self._kick()

    async def _dispatch_loop(self):
        last_scan = time.monotonic()
        while not self._stopping:
            try:
                if time.monotonic() - last_scan >= HEARTBEAT:
                    last_scan = time.monotonic()
                    self.store.heartbeat(self.owner, list(self.running))
                    self._recover_orphans()
                    self._check_cancels = True
                if self._check_cancels:
                    self._check_cancels = False
                    await self._honour_cancel_requests()
                await self.executor.refresh()
                self._publish_executor()
                while len(self.running) < self.executor.capacity():
                    job = self.store.claim(self.owner, self.host, self.pid, self.executor.name)
                    if job is None:
                        break
                    state = _Running(job)
                    self.running[job["id"]] = state
                    state.task = asyncio.create_task(self._run(state), name=f"morphspace-job-{job['id']}")
            except asyncio.CancelledError:
                raise
            except Exception:  # noqa: BLE001 - a bad moment in the loop must not end the queue
                log.exception("job dispatcher")
            self._wake.clear()
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._wake.wait(), HEARTBEAT)

    def _publish_executor(self):
        """What runs the jobs, as /v1/health shows it (in the store: every server process reads it)."""
        status = self.executor.status()
        if status != self._published_status or time.monotonic() - self._published_at >= HEARTBEAT:
            self.store.set_meta("executor", {**status, "checked_at": time.time()})
            self._published_status, self._published_at = status, time.monotonic()

    def executor_status(self):
        """/v1/health's ``jobs``: the executor (for Dask: whether the scheduler answers, its
        workers and threads), when that was checked, and the jobs queued and running."""
        status = dict(self.store.get_meta("executor") or {"executor": None})
        checked = status.pop("checked_at", None)
        status["checked_ago"] = round(max(time.time() - checked, 0.0), 3) if checked else None
        return {**status, **self.store.counts(("queued", "running"))}

    async def _honour_cancel_requests(self):
        """Cancels asked of another server process for jobs this one runs (shared database)."""
        for job_id in list(self.running):
            job = self.store.get(job_id)
            if job is not None and job["cancel_requested"] and job_id not in self.executor.cancelling:
                await self._stop_job(job_id)

    def _recover_orphans(self):
        now = time.time()
        for job in self.store.running():
            if job["owner"] == self.owner:
                continue
            reason = None
            if job["owner_host"] == self.host and job["owner_pid"] is not None:
                if job["owner_pid"] == self.pid or not _pid_alive(job["owner_pid"]):
                    reason = f"the server process that ran it (pid {job['owner_pid']}) exited"
            if reason is None and (job["heartbeat"] or 0) < now - STALE_AFTER:
                reason = (f"its server ({job['owner_host']}, pid {job['owner_pid']}) has not been heard from "
                          f"for {STALE_AFTER:.0f} s")
            if reason is not None:
                status = self.store.recover(job, reason)
                if status is not None:
                    log.warning("job %s: %s; now %s", job["id"], reason, status)
                    shutil.rmtree(self.jobs_dir / job["id"], ignore_errors=True)
                    self._kick()

    def _clean_work_dirs(self):
        """Staging directories of jobs that are not running any more (left by a crash)."""
        if not self.jobs_dir.is_dir():
            return
        for entry in self.jobs_dir.iterdir():
            job = self.store.get(entry.name)
            if job is None or job["status"] != "running":
                shutil.rmtree(entry, ignore_errors=True)

    # --- running one job ------------------------------------------------------------------------
    def _on_message(self, state, message):
        kind = message.get("t")
        if kind == "progress":
            state.stage = str(message.get("stage", ""))[:100]
            state.progress = float(message.get("progress", 0.0))
        elif kind == "log":
            state.log.append(_relative(message.get("line", ""), self.settings.data_dir))
        elif kind == "worker":
            info = message.get("info", {})
            before = (state.worker or {}).get("address")
            if before and info.get("address") and info["address"] != before:  # Dask lost the job's worker
                state.log.append(f"the Dask worker running the job ({before}) was lost; Dask started the job "
                                 f"again on {info['address']} (from its first stage, in the same attempt)")
            state.worker = {**(state.worker or {}), **info}
        else:
            return
        state.dirty = True
        now = time.monotonic()
        if kind == "worker" or now - state.flushed_at >= FLUSH:
            self._flush(state)
        elif state.timer is None:  # write it soon even if no other message follows
            state.timer = asyncio.get_running_loop().call_later(FLUSH, self._flush, state)

    def _flush(self, state):
        if state.timer is not None:
            state.timer.cancel()
            state.timer = None
        if not state.dirty or self.store is None or state.job["id"] not in self.running:
            return
        state.dirty, state.flushed_at = False, time.monotonic()
        self.store.update_running(state.job["id"], self.owner, stage=state.stage, progress=state.progress,
                                  log=state.log, worker=state.worker)

    async def _run(self, state):
        job = state.job
        job_id = job["id"]
        job_dir = self.jobs_dir / job_id
        # a run of its own: an earlier run's task that Dask could not stop finds its staging
        # directory gone (and stops), and never shares one with this run, nor a task key
        shutil.rmtree(job_dir, ignore_errors=True)
        run = f"{job['attempts']}-{uuid.uuid4().hex[:8]}"
        staging = job_dir / f"attempt-{run}"
        staging.mkdir(parents=True)
        payload = {"id": job_id, "kind": job["kind"], "attempt": job["attempts"], "run": run, "params": job["params"],
                   "data_dir": str(self.settings.data_dir.resolve()), "staging": str(staging.resolve())}
        state.log.append(f"attempt {job['attempts']} started on {self.executor.name} executor (server pid {self.pid})")
        status, result, error = "failed", None, None
        try:
            output = await self.executor.run(job, payload, lambda message: self._on_message(state, message))
            if self.store.get(job_id)["cancel_requested"]:
                raise JobCancelled("cancelled by request")
            state.stage, state.dirty = "publish", True
            self._flush(state)
            result = await asyncio.to_thread(publish, output, staging, self.settings.data_dir,
                                             bool(job["params"].get("replace")))
            status = "succeeded"
            state.log.append(f"published {result['url']}")
        except JobCancelled as exc:
            status, error = "cancelled", str(exc)
        except JobError as exc:
            error = str(exc)
        except WorkerLost as exc:
            error = str(exc)
        except Interrupted as exc:
            status = "interrupted"
            error = str(exc)
        except asyncio.CancelledError:  # the server is stopping; stop() has queued the job again
            raise
        except Exception as exc:  # noqa: BLE001 - recorded on the job, the server goes on
            log.exception("job %s", job_id)
            error = f"internal error: {type(exc).__name__}: {_relative(exc, self.settings.data_dir)}"
        finally:
            if state.timer is not None:
                state.timer.cancel()
            self.running.pop(job_id, None)
            shutil.rmtree(job_dir, ignore_errors=True)
            self._kick()
        if status == "interrupted":  # queued again while it has attempts left, as after a server crash
            if self.store is not None:
                record = {**self.store.get(job_id), "log": list(state.log)}
                log.warning("job %s: %s; now %s", job_id, error, self.store.recover(record, error))
            return
        if error:
            state.log.append(f"{status}: {error}")
        if self.store is not None:
            self.store.finish(job_id, self.owner, status, result=result, error=error, log=state.log,
                              stage=status if status != "failed" else state.stage)
