"""A local job worker: ``python -m server.jobs.worker``, one process per job.

The server writes the job's JSON payload as one line on stdin and keeps stdin open; the worker
answers with JSON lines on stdout (``progress``, ``log``, then one ``result``, ``error`` or
``cancelled``). Anything the engine prints goes to stderr, which the server keeps as log lines.
When stdin closes (the server died) the worker exits at once, so no job outlives its server;
SIGTERM stops it (the server's cancel), leaving the staging directory for the server to remove.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import traceback


def _watch_parent():
    """Exit as soon as the server's end of stdin closes."""
    try:
        while sys.stdin.buffer.read(65536):
            pass
    finally:
        os._exit(70)


def main():
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server decides when a job stops
    protocol = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # print() from the engine goes to stderr, not into the protocol
    sys.stdout = sys.stderr
    lock = threading.Lock()

    def emit(message):
        line = json.dumps(message)
        with lock:
            protocol.write(line + "\n")

    line = sys.stdin.buffer.readline()
    if not line:
        return 2
    payload = json.loads(line)
    threading.Thread(target=_watch_parent, daemon=True).start()
    from server.jobs.tasks import JobCancelled, JobError, Reporter, _relative, run_task

    reporter = Reporter(payload["kind"], emit, staging=payload["staging"])
    emit({"t": "worker", "info": {"pid": os.getpid()}})
    try:
        emit({"t": "result", "result": run_task(payload, reporter)})
    except JobCancelled as exc:
        emit({"t": "cancelled", "error": str(exc)})
    except JobError as exc:
        emit({"t": "error", "error": str(exc)})
    except Exception as exc:  # noqa: BLE001 - reported to the job record; the traceback goes to the log
        traceback.print_exc()
        emit({"t": "error", "error": f"{type(exc).__name__}: {_relative(exc, payload['data_dir'])}"})
    protocol.flush()
    sys.stderr.flush()
    return 0


if __name__ == "__main__":
    # os._exit: the stdin watcher thread is blocked in a read that interpreter shutdown would trip on
    os._exit(main())
