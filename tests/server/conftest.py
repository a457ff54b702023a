"""Shared fixtures for server tests: small real motion spaces and a real uvicorn server.

The spaces are built once per test run (shared by the xdist workers through a lock file) from
the synthetic body at 1,000 vertices: a two-gait speed chain and a two-jump distance chain.
``live_server(...)`` starts ``morphspace serve`` in a subprocess bound to 127.0.0.1 on a free port
and stops it after the test (or module).
"""

from __future__ import annotations

import fcntl
import os

import pytest

from live_server import LiveServer, data_dir_with_spaces, free_port  # noqa: F401 (re-exported)

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


@pytest.fixture(scope="module")
def server(built_spaces, tmp_path_factory):
    """A running server with the speed and jump spaces (shared by a module's tests)."""
    data = data_dir_with_spaces(tmp_path_factory.mktemp("server-data"), built_spaces)
    with LiveServer(data) as live:
        yield live
