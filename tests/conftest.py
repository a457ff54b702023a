"""Fixtures every test directory shares.

- ``build_once(name, build)``: a directory built once per test run and shared by the xdist
  workers (a lock file, then a ``done`` marker);
- ``built_spaces``: speed.mspace and jump.mspace, small real motion spaces from the synthetic body
  at 1,000 vertices (a two-gait speed chain and a two-jump distance chain), used by the server,
  browser and engine-client tests;
- ``built_steer``: steer.mspace, a speed x turn_rate fan of four gaits (its own directory, built
  once), used by the browser and the player tests;
- ``built_graph``: the tiny motion graph with a reach (engine.graph.tiny: walk, stand, jump, reach
  and tiny.mgraph in one directory, as a server's spaces directory holds them).

tests/server/live_server.py (``LiveServer``, ``data_dir_with_spaces``) is loaded here by path, so
every test directory can ``from live_server import ...`` without putting tests/server on the path.
"""

from __future__ import annotations

import fcntl
import importlib.util
import os
import sys
from pathlib import Path

import pytest

FPS = 15.0


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(name, module)
    spec.loader.exec_module(module)
    return sys.modules[name]


_load("live_server", Path(__file__).resolve().parent / "server" / "live_server.py")


@pytest.fixture(scope="session")
def build_once(tmp_path_factory):
    """``build_once(name, build)``: the run's directory ``name``, ``build(directory)`` called once
    for all workers (not shared with other runs)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the run's directory, shared by its workers

    def once(name, build):
        root = base / name
        root.mkdir(exist_ok=True)
        with open(root / ".lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (root / "done").exists():
                build(root)
                (root / "done").write_text("ok")
            fcntl.flock(lock, fcntl.LOCK_UN)
        return root

    return once


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


def _build_steer(directory):
    """speed x turn_rate (fan): gaits at 0.9 and 2.6 m/s, turns of +-40 deg/s at 1.5 m/s (1,000 vertices).
    Fast turns are out of its reach (clamped): what issue 15's first two items are about."""
    from engine.motion_space import SourceClip, build_motion_space
    from engine.parameters import Layout
    from engine.synthetic import animate, build_body, gait

    body = build_body(1000)
    gaits = [("slow", 0.9, 0.0), ("fast", 2.6, 0.0), ("left", 1.5, 40.0), ("right", 1.5, -40.0)]
    clips = [SourceClip(name, animate(body, gait(body.skeleton, v, turn_rate=r, cycles=1.0, fps=FPS)), FPS, True)
             for name, v, r in gaits]
    build_motion_space(directory / "steer.mspace", clips, body.F, name="steer", epsilon=0.008, rest=body.V,
                       parameters={"layout": Layout("fan", 4, chain=(0, 1), left=2, right=3),
                                   "names": ["speed", "turn_rate"]})


def _build_graph(directory):
    from engine.graph.tiny import build_tiny_graph, build_tiny_spaces

    build_tiny_spaces(directory, reach=True)
    build_tiny_graph(directory, directory / "tiny.mgraph", reach=True)


@pytest.fixture(scope="session")
def built_graph(build_once):
    """Directory with walk, stand, jump and reach .mspace files and tiny.mgraph joining them
    (walk <-> stand, stand -> jump, walk -> jump, jump -> stand, stand <-> reach; built once)."""
    return build_once("morphspace-test-graph", _build_graph)


@pytest.fixture(scope="session")
def built_spaces(build_once):
    """Directory with speed.mspace and jump.mspace (built once for all workers)."""
    return build_once("morphspace-test-spaces", _build_spaces)


@pytest.fixture(scope="session")
def built_steer(build_once):
    """Directory with steer.mspace (built once for all workers)."""
    return build_once("morphspace-test-steer", _build_steer)
