"""REST exports of recorded motion-graph performances against a real server: a short one at once,
a long one as an ``export`` job; both are the engine's replay of the recording (validator-clean
glTF read back to its frames); bad recordings are 4xx errors naming the problem."""

from __future__ import annotations

import importlib.util
import json
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from live_server import LiveServer, data_dir_with_graph

from engine.export import play_performance, scripted_recording
from engine.graph import MotionGraph

ROOT = Path(__file__).resolve().parents[2]
LIMIT = 100_000  # vertex-frames: 100 frames of the 1,000-vertex tiny graph


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


gltf_reader = _load("morphspace_gltf_reader", ROOT / "tests" / "engine" / "gltf_reader.py")
gltf_validator = _load("morphspace_gltf_validator", ROOT / "tests" / "engine" / "gltf_validator.py")


@pytest.fixture(scope="module")
def client(built_graph, tmp_path_factory):
    data = data_dir_with_graph(tmp_path_factory.mktemp("graph-exports"), built_graph)
    with LiveServer(data, env={"MORPHSPACE_EXPORT_SYNC_MAX_VERTEX_FRAMES": str(LIMIT)}) as live:
        with httpx.Client(base_url=live.url, timeout=120) as client:
            yield client


def recording(built_graph, seconds):
    """walk -> jump -> (stand) -> walk on at 24 frames/s, with its frames played by the engine."""
    with MotionGraph.open(built_graph / "tiny.mgraph") as graph:
        document = scripted_recording(graph, params={"speed": 1.1}, fps=24, seconds=seconds, requests=[
            {"time": 0.3, "node": "jump", "params": {"jump_height": 0.4}},
            {"time": 1.5, "node": "walk", "params": {"speed": 1.5}, "budget": 1.0}])
        frames, digest = play_performance(graph, document)
        world = np.stack([frames.world(k) for k in range(len(frames))]).astype(np.float64)
    return dict(document, frames_sha256=digest), world


def assert_valid_glb(data, tmp_path):
    path = tmp_path / "perf.glb"
    path.write_bytes(data)
    gltf_validator.assert_clean(gltf_validator.validate(path))


def test_a_short_performance_exports_at_once(client, built_graph, tmp_path):
    document, world = recording(built_graph, 2.0)
    response = client.post("/v1/graphs/tiny/export", json={"recording": document})
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "model/gltf-binary"
    assert response.headers["content-disposition"] == 'attachment; filename="tiny.glb"'
    assert response.headers["x-morphspace-frames"] == "49"
    assert response.headers["x-morphspace-frames-sha256"] == document["frames_sha256"]
    assert_valid_glb(response.content, tmp_path)
    _, vertices, _, _ = gltf_reader.animated_frames(response.content)
    assert np.abs(vertices - world).max() < 2e-5
    again = client.post("/v1/graphs/tiny/export", json={"recording": document})
    assert again.content == response.content  # deterministic
    usd = client.post("/v1/graphs/tiny/export", json={"recording": document, "format": "usd"})
    assert usd.status_code == 200 and usd.content[:8] == b"PXR-USDC"


def test_a_long_performance_is_an_export_job(client, built_graph, tmp_path):
    document, world = recording(built_graph, 6.0)
    refused = client.post("/v1/graphs/tiny/export", json={"recording": document})
    assert refused.status_code == 422 and "145 frames x 1000 vertices is too long" in refused.json()["detail"]
    assert '"graph": "tiny"' in refused.json()["detail"]
    clocked = client.post("/v1/jobs", json={"kind": "export", "graph": "tiny", "recording": document, "rate": 30})
    assert clocked.status_code == 422 and "replays its recording" in clocked.text and "leave out rate" in clocked.text
    response = client.post("/v1/jobs", json={"kind": "export", "graph": "tiny", "recording": document})
    assert response.status_code == 202, response.text
    job_id = response.json()["id"]
    # the record shows what the export uses, not a clip's defaults the recording overrides
    assert not {"duration", "rate", "params", "track", "mode", "smoothing"} & set(response.json()["params"])
    deadline = time.monotonic() + 180
    while (job := client.get(f"/v1/jobs/{job_id}").json())["status"] in ("queued", "running"):
        assert time.monotonic() < deadline, job
        time.sleep(0.2)
    assert job["status"] == "succeeded", job
    result = job["result"]
    assert result["graph"] == "tiny" and result["frames"] == 145 and result["url"] == f"/v1/exports/{job_id}.glb"
    assert any("exported 145 frames of tiny as glb" in line for line in job["log"])
    assert not any("differ" in line for line in job["log"])
    download = client.get(result["url"])
    assert download.status_code == 200
    assert_valid_glb(download.content, tmp_path)
    _, vertices, _, _ = gltf_reader.animated_frames(download.content)
    assert np.abs(vertices - world).max() < 2e-5
    assert client.delete(result["url"]).status_code == 204


def _changed(document, change):
    document = json.loads(json.dumps(document))
    change(document)
    return document


CHANGES = [
    (lambda d: d.update(graph_checksum="feedface"), 422, "the recording was made with graph 'tiny' (feedface)"),
    (lambda d: d["requests"][0].update(node="fly"), 422, "requests[0]: unknown node 'fly'"),
    (lambda d: d["requests"][0].update(params={"height": 1}), 422, "node 'jump' has no parameter 'height'"),
    (lambda d: d.update(format="something"), 422, "not a morphspace-graph-recording"),
    (lambda d: d.update(steps="many"), 422, "steps a non-negative integer"),
]


@pytest.mark.parametrize("change, status, message", CHANGES)
def test_bad_recordings_are_4xx_naming_the_problem(client, built_graph, change, status, message):
    document, _ = recording(built_graph, 2.0)
    bad = _changed(document, change)
    for response in (client.post("/v1/graphs/tiny/export", json={"recording": bad}),
                     client.post("/v1/jobs", json={"kind": "export", "graph": "tiny", "recording": bad})):
        assert response.status_code == status and message in response.text, response.text


@pytest.mark.parametrize("path, body, status, message", [
    ("/v1/graphs/nowhere/export", {"recording": {}}, 404, "no motion graph 'nowhere'"),
    ("/v1/graphs/tiny/export", {"recording": "session.json"}, 422, "recording"),
    ("/v1/graphs/tiny/export", {}, 422, "recording"),
    ("/v1/jobs", {"kind": "export", "graph": "tiny"}, 422, "graph needs one"),
    ("/v1/jobs", {"kind": "export", "space": "walk", "graph": "tiny", "recording": {}}, 422, "either space"),
    ("/v1/jobs", {"kind": "export", "graph": "nowhere", "recording": {}}, 404, "no motion graph 'nowhere'"),
])
def test_bad_requests_are_clear_errors(client, path, body, status, message):
    response = client.post(path, json=body)
    assert response.status_code == status and message in response.text, response.text
