"""REST exports against a real server: a short clip at once (glTF, USD, an OBJ zip), a long one
as an ``export`` job whose file is downloaded; the files pass the reference validators and
read back as the engine's frames; bad requests are clear errors."""

from __future__ import annotations

import importlib.util
import io
import json
import subprocess
import time
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from engine.export import Clip, play_clip
from engine.mesh_io import read_sequence
from engine.motion_space import MotionSpace

ROOT = Path(__file__).resolve().parents[2]


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


gltf_reader = _load("morphspace_gltf_reader", ROOT / "tests" / "engine" / "gltf_reader.py")
CLIP = {"params": {"speed": 1.2}, "track": [{"time": 1.0, "params": {"speed": 2.4}}], "duration": 2.0, "rate": 30}


@pytest.fixture(scope="module")
def client(server):
    with httpx.Client(base_url=server.url, timeout=120) as client:
        yield client


@pytest.fixture(scope="module")
def reference(built_spaces):
    """The engine's frames for CLIP, placed in world coordinates."""
    with MotionSpace.open(built_spaces / "speed.mspace") as space:
        frames = play_clip(space, Clip(params={"speed": 1.2}, track=((1.0, {"speed": 2.4}),), duration=2.0, rate=30))
        return frames, np.stack([frames.world(k) for k in range(len(frames))]).astype(np.float64)


def assert_valid_glb(data, tmp_path):
    path = tmp_path / "clip.glb"
    path.write_bytes(data)
    run = subprocess.run(["node", str(ROOT / "tests" / "validators" / "validate_gltf.js"), str(path)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    issues = json.loads(run.stdout)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_a_short_clip_exports_at_once_as_glb(client, reference, tmp_path):
    response = client.post("/v1/spaces/speed/export", json={"format": "glb", **CLIP})
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "model/gltf-binary"
    assert response.headers["content-disposition"] == 'attachment; filename="speed.glb"'
    assert response.headers["x-morphspace-frames"] == "61"
    assert_valid_glb(response.content, tmp_path)
    frames, world = reference
    times, vertices, _, _ = gltf_reader.animated_frames(response.content)
    assert len(times) == 61 and np.abs(vertices - world).max() < 2e-5  # int16: 0.014 mm steps


@pytest.mark.parametrize("mode", ["hybrid", "linear"])
def test_the_same_export_gives_the_same_bytes_every_time(client, built_spaces, tmp_path, mode):
    """Whatever was exported before (a docs-only user found the second and third of three equal
    requests differing from the first, and from the CLI, in the last float bit: phase tables kept
    from the earlier exports); and the same bytes as the engine's own export of the clip."""
    from engine.export import write_export

    body = {"format": "usd", "mode": mode, "params": {"speed": 1.1}, "duration": 3.0, "rate": 30}
    answers = [client.post("/v1/spaces/speed/export", json=body) for _ in range(3)]
    assert all(r.status_code == 200 for r in answers), answers[0].text
    assert answers[0].content == answers[1].content == answers[2].content
    with MotionSpace.open(built_spaces / "speed.mspace") as space:
        write_export(tmp_path / "speed.usd", play_clip(space, Clip(params={"speed": 1.1}, duration=3.0, rate=30,
                                                                    mode=mode)), "usd")
    assert answers[0].content == (tmp_path / "speed.usd").read_bytes()


def test_usd_and_an_obj_zip_at_once(client, reference, tmp_path):
    from pxr import Usd, UsdGeom

    frames, world = reference
    response = client.post("/v1/spaces/speed/export", json={"format": "usd", **CLIP})
    assert response.status_code == 200 and response.headers["content-type"] == "application/octet-stream"
    (tmp_path / "clip.usd").write_bytes(response.content)
    stage = Usd.Stage.Open(str(tmp_path / "clip.usd"))
    assert stage.GetTimeCodesPerSecond() == 30 and UsdGeom.GetStageUpAxis(stage) == "Y"
    points = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/speed/mesh")).GetPointsAttr().Get(Usd.TimeCode(40)))
    assert np.abs(points - frames.local[40]).max() < 1e-6
    response = client.post("/v1/spaces/speed/export", json={"format": "obj", **CLIP})
    assert response.status_code == 200 and response.headers["content-type"] == "application/zip"
    (tmp_path / "clip.zip").write_bytes(response.content)
    assert np.abs(read_sequence(tmp_path / "clip.zip").vertices - world).max() < 1e-6
    response = client.post("/v1/spaces/speed/export", json={"format": "vat", **CLIP})
    assert response.status_code == 200 and response.headers["content-type"] == "application/zip"
    archive = zipfile.ZipFile(io.BytesIO(response.content))
    assert json.loads(archive.read("vat.json"))["frames"] == 61 and archive.read("positions.png")[:4] == b"\x89PNG"


@pytest.mark.parametrize("path, body, status, message", [
    ("/v1/spaces/nowhere/export", {}, 404, "no motion space 'nowhere'"),
    ("/v1/spaces/speed/export", {"params": {"speed": 9}}, 422, "params: speed = 9 m/s is out of range; speed spans"),
    ("/v1/spaces/speed/export", {"params": {"pace": 1}}, 422, "unknown parameter 'pace'; speed has speed"),
    ("/v1/spaces/speed/export", {"track": [{"time": 30, "params": {"speed": 1}}]}, 422, "outside the clip [0, 10] s"),
    ("/v1/spaces/speed/export", {"format": "fbx"}, 422, "glb"),
    ("/v1/spaces/speed/export", {"duration": 30}, 422,
     "1801 frames x 1000 vertices is too long to export synchronously"),
])
def test_bad_requests_are_clear_errors(client, path, body, status, message):
    response = client.post(path, json=body)
    assert response.status_code == status and message in response.text, response.text
    if "too long" in message:
        assert '"kind": "export"' in response.json()["detail"] and "POST /v1/jobs" in response.json()["detail"]


def test_a_long_clip_is_an_export_job_with_a_download(client, reference, tmp_path):
    response = client.post("/v1/jobs", json={"kind": "export", "space": "speed", "format": "glb", **CLIP})
    assert response.status_code == 202, response.text
    job_id = response.json()["id"]
    deadline = time.monotonic() + 120
    while (job := client.get(f"/v1/jobs/{job_id}").json())["status"] in ("queued", "running"):
        assert time.monotonic() < deadline, job
        time.sleep(0.2)
    assert job["status"] == "succeeded", job
    result = job["result"]
    assert result["url"] == f"/v1/exports/{job_id}.glb" and result["frames"] == 61 and result["format"] == "glb"
    assert any("exported 61 frames of speed as glb" in line for line in job["log"])
    download = client.get(result["url"])
    assert download.status_code == 200 and download.headers["content-type"] == "model/gltf-binary"
    assert len(download.content) == result["bytes"]
    assert_valid_glb(download.content, tmp_path)
    _, vertices, _, _ = gltf_reader.animated_frames(download.content)
    assert np.abs(vertices - reference[1]).max() < 2e-5
    assert client.get("/v1/jobs", params={"kind": "export"}).json()["jobs"][0]["id"] == job_id
    assert client.delete(result["url"]).status_code == 204
    assert client.get(result["url"]).status_code == 404


@pytest.mark.parametrize("body, status, message", [
    ({"kind": "export", "space": "nowhere"}, 404, "no motion space 'nowhere'"),
    ({"kind": "export", "space": "speed", "params": {"speed": 0.1}}, 422, "speed = 0.1 m/s is out of range"),
    ({"kind": "export", "space": "speed", "rate": 0}, 422, "rate"),
])
def test_bad_export_jobs_are_refused(client, body, status, message):
    response = client.post("/v1/jobs", json=body)
    assert response.status_code == status and message in response.text, response.text


def test_unknown_downloads_are_404(client):
    for name in ("0123456789abcdef.glb", "../jobs.sqlite", "x.txt"):
        assert client.get(f"/v1/exports/{name}").status_code == 404

