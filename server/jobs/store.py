"""Job records in SQLite (``data_dir/jobs.sqlite``, WAL): the one place a job's state lives.

A record moves queued -> running -> succeeded | failed | cancelled. Claiming a queued job is one
atomic ``UPDATE ... WHERE status = 'queued'``, so several server processes can share the file.
The process running a job is its *owner* (``owner``: host, pid and a per-process id); it refreshes
``heartbeat`` while the job runs, so a job whose owner died can be told apart from one that is
merely slow (see ``JobService`` for the recovery rules).
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
import uuid
from pathlib import Path

STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")
FINAL = ("succeeded", "failed", "cancelled")
LOG_LINES = 200  # lines of log kept with a record
LOG_LINE_CHARS = 500

SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    kind TEXT NOT NULL,
    status TEXT NOT NULL,
    stage TEXT NOT NULL DEFAULT '',
    progress REAL NOT NULL DEFAULT 0,
    params TEXT NOT NULL,
    result TEXT,
    error TEXT,
    log TEXT NOT NULL DEFAULT '[]',
    attempts INTEGER NOT NULL DEFAULT 0,
    max_attempts INTEGER NOT NULL DEFAULT 2,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    executor TEXT,
    worker TEXT,
    owner TEXT,
    owner_host TEXT,
    owner_pid INTEGER,
    heartbeat REAL,
    created_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    updated_at REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status, created_at);
CREATE TABLE IF NOT EXISTS meta (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL,
    updated_at REAL NOT NULL
);
"""


def _row(row):
    if row is None:
        return None
    job = dict(row)
    job["params"] = json.loads(job["params"])
    job["result"] = json.loads(job["result"]) if job["result"] else None
    job["log"] = json.loads(job["log"])
    job["worker"] = json.loads(job["worker"]) if job["worker"] else None
    job["cancel_requested"] = bool(job["cancel_requested"])
    return job


def clip_line(line):
    line = str(line).rstrip("\n")
    return line if len(line) <= LOG_LINE_CHARS else line[:LOG_LINE_CHARS - 3] + "..."


class JobStore:
    """Thread-safe access to the jobs table; every method is one short transaction."""

    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(self.path, timeout=10.0, check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA busy_timeout=10000")
        # several worker processes open the store at once: switching to WAL takes a lock that the
        # busy timeout does not wait for when another process is switching too ("database is locked")
        for attempt in range(50):
            try:
                self._db.execute("PRAGMA journal_mode=WAL")
                break
            except sqlite3.OperationalError as exc:
                if "locked" not in str(exc) or attempt == 49:
                    raise
                time.sleep(0.1)
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.execute("PRAGMA busy_timeout=10000")
        self._db.executescript(SCHEMA)

    def close(self):
        with self._lock:
            self._db.close()

    def _one(self, sql, args=()):
        with self._lock:
            return _row(self._db.execute(sql, args).fetchone())

    def _execute(self, sql, args=()):
        with self._lock:
            return self._db.execute(sql, args).rowcount

    # --- creating and reading -------------------------------------------------------------------
    def create(self, kind, params, *, max_attempts=2):
        now = time.time()
        job_id = uuid.uuid4().hex[:16]
        self._execute("INSERT INTO jobs (id, kind, status, stage, params, log, max_attempts, created_at, updated_at) "
                      "VALUES (?, ?, 'queued', 'queued', ?, ?, ?, ?, ?)",
                      (job_id, kind, json.dumps(params), json.dumps([]), max_attempts, now, now))
        return self.get(job_id)

    def get(self, job_id):
        return self._one("SELECT * FROM jobs WHERE id = ?", (job_id,))

    def list(self, *, status=None, kind=None, limit=100, offset=0):
        where, args = [], []
        if status:
            where.append(f"status IN ({', '.join('?' * len(status))})")
            args.extend(status)
        if kind:
            where.append("kind = ?")
            args.append(kind)
        sql = "SELECT * FROM jobs" + (f" WHERE {' AND '.join(where)}" if where else "")
        sql += " ORDER BY created_at DESC, id LIMIT ? OFFSET ?"
        with self._lock:
            rows = self._db.execute(sql, (*args, limit, offset)).fetchall()
        return [_row(r) for r in rows]

    def active_using(self, key, value):
        """Queued or running jobs whose params[key] (a name or list of names) contains ``value``."""
        with self._lock:
            rows = self._db.execute("SELECT * FROM jobs WHERE status IN ('queued', 'running')").fetchall()
        out = []
        for job in map(_row, rows):
            got = job["params"].get(key)
            if got == value or (isinstance(got, list) and value in got):
                out.append(job)
        return out

    # --- the owner's transitions ----------------------------------------------------------------
    def claim(self, owner, host, pid, executor):
        """Atomically take the oldest queued job: running, attempts + 1, owned by ``owner``."""
        now = time.time()
        with self._lock:
            row = self._db.execute(
                "UPDATE jobs SET status = 'running', stage = 'starting', progress = 0, attempts = attempts + 1, "
                "owner = ?, owner_host = ?, owner_pid = ?, executor = ?, worker = NULL, heartbeat = ?, "
                "started_at = ?, updated_at = ? "
                "WHERE id = (SELECT id FROM jobs WHERE status = 'queued' AND cancel_requested = 0 "
                "            ORDER BY created_at, id LIMIT 1) AND status = 'queued' RETURNING *",
                (owner, host, pid, executor, now, now, now)).fetchone()
        return _row(row)

    def update_running(self, job_id, owner, *, stage=None, progress=None, log=None, worker=None):
        """Progress, stage, log tail (a list of lines) and worker of a job this owner runs."""
        sets, args = ["heartbeat = ?", "updated_at = ?"], [time.time(), time.time()]
        if stage is not None:
            sets.append("stage = ?")
            args.append(stage)
        if progress is not None:
            sets.append("progress = MAX(progress, ?)")
            args.append(float(min(max(progress, 0.0), 1.0)))
        if log is not None:
            sets.append("log = ?")
            args.append(json.dumps([clip_line(line) for line in list(log)[-LOG_LINES:]]))
        if worker is not None:
            sets.append("worker = ?")
            args.append(json.dumps(worker))
        return self._execute(f"UPDATE jobs SET {', '.join(sets)} WHERE id = ? AND owner = ? AND status = 'running'",
                             (*args, job_id, owner)) == 1

    def heartbeat(self, owner, job_ids):
        if not job_ids:
            return
        now = time.time()
        with self._lock:
            self._db.executemany("UPDATE jobs SET heartbeat = ? WHERE id = ? AND owner = ? AND status = 'running'",
                                 [(now, job_id, owner) for job_id in job_ids])

    def finish(self, job_id, owner, status, *, result=None, error=None, log=None, stage=None):
        """Final status of a running job this owner holds; False if it no longer holds it."""
        assert status in FINAL
        now = time.time()
        sets = ["status = ?", "finished_at = ?", "updated_at = ?", "heartbeat = NULL", "result = ?", "error = ?"]
        args = [status, now, now, json.dumps(result) if result is not None else None, error]
        if status == "succeeded":
            sets.append("progress = 1")
        if stage is not None:
            sets.append("stage = ?")
            args.append(stage)
        if log is not None:
            sets.append("log = ?")
            args.append(json.dumps([clip_line(line) for line in list(log)[-LOG_LINES:]]))
        return self._execute(f"UPDATE jobs SET {', '.join(sets)} WHERE id = ? AND owner = ? AND status = 'running'",
                             (*args, job_id, owner)) == 1

    # --- cancelling and recovering --------------------------------------------------------------
    def cancel_queued(self, job_id):
        now = time.time()
        return self._execute("UPDATE jobs SET status = 'cancelled', stage = 'cancelled', cancel_requested = 1, "
                             "error = 'cancelled before it started', finished_at = ?, updated_at = ? "
                             "WHERE id = ? AND status = 'queued'", (now, now, job_id)) == 1

    def request_cancel(self, job_id):
        return self._execute("UPDATE jobs SET cancel_requested = 1, updated_at = ? WHERE id = ? AND status = 'running'",
                             (time.time(), job_id)) == 1

    def recover(self, job, reason, *, consume=True):
        """A running job whose owner is gone: queued again while attempts remain, else failed.

        ``consume=False`` (a clean server stop) queues it again without counting the attempt.
        Returns the new status, or None if the record changed meanwhile (someone else recovered it).
        """
        now = time.time()
        log = list(job["log"])
        if job["cancel_requested"]:
            status, error = "cancelled", f"cancelled; {reason}"
        elif not consume:
            status, error = "queued", None
            log.append(f"attempt {job['attempts']} stopped: {reason}; queued again")
        elif job["attempts"] < job["max_attempts"]:
            status, error = "queued", None
            log.append(f"attempt {job['attempts']} interrupted: {reason}; queued again")
        else:
            status, error = "failed", f"interrupted: {reason} (attempt {job['attempts']} of {job['max_attempts']})"
            log.append(error)
        finished = now if status != "queued" else None
        changed = self._execute(
            "UPDATE jobs SET status = ?, stage = ?, error = ?, log = ?, owner = NULL, owner_host = NULL, "
            "owner_pid = NULL, heartbeat = NULL, worker = NULL, finished_at = ?, updated_at = ?, "
            "progress = CASE WHEN ? = 'queued' THEN 0 ELSE progress END, attempts = attempts - ? "
            "WHERE id = ? AND status = 'running' AND owner IS ?",
            (status, status if status != "failed" else job["stage"], error,
             json.dumps([clip_line(x) for x in log[-LOG_LINES:]]), finished, now, status, 0 if consume else 1,
             job["id"], job["owner"]))
        return status if changed == 1 else None

    # --- what the queue's process publishes for the others ----------------------------------------
    def set_meta(self, key, value):
        self._execute("INSERT INTO meta (key, value, updated_at) VALUES (?, ?, ?) "
                      "ON CONFLICT(key) DO UPDATE SET value = excluded.value, updated_at = excluded.updated_at",
                      (key, json.dumps(value), time.time()))

    def get_meta(self, key):
        with self._lock:
            row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return json.loads(row[0]) if row else None

    def counts(self, statuses):
        """``{status: jobs in it}`` for each of ``statuses``."""
        statuses = tuple(statuses)
        with self._lock:  # (the status index: finished jobs are not scanned)
            rows = dict(self._db.execute(f"SELECT status, COUNT(*) FROM jobs WHERE status IN "
                                         f"({', '.join('?' * len(statuses))}) GROUP BY status", statuses).fetchall())
        return {status: rows.get(status, 0) for status in statuses}

    def running(self):
        with self._lock:
            rows = self._db.execute("SELECT * FROM jobs WHERE status = 'running'").fetchall()
        return [_row(r) for r in rows]
