"""Shared fixtures for server tests: small real motion spaces and a real uvicorn server.

The spaces are built once per test run (shared by the xdist workers through a lock file) from
the synthetic body at 1,000 vertices: a two-gait speed chain and a two-jump distance chain.
``live_server(...)`` starts ``morphspace serve`` in a subprocess bound to 127.0.0.1 on a free port
and stops it after the test (or module).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

FPS = 15.0


def _build_spaces(directory):
    from engine.motion_space import SourceClip, build_motion_space
    from engine.parameters import Layout
    from engine.synthetic import animate, build_body, gait, jump

    body = build_body(1000)
    clips = [SourceClip(f"gait_{v}", animate(body, gait(body.skeleton, v, cycles=2.0, fps=FPS)), FPS, True)
             for v in (0.9, 2.6)]
    build_motion_space(directory / "speed.mspace", clips, body.F, name="speed", epsilon=0.008, rest=body.V,
                       parameters={"layout": Layout("chain", 2, chain=(0, 1)), "names": ["speed"]})
    clips = [SourceClip(f"jump_{d}", animate(body, jump(body.skeleton, 0.3, d, fps=FPS)), FPS, False)
             for d in (0.3, 1.0)]
    build_motion_space(directory / "jump.mspace", clips, body.F, name="jump", epsilon=0.008, rest=body.V,
                       parameters={"layout": Layout("chain", 2, chain=(0, 1)), "names": ["jump_distance"]})


@pytest.fixture(scope="session")
def built_spaces(tmp_path_factory):
    """Directory with speed.mspace and jump.mspace (built once for all workers)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the run's directory, shared by its workers (not by other runs)
    root = base / "morphspace-test-spaces"
    root.mkdir(exist_ok=True)
    with open(root / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (root / "done").exists():
            _build_spaces(root)
            (root / "done").write_text("ok")
        fcntl.flock(lock, fcntl.LOCK_UN)
    return root


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class LiveServer:
    """A ``morphspace serve`` subprocess on 127.0.0.1."""

    def __init__(self, data_dir, env=None, args=()):
        self.data_dir = Path(data_dir)
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
                stdout=log, stderr=subprocess.STDOUT, env=self.env, start_new_session=True)
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


@pytest.fixture(scope="module")
def server(built_spaces, tmp_path_factory):
    """A running server with the speed and jump spaces (shared by a module's tests)."""
    data = data_dir_with_spaces(tmp_path_factory.mktemp("server-data"), built_spaces)
    with LiveServer(data) as live:
        yield live
