"""The counter board: what every server worker process publishes for the others to read.

``morphspace serve --workers N`` runs N processes (server/workers/supervisor.py); any of them may
answer ``/v1/health``, which must report all of them. The supervisor creates one anonymous shared
memory block before it forks the workers, so every process maps the same pages: no file, nothing
to clean up.

The block holds blobs of at most ``BLOB`` bytes, each with one writer:

- ``worker(i)``: written by worker ``i`` itself (every ``PUBLISH_EVERY`` s and whenever it
  answers /v1/health): its pid and counters (connections, frames sent and dropped, stream errors,
  the frame scheduler's tally);
- ``slot(i)``: written by the supervisor: the pid it forked for index ``i``, when, how many times
  it restarted that index and why the last one ended;
- ``retired``: written by the supervisor: the sums of the counters of workers that have ended,
  so totals survive a restart (gauges such as ``connections`` are not carried over: a dead
  worker's connections are closed).

A blob is JSON behind a sequence lock: the writer makes the sequence odd, writes, makes it even;
a reader copies the bytes and retries when the sequence was odd or changed meanwhile. A worker
killed in the middle of a write leaves its sequence odd: its blob reads as empty until the next
write (the supervisor's ``retire``), which starts again from the next even number. Counters are
summed key by key (nested dicts too; a key ending in ``_max`` is a peak and takes the largest),
so a counter added to the stream statistics or the scheduler is aggregated without a change here.
"""

from __future__ import annotations

import json
import mmap
import struct
import time

BLOB = 4096                 # bytes per blob (one page)
PUBLISH_EVERY = 0.25        # seconds between a worker's publications
GAUGES = frozenset({"connections"})  # counters that are a current value, not a running total
_HEAD = struct.Struct("<QI")  # sequence, payload length
_RETRIES = 1000


class CounterBoard:
    """``workers`` workers' blobs, the supervisor's slots and the retired totals in shared memory."""

    def __init__(self, workers):
        self.workers = int(workers)
        self._memory = mmap.mmap(-1, BLOB * (2 * self.workers + 1))  # anonymous, MAP_SHARED: kept across fork

    # --- raw blobs ------------------------------------------------------------------------------
    def _write(self, blob, value):
        payload = json.dumps(value, separators=(",", ":")).encode()
        if len(payload) > BLOB - _HEAD.size:
            raise ValueError(f"counter board: {len(payload)} bytes do not fit in a {BLOB}-byte blob")
        offset = blob * BLOB
        sequence, _ = _HEAD.unpack_from(self._memory, offset)
        sequence += sequence & 1  # odd: its writer was killed mid-write; go on from the next even
        _HEAD.pack_into(self._memory, offset, sequence + 1, 0)  # odd: being written
        self._memory[offset + _HEAD.size:offset + _HEAD.size + len(payload)] = payload
        _HEAD.pack_into(self._memory, offset, sequence + 2, len(payload))

    def _read(self, blob):
        offset = blob * BLOB
        for _ in range(_RETRIES):
            sequence, length = _HEAD.unpack_from(self._memory, offset)
            payload = self._memory[offset + _HEAD.size:offset + _HEAD.size + length]
            again, _ = _HEAD.unpack_from(self._memory, offset)
            if sequence == again and sequence % 2 == 0:
                return json.loads(payload) if length else {}
            time.sleep(0)
        return {}  # a writer died mid-write (cannot happen to a live one for this long)

    # --- the three kinds of blob ----------------------------------------------------------------
    def publish(self, index, pid, counters):
        """Worker ``index`` (process ``pid``) reports its counters (a dict of numbers or dicts)."""
        self._write(index, {"pid": pid, "published_at": time.time(), "counters": counters})

    def worker(self, index):
        return self._read(index)

    def set_slot(self, index, **fields):
        """Supervisor: merge ``fields`` into the record of index ``index``."""
        self._write(self.workers + index, {**self.slot(index), **fields})

    def slot(self, index):
        return self._read(self.workers + index)

    def retire(self, index):
        """Supervisor, once worker ``index`` has ended: add its counters to the retired totals and
        clear its blob (the index's next process starts from zero)."""
        counters = self.worker(index).get("counters", {})
        totals = self._read(2 * self.workers)
        self._write(2 * self.workers, add_counters(totals, counters, skip=GAUGES))
        self._write(index, {})

    def retired(self):
        return self._read(2 * self.workers)

    # --- reading it all -------------------------------------------------------------------------
    def summary(self, now=None, shape=None):
        """(workers, totals, restarts): one record per index (``index``, ``pid``, ``alive``,
        ``jobs`` (runs the job queue), ``started_at``, ``restarts``, ``last_exit``, the counters),
        the counters summed over the live workers and the retired ones, and restarts in all.

        ``shape``: counters (the caller's own) whose keys, zeroed, stand in for those of a worker
        that has published nothing yet or has ended (between a worker's end and its restart), so
        every record carries every counter (docs/rest.md)."""
        now = time.time() if now is None else now
        workers, totals, restarts = [], self.retired(), 0
        for index in range(self.workers):
            slot, published = self.slot(index), self.worker(index)
            current = published.get("pid") == slot.get("pid") and slot.get("pid") is not None
            counters = published.get("counters", {}) if current else {}
            if shape is not None:
                counters = {**zeroed(shape), **counters}
            restarts += slot.get("restarts", 0)
            totals = add_counters(totals, counters)
            workers.append({"index": index, "pid": slot.get("pid"), "alive": current, "jobs": index == 0,
                            "started_at": slot.get("started_at"), "restarts": slot.get("restarts", 0),
                            "last_exit": slot.get("last_exit"),
                            "published_ago": round(now - published["published_at"], 3) if current else None,
                            **counters})
        return workers, totals, restarts


def zeroed(counters):
    """``counters`` with every number 0 (nested dicts too): the counters of a worker that has none."""
    return {key: zeroed(value) if isinstance(value, dict) else type(value)() if isinstance(value, (int, float))
            else value for key, value in counters.items()}


def add_counters(a, b, skip=()):
    """``a`` + ``b`` key by key: numbers add (keys ending in ``_max``: the larger), dicts recurse;
    keys in ``skip`` are left out of ``b``. Neither argument is changed."""
    out = dict(a)
    for key, value in b.items():
        if key in skip or isinstance(value, bool):
            continue
        if isinstance(value, dict):
            out[key] = add_counters(out.get(key, {}), value, skip)
        elif isinstance(value, (int, float)) and key.endswith("_max"):  # a peak: the largest, not a sum
            out[key] = max(out.get(key, value), value)
        elif isinstance(value, (int, float)):
            out[key] = out.get(key, 0) + value
    return out
