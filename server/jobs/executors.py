"""Where jobs run: a local worker process per job (default), or a Dask cluster.

An executor's ``run(job, payload, on_message)`` returns the task's result or raises
``JobCancelled`` / ``JobError`` / ``WorkerLost`` / ``Interrupted``; ``on_message(dict)`` receives progress, log and
worker messages as they come (server/jobs/tasks.py, ``Reporter``). ``cancel(job_id)`` stops a job:
the local executor terminates the process (SIGTERM, then SIGKILL); the Dask executor cancels the
future and the task notices its CANCEL file at its next progress report.

Nothing here unpickles anything the API received: payloads are JSON, and what Dask sends are
references to the module-level function ``server.jobs.tasks.dask_entry`` plus a JSON string.
Dask's own protocol pickles, so the scheduler and workers must sit on a trusted network.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import signal
import socket
import sys

from server.jobs.tasks import JobCancelled, JobError

log = logging.getLogger("morphspace.jobs")


class WorkerLost(Exception):
    """The process (or Dask worker) running a job went away without an answer."""


class Interrupted(Exception):
    """What runs jobs went away under this one (the Dask scheduler): not the job's doing, so it
    is queued again while it has attempts left, as after a server crash."""


def describe_exit(returncode):
    if returncode is None:
        return "is still running"
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        return f"was killed by {name}"
    return f"exited with status {returncode}"


class LocalExecutor:
    """One ``python -m server.jobs.worker`` process per job, at most ``slots`` at a time."""

    name = "local"
    grace = 3.0  # seconds between SIGTERM and SIGKILL on cancel

    def __init__(self, slots):
        self.slots = slots
        self.processes = {}
        self.cancelling = set()

    def capacity(self):
        return self.slots

    def status(self):
        return {"executor": self.name, "slots": self.slots}

    async def refresh(self):
        return None

    async def start(self):
        return None

    async def stop(self):
        for job_id in list(self.processes):
            await self.cancel(job_id, grace=1.0)

    async def run(self, job, payload, on_message):
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        process = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "server.jobs.worker", stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, start_new_session=True, env=env,
            limit=1 << 20)
        job_id = job["id"]
        self.processes[job_id] = process
        on_message({"t": "worker", "info": {"host": socket.gethostname(), "pid": process.pid}})
        final = {}
        stage = ["starting"]

        async def read_stdout():
            while line := await process.stdout.readline():
                try:
                    message = json.loads(line)
                except ValueError:
                    on_message({"t": "log", "line": line.decode("utf-8", "replace")})
                    continue
                if message.get("t") in ("result", "error", "cancelled"):
                    final.update(message)
                else:
                    if message.get("t") == "progress":
                        stage[0] = message.get("stage", stage[0])
                    on_message(message)

        async def read_stderr():
            while line := await process.stderr.readline():
                text = line.decode("utf-8", "replace").rstrip()
                if text and "\r" not in text:
                    on_message({"t": "log", "line": text})

        try:
            process.stdin.write(json.dumps(payload).encode() + b"\n")
            await process.stdin.drain()
            await asyncio.gather(read_stdout(), read_stderr())
            returncode = await process.wait()
        except asyncio.CancelledError:  # the server is stopping: take the worker down with it
            with contextlib.suppress(ProcessLookupError):
                process.kill()
            raise
        finally:
            self.processes.pop(job_id, None)
            with contextlib.suppress(Exception):
                process.stdin.close()
        if job_id in self.cancelling:
            self.cancelling.discard(job_id)
            raise JobCancelled("cancelled by request")
        if final.get("t") == "result" and returncode == 0:
            return final["result"]
        if final.get("t") == "cancelled":
            raise JobCancelled(final.get("error", "cancelled"))
        if final.get("t") == "error":
            raise JobError(final["error"])
        raise WorkerLost(f"the worker process (pid {process.pid}) {describe_exit(returncode)} during stage "
                         f"{stage[0]!r} without finishing the job")

    async def cancel(self, job_id, grace=None):
        process = self.processes.get(job_id)
        if process is None:
            return False
        self.cancelling.add(job_id)
        with contextlib.suppress(ProcessLookupError):
            process.terminate()
        try:
            await asyncio.wait_for(process.wait(), grace or self.grace)
        except asyncio.TimeoutError:
            with contextlib.suppress(ProcessLookupError):
                process.kill()
        return True


class DaskExecutor:
    """Jobs as tasks on a Dask cluster (``settings.dask_scheduler``); progress via worker events.

    ``refresh()`` (the dispatcher calls it before it claims jobs) asks the scheduler for its
    workers: ``capacity()`` is their threads in all (every coordinator secedes while it waits, so
    as many jobs as threads can run at once), and ``status()`` says so for /v1/health. While the
    scheduler cannot be reached ``capacity()`` is 0: jobs wait in the queue."""

    name = "dask"
    probe_timeout = 3.0  # seconds for the scheduler to answer a refresh

    def __init__(self, address, connect_timeout=10.0):
        self.address = address
        self.connect_timeout = connect_timeout
        self.client = None
        self.futures = {}
        self.cancelling = set()
        self.cluster = {"reachable": None, "workers": None, "threads": None, "error": None}

    async def _client(self, timeout=None):
        if self.client is None or self.client.status not in ("running", "connecting"):
            from distributed import Client

            if self.client is not None:
                with contextlib.suppress(Exception):
                    await self.client.close()
            try:
                self.client = await Client(self.address, asynchronous=True, timeout=timeout or self.connect_timeout,
                                           set_as_default=False)
            except (OSError, asyncio.TimeoutError) as exc:
                self.client = None
                raise JobError(f"cannot reach the Dask scheduler at {self.address} ({exc})") from None
        return self.client

    async def refresh(self):
        """Ask the scheduler for its workers (``self.cluster``)."""
        try:
            client = await self._client(self.probe_timeout)
            info = await asyncio.wait_for(client.scheduler.identity(n_workers=-1), self.probe_timeout)
        except Exception as exc:  # noqa: BLE001 - whatever the reason, the scheduler is not there for us
            message = str(exc) if isinstance(exc, JobError) else (
                f"cannot reach the Dask scheduler at {self.address} ({type(exc).__name__}: {exc})")
            if self.cluster["reachable"] is not False:
                log.warning("%s; jobs wait in the queue until it answers", message)
            self.cluster = {"reachable": False, "workers": None, "threads": None, "error": message}
            return
        workers = info.get("workers", {})
        self.cluster = {"reachable": True, "workers": len(workers),
                        "threads": sum(int(w.get("nthreads", 1)) for w in workers.values()), "error": None}

    def capacity(self):
        if not self.cluster["reachable"]:
            return 0
        return max(1, self.cluster["threads"])

    def status(self):
        return {"executor": self.name, "scheduler": self.address, **self.cluster}

    async def start(self):
        await self.refresh()

    async def stop(self):
        for job_id in list(self.futures):
            await self.cancel(job_id)
        if self.client is not None:
            with contextlib.suppress(Exception):
                await self.client.close()
            self.client = None

    async def run(self, job, payload, on_message):
        from server.jobs.tasks import dask_entry

        client = await self._client()
        job_id = job["id"]
        # a key per run: a task of an earlier run (which Dask cannot stop) may still hold its own
        topic = f"morphspace-job-{job_id}-{payload['run']}"
        loop = asyncio.get_running_loop()

        def handler(event):
            message = event[1] if isinstance(event, (tuple, list)) and len(event) == 2 else event
            if isinstance(message, dict):
                loop.call_soon_threadsafe(on_message, message)

        client.subscribe_topic(topic, handler)
        future = client.submit(dask_entry, json.dumps(payload), topic, key=topic, pure=False, retries=0)
        self.futures[job_id] = future
        on_message({"t": "worker", "info": {"scheduler": self.address, "key": topic}})
        if self.cluster["reachable"] and not self.cluster["workers"]:
            on_message({"t": "log", "line": f"the Dask cluster at {self.address} has no workers: the job waits "
                                            "for one to join"})
        try:
            answer = json.loads(await future)
        except asyncio.CancelledError:
            if job_id in self.cancelling:
                raise JobCancelled("cancelled by request") from None
            with contextlib.suppress(Exception):
                await future.cancel()
            raise
        except Exception as exc:  # noqa: BLE001 - KilledWorker, lost scheduler, ...
            if job_id in self.cancelling:
                raise JobCancelled("cancelled by request") from None
            await self.refresh()
            if not self.cluster["reachable"]:
                raise Interrupted(f"the Dask scheduler at {self.address} went away while the job ran "
                                  f"({type(exc).__name__})") from None
            raise WorkerLost(f"the Dask task failed: {type(exc).__name__}: {exc}") from None
        finally:
            self.futures.pop(job_id, None)
            with contextlib.suppress(Exception):
                client.unsubscribe_topic(topic)
        self.cancelling.discard(job_id)
        if "result" in answer:
            return answer["result"]
        if "cancelled" in answer:
            raise JobCancelled(answer["cancelled"])
        if answer.get("traceback"):
            for line in answer["traceback"].splitlines():
                on_message({"t": "log", "line": line})
        raise JobError(answer.get("error", "the Dask task failed"))

    async def cancel(self, job_id, grace=None):
        future = self.futures.get(job_id)
        if future is None:
            return False
        self.cancelling.add(job_id)
        with contextlib.suppress(Exception):
            await future.cancel()
        return True
