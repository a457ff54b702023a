"""Engine-client tests: clients running inside real game engines (headless) against a real server.

The server fixtures (small real motion spaces built once per run, a ``morphspace serve``
subprocess) come from tests/server/conftest.py and its live_server module, loaded by path so
the conftest modules do not shadow each other (as tests/browser does).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(name, module)
    spec.loader.exec_module(module)
    return sys.modules[name]


_SERVER_TESTS = Path(__file__).resolve().parents[1] / "server"
_load("live_server", _SERVER_TESTS / "live_server.py")  # what tests/server/conftest.py imports
server_fixtures = _load("morphspace_server_fixtures", _SERVER_TESTS / "conftest.py")
built_spaces = server_fixtures.built_spaces  # the session fixture, shared through its lock file
