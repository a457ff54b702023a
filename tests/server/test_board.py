"""server/workers/board.py: the counter board's blobs, sequence lock and sums."""

from __future__ import annotations

import os

from server.workers.board import _HEAD, CounterBoard, add_counters


def test_a_published_record_reads_back_and_retiring_keeps_its_totals():
    board = CounterBoard(2)
    board.publish(1, 1234, {"frames_sent": 5, "connections": 2, "scheduler": {"frames": 7, "transport_bytes_max": 9}})
    assert board.worker(1)["counters"]["frames_sent"] == 5 and board.worker(1)["pid"] == 1234
    board.set_slot(1, pid=1234, restarts=0)
    board.retire(1)
    assert board.worker(1) == {}
    assert board.retired() == {"frames_sent": 5, "scheduler": {"frames": 7, "transport_bytes_max": 9}}  # not the gauge


def test_a_writer_killed_mid_write_does_not_leave_the_blob_unreadable():
    """A SIGKILL between a write's two sequence updates leaves the sequence odd; the next write
    (the supervisor retiring the dead worker, then the new worker publishing) must leave a
    readable blob, not one whose parity is inverted for good."""
    board = CounterBoard(1)
    board.publish(0, os.getpid(), {"frames_sent": 1})
    sequence, length = _HEAD.unpack_from(board._memory, 0)
    _HEAD.pack_into(board._memory, 0, sequence + 1, length)  # killed right after marking it odd
    assert board.worker(0) == {}  # being written: readers give up on it
    board.retire(0)
    board.publish(0, 4321, {"frames_sent": 3})
    assert board.worker(0)["pid"] == 4321 and board.worker(0)["counters"] == {"frames_sent": 3}
    assert _HEAD.unpack_from(board._memory, 0)[0] % 2 == 0


def test_counters_add_key_by_key_and_peaks_take_the_largest():
    a = {"frames": 2, "scheduler": {"ticks": 1, "transport_bytes_max": 10}}
    b = {"frames": 3, "connections": 4, "scheduler": {"ticks": 2, "transport_bytes_max": 7}, "flag": True}
    assert add_counters(a, b, skip={"connections"}) == {"frames": 5, "scheduler": {"ticks": 3, "transport_bytes_max": 10}}
    assert a == {"frames": 2, "scheduler": {"ticks": 1, "transport_bytes_max": 10}}  # unchanged


def test_a_worker_between_its_end_and_its_restart_reports_every_counter_as_zero():
    """docs/rest.md lists ``connections``, ``frames_sent``, ... in every worker record, also for
    a worker that has ended and not yet started again (a client parsing health crashed on it)."""
    board = CounterBoard(2)
    mine = {"connections": 3, "frames_sent": 10, "frames_dropped": 1, "stream_errors": 0,
            "scheduler": {"ticks": 4, "transport_bytes_max": 900}}
    board.set_slot(0, pid=100, started_at=1.0, restarts=0)
    board.publish(0, 100, mine)
    board.set_slot(1, pid=None, restarts=1, last_exit="pid 101 was killed by SIGKILL")
    workers, totals, _ = board.summary(shape=mine)
    assert workers[0]["alive"] and workers[0]["frames_sent"] == 10
    ended = workers[1]
    assert not ended["alive"] and ended["pid"] is None and ended["published_ago"] is None
    assert {key: ended[key] for key in mine} == {"connections": 0, "frames_sent": 0, "frames_dropped": 0,
                                                 "stream_errors": 0,
                                                 "scheduler": {"ticks": 0, "transport_bytes_max": 0}}
    assert totals["frames_sent"] == 10
