"""The REST surface as documented: docs/rest.md covers every /v1 route and setting, the OpenAPI
schema is complete, and the server refuses an open bind without a token."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from live_server import LiveServer, free_port

from server.app import create_app
from server.settings import Settings

DOC = Path(__file__).resolve().parents[2] / "docs" / "rest.md"


def _shape(path):
    return re.sub(r"\{[^}]+\}", "{}", path)


def test_every_v1_route_is_documented(tmp_path):
    app = create_app(Settings(data_dir=tmp_path))
    text = DOC.read_text()
    documented = {(m, _shape(p)) for m, p in re.findall(r"^### `(GET|POST|DELETE|PUT|PATCH) (/v1/[^`?]*)", text,
                                                        re.M)}
    routes = {(method.upper(), _shape(path)) for path, operations in app.openapi()["paths"].items()
              if path.startswith("/v1") for method in operations}
    assert routes, "no routes"
    assert routes - documented == set(), "routes missing from docs/rest.md"
    assert documented - routes == set(), "docs/rest.md documents routes the server does not have"


def test_every_setting_is_documented():
    text = DOC.read_text()
    for name in Settings.model_fields:
        assert f"`MORPHSPACE_{name.upper()}`" in text, name


def test_openapi_is_complete(tmp_path):
    schema = create_app(Settings(data_dir=tmp_path)).openapi()
    for path, operations in schema["paths"].items():
        for method, operation in operations.items():
            assert operation.get("summary"), (method, path)
            assert any(code.startswith("2") for code in operation["responses"]), (method, path)
    upload = schema["paths"]["/v1/datasets"]["post"]
    assert {"application/zip", "multipart/form-data"} <= set(upload["requestBody"]["content"])
    assert {"401", "409", "413", "415", "422"} <= set(upload["responses"])
    job = schema["paths"]["/v1/jobs"]["post"]
    body = job["requestBody"]["content"]["application/json"]["schema"]
    assert body["discriminator"]["propertyName"] == "kind"
    assert set(body["discriminator"]["mapping"]) == {"build", "align", "ingest", "export", "graph"}
    for model in ("JobRecord", "BuildSpec", "DatasetInfo"):
        assert model in schema["components"]["schemas"], model


def test_serve_refuses_an_open_bind_without_a_token(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("MORPHSPACE_TOKEN", "MORPHSPACE_ALLOW_OPEN_BIND")}
    run = subprocess.run([sys.executable, "-m", "server.cli", "serve", "--host", "0.0.0.0", "--port",
                          str(free_port()), "--data-dir", str(tmp_path / "data")],
                         env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, (run.returncode, run.stdout, run.stderr)
    assert "refusing to bind 0.0.0.0 without a token" in run.stderr
    assert "MORPHSPACE_TOKEN" in run.stderr


@pytest.mark.parametrize("args, env, line", [
    (["--port", "99999"], {}, "morphspace serve: error: --port 99999: Input should be less than or equal to 65535"),
    (["--stall-timeout", "0"], {}, "morphspace serve: error: --stall-timeout 0.0: Input should be greater than 0"),
    ([], {"MORPHSPACE_STREAM_MAX_FPS": "-1"}, "morphspace serve: error: MORPHSPACE_STREAM_MAX_FPS=-1: Input should be "
                                              "greater than 0"),
])
def test_serve_names_the_option_or_variable_of_a_bad_setting_on_one_line(tmp_path, args, env, line):
    """Not pydantic's several-line report in the settings' own field names (``stream_stall_timeout``);
    found by a docs-only user."""
    run = subprocess.run([sys.executable, "-m", "server.cli", "serve", "--data-dir", str(tmp_path / "data"), *args],
                         env={**os.environ, **env}, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.strip() == line, (run.returncode, run.stderr)
    assert not (tmp_path / "data").exists()


@pytest.mark.parametrize("signum, status, word", [(signal.SIGINT, 130, "interrupted"),
                                                  (signal.SIGTERM, 143, "terminated")])
def test_serve_ends_on_ctrl_c_and_sigterm_as_every_command_does(tmp_path, signum, status, word):
    """docs/cli.md: Ctrl-C ends a command with `interrupted` and status 130, SIGTERM with
    `terminated` and 143, serve included once it has stopped gracefully (it ended with status 0
    on Ctrl-C and was killed by SIGTERM after its stop, both without a word; a docs-only user)."""
    with LiveServer(tmp_path / "data", ctrl_c=signal.SIG_DFL) as server:   # answering: uvicorn has the signals
        server.process.send_signal(signum)
        server.process.wait(60)
    log = server.log.read_text()
    assert "morphspace: serving" in log.splitlines()[0], log[:2000]
    assert server.process.returncode == status, (server.process.returncode, log[-2000:])
    assert log.rstrip().splitlines()[-1] == f"morphspace serve: {word}", log[-2000:]


def test_serve_started_with_ctrl_c_ignored_keeps_ignoring_it(tmp_path):
    """As every other command does (Python keeps an inherited SIG_IGN). uvicorn stopped on it, then
    ended with status 0 and no word: a flaky failure when the suite ran in the background."""
    with LiveServer(tmp_path / "data", ctrl_c=signal.SIG_IGN) as server:
        server.process.send_signal(signal.SIGINT)
        time.sleep(1.0)   # uvicorn's loop looks at its exit flag every 0.1 s
        assert server.process.poll() is None
        assert httpx.get(server.url + "/v1/health", timeout=10).status_code == 200
        server.process.send_signal(signal.SIGTERM)
        server.process.wait(60)
    log = server.log.read_text()
    assert server.process.returncode == 143 and log.rstrip().splitlines()[-1] == "morphspace serve: terminated", log


def _documented_keys(text, after):
    """The keys of the first `{"a", "b", ...}` list in docs/rest.md after ``after``."""
    listing = re.search(r"`(\{[^`]*\})`", text[text.index(after):]).group(1)
    return set(re.findall(r"(?<!: )\"(\w+)\"", listing))  # keys, not values ("executor": "local")


def test_health_answers_what_rest_md_says(tmp_path):
    """/v1/health's keys, and its ``jobs`` record's on the local executor, are the documented ones."""
    from live_server import LiveServer

    text = DOC.read_text()
    with LiveServer(tmp_path / "data") as server:
        health = httpx.get(server.url + "/v1/health", timeout=10).json()
    assert set(health) == _documented_keys(text, "### `GET /v1/health`")
    assert set(health["jobs"]) == _documented_keys(text, "- `jobs`: what runs the jobs")
    assert health["jobs"]["executor"] == "local" and health["jobs"]["queued"] == 0
