"""Shared fixtures for server tests: a real uvicorn server over the small real motion spaces.

The spaces (``built_spaces``) come from tests/conftest.py, built once per test run.
``live_server(...)`` starts ``morphspace serve`` in a subprocess bound to 127.0.0.1 on a free port
and stops it after the test (or module).
"""

from __future__ import annotations

import pytest

from live_server import LiveServer, data_dir_with_spaces, free_port  # noqa: F401 (re-exported)


@pytest.fixture(scope="module")
def server(built_spaces, tmp_path_factory):
    """A running server with the speed and jump spaces (shared by a module's tests)."""
    data = data_dir_with_spaces(tmp_path_factory.mktemp("server-data"), built_spaces)
    with LiveServer(data) as live:
        yield live
