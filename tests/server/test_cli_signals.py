"""SIGTERM ends a command's worker processes with it (docs/cli.md: "both run the command's clean-up
first: its worker processes end").

A docs-only trial sent SIGTERM to `morphspace align` while its two worker processes raced roots:
the workers ran on at full CPU and the command ended only 38 s later, when the race had finished,
as a service manager's or `docker stop`'s SIGTERM would wait (Ctrl-C to the process group ended
it in 2 s, as the workers got it too).
"""

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from server.cli import main


def _descendants(pid):
    """The pids of ``pid``'s descendants (Linux /proc): the worker processes of a forkserver pool are
    the forkserver's children, not the command's."""
    found, todo = set(), [pid]
    while todo:
        for task in Path(f"/proc/{todo.pop()}/task").glob("*"):
            try:
                children = {int(c) for c in (task / "children").read_text().split()} - found
            except OSError:
                continue
            found |= children
            todo.extend(children)
    return found


def _running(pid):
    """Whether ``pid`` is a live process (not gone, not a zombie)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.fixture(scope="module")
def studio_tiny(tmp_path_factory):
    data = tmp_path_factory.mktemp("signals") / "studio-tiny"
    assert main(["synth", "--preset", "studio-tiny", "--out", str(data), "--workers", "2", "--no-previews"]) == 0
    return data


def test_sigterm_ends_the_worker_processes_at_once(studio_tiny, tmp_path):
    data = tmp_path / "studio-tiny"
    shutil.copytree(studio_tiny, data)
    command = [sys.executable, "-m", "server.cli", "align", str(data), "--out", str(tmp_path / "out"), "--workers", "2"]
    process = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE)
    seen = []
    reader = threading.Thread(target=lambda: seen.extend(iter(lambda: os.read(process.stderr.fileno(), 4096), b"")),
                              daemon=True)
    reader.start()
    deadline = time.monotonic() + 300
    while b"race roots" not in b"".join(seen) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)   # until the workers race the roots (two whole trees, tens of seconds each)
    assert process.poll() is None, b"".join(seen).decode()[-2000:]
    time.sleep(1.0)
    workers = _descendants(process.pid)
    assert len(workers) >= 2, "no worker processes to end"
    sent = time.monotonic()
    process.send_signal(signal.SIGTERM)
    process.wait(timeout=120)
    took = time.monotonic() - sent
    reader.join(timeout=10)
    stderr = b"".join(seen).decode()
    assert process.returncode == 143 and stderr.rstrip().endswith("morphspace align: terminated"), stderr[-2000:]
    assert took < 10, f"the command ended {took:.1f} s after SIGTERM"
    deadline = time.monotonic() + 10
    while any(_running(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.05)   # the forkserver and resource tracker leave when the command's pipes close
    assert not [pid for pid in workers if _running(pid)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["studio-tiny"]   # no output, no staging left


def test_sigterm_while_the_workers_start_ends_quietly(studio_tiny, tmp_path):
    """SIGTERM as the root trial's pool starts its workers: a worker forked but not yet registered
    as a child process used to outlive the command, unpickle its start-up data after the pool's
    semaphores were unlinked and print a FileNotFoundError (or EOFError) traceback after
    "terminated", or the forkserver died on a half-sent request with an EOFError traceback (4 runs
    of 6 before the fix; after it 0 of 14 with two busy loops beside). Three tries."""
    command = [sys.executable, "-m", "server.cli", "align", str(studio_tiny), "--out", str(tmp_path / "out"),
               "--workers", "2"]
    for _ in range(3):
        process = subprocess.Popen(command, cwd=tmp_path, stderr=subprocess.PIPE)
        seen = []
        reader = threading.Thread(target=lambda: seen.extend(iter(lambda: os.read(process.stderr.fileno(), 4096),
                                                                   b"")), daemon=True)
        reader.start()
        deadline = time.monotonic() + 120
        while b"try roots" not in b"".join(seen) and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert process.poll() is None, b"".join(seen).decode()[-2000:]
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=60)
        reader.join(timeout=10)
        time.sleep(0.5)  # a worker left running would print its traceback to the same stderr by now
        stderr = b"".join(seen).decode(errors="replace")
        assert process.returncode == 143 and stderr.rstrip().endswith("morphspace align: terminated"), stderr[-2000:]
        assert "Traceback" not in stderr, stderr[-2000:]
        assert sorted(p.name for p in tmp_path.iterdir()) == []   # no output, no staging left
