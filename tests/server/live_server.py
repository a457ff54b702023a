"""A real ``morphspace serve`` for tests: ``LiveServer``, ``free_port``, ``data_dir_with_spaces``,
``data_dir_with_graph``.

A module of its own (not conftest.py) so test files import it by a name no other test
directory uses: ``from live_server import LiveServer`` works whichever test directories one
pytest run collects (``conftest`` would resolve to the first directory's).
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop_with_parent():
    """In the server's process before it runs: SIGTERM when the test process dies (Linux's
    PR_SET_PDEATHSIG), so a pytest killed by a timeout leaves no server behind."""
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # 1: PR_SET_PDEATHSIG


def _in_the_server(ctrl_c):
    _stop_with_parent()
    if ctrl_c is not None:
        signal.signal(signal.SIGINT, ctrl_c)


class LiveServer:
    """A ``morphspace serve`` subprocess on 127.0.0.1. ``ctrl_c``: SIGINT's disposition in it
    (``signal.SIG_DFL`` a terminal's, ``signal.SIG_IGN`` a shell's background job's; None: this
    process's, which is ignored when the test suite itself runs in the background)."""

    def __init__(self, data_dir, env=None, args=(), ctrl_c=None):
        self.data_dir = Path(data_dir)
        self.ctrl_c = ctrl_c
        self.args = list(args)  # more `morphspace serve` options (e.g. --workers 2)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.ws_url = f"ws://127.0.0.1:{self.port}/v1/stream"
        self.env = dict(os.environ, **(env or {}))
        self.process = None
        self.log = self.data_dir / "server.log"

    def start(self, timeout=60.0):
        self.data_dir.mkdir(parents=True, exist_ok=True)
        with open(self.log, "ab") as log:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "server.cli", "serve", "--data-dir", str(self.data_dir),
                 "--port", str(self.port), "--log-level", "warning", *self.args],
                stdout=log, stderr=subprocess.STDOUT, env=self.env, start_new_session=True,
                preexec_fn=functools.partial(_in_the_server, self.ctrl_c))
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"the server exited ({self.process.returncode}):\n{self.log.read_text()[-3000:]}")
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(self.url + "/v1/health", timeout=1.0).status_code == 200:
                    return self
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"the server did not come up in {timeout} s:\n{self.log.read_text()[-3000:]}")

    def stop(self, timeout=10.0):
        if self.process is None or self.process.poll() is not None:
            return
        os.killpg(self.process.pid, signal.SIGTERM)
        try:
            self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(timeout)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


def data_dir_with_spaces(path, built_spaces, names=("speed", "jump")):
    """A data directory whose spaces/ holds copies of the built test spaces."""
    spaces = Path(path) / "spaces"
    spaces.mkdir(parents=True, exist_ok=True)
    for name in names:
        shutil.copyfile(built_spaces / f"{name}.mspace", spaces / f"{name}.mspace")
    return Path(path)


def data_dir_with_graph(path, built_graph):
    """A data directory whose spaces/ holds copies of the built test graph (tiny.mgraph) and its
    spaces (walk, stand, jump, reach)."""
    spaces = Path(path) / "spaces"
    spaces.mkdir(parents=True, exist_ok=True)
    for name in ("walk.mspace", "stand.mspace", "jump.mspace", "reach.mspace", "tiny.mgraph"):
        shutil.copyfile(built_graph / name, spaces / name)
    return Path(path)
