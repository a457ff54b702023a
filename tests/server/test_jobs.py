"""Jobs against a live server: upload then build, progress, cancel, a killed worker, a crashed server.

The dataset is two short synthetic gaits at 1,000 vertices (10 fps, one cycle each); a build at 8
phases takes about 10-15 s here, most of it tetrahedralisation (cached per data directory).
"""

from __future__ import annotations

import io
import json
import os
import signal
import shutil
import tempfile
import time
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest
from live_server import LiveServer

from engine.mesh_io import read_mesh
from server.cli import main as cli_main
from server.commands.align_output import stopped_text
from server.units import count_text

TOKEN = "test-token-jobs"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
SEQUENCES = {"slow": 0.9, "fast": 2.6}
FINAL = ("succeeded", "failed", "cancelled")


def capture_zip(fps=10.0, units="m", up="y"):
    """A zip of two synthetic gait sequences (<seq>/frame_NNNN.obj + meta.json), in ``units`` with
    ``up`` up (the meta.json says nothing about either)."""
    from engine.mesh_io import write_obj
    from engine.mesh_io.units import from_metres_y_up
    from engine.synthetic import animate, build_body, gait

    body = build_body(1000)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        with tempfile.TemporaryDirectory() as tmp:
            for name, speed in SEQUENCES.items():
                V = animate(body, gait(body.skeleton, speed, cycles=1.0, fps=fps))
                for k, frame in enumerate(V):
                    path = Path(tmp) / f"{name}_{k}.obj"
                    write_obj(path, from_metres_y_up(frame, units, up), body.F, precision=6)
                    archive.write(path, f"{name}/frame_{k:04d}.obj")
                archive.writestr(f"{name}/meta.json", json.dumps({"fps": fps, "cyclic": True}))
    return buffer.getvalue()


def build_request(space, dataset="gaits", **extra):
    return {"kind": "build", "dataset": dataset, "space": space,
            "spec": {"sources": list(SEQUENCES), "phases": 8, "epsilon_mm": 10.0,
                     "parameters": {"layout": "chain", "chain": list(SEQUENCES), "measures": ["speed"],
                                    "resolution": 5}}, **extra}


def wait_for(client, job_id, until, timeout=60.0, seen=None, every=0.1):
    """Poll a job every ``every`` s until ``until(record)``; every record goes to ``seen``. Fails
    after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if seen is not None:
            seen.append(job)
        if until(job):
            return job
        time.sleep(every)
    raise AssertionError(f"job {job_id} did not get there in {timeout} s: {job}")


def pid_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not yet reaped) is not alive
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def wait_dead(pid, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not pid_alive(pid):
            return True
        time.sleep(0.05)
    return False


@pytest.fixture(scope="module")
def dataset_zip():
    return capture_zip()


@pytest.fixture(scope="module")
def live(tmp_path_factory, dataset_zip):
    with LiveServer(tmp_path_factory.mktemp("jobs-data"), env={"MORPHSPACE_TOKEN": TOKEN}) as server:
        with httpx.Client(base_url=server.url, timeout=30.0) as client:
            r = client.post("/v1/datasets", params={"name": "gaits"}, content=dataset_zip,
                            headers={**AUTH, "Content-Type": "application/zip"})
            assert r.status_code == 201, r.text
        yield server


@pytest.fixture()
def client(live):
    with httpx.Client(base_url=live.url, timeout=30.0) as c:
        yield c


def test_upload_build_and_the_space_appears(client, live):
    assert client.post("/v1/jobs", json=build_request("gaitspace")).status_code == 401
    r = client.post("/v1/jobs", json=build_request("gaitspace"), headers=AUTH)
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["status"] == "queued" and r.headers["location"] == f"/v1/jobs/{job['id']}"
    seen = []
    # polled often: the build takes a second or two (its tets' split is compiled since session 55)
    job = wait_for(client, job["id"], lambda j: j["status"] in FINAL, timeout=90, seen=seen, every=0.01)
    assert job["status"] == "succeeded", job
    progress = [j["progress"] for j in seen if j["status"] == "running"]
    assert progress == sorted(progress), "progress went backwards"
    # at least two values between 0 and 1 (three were asked for until session 56: the build now
    # sends only a few, at most every 0.2 s and at each stage, and one suite run under load saw
    # 0.35 and 0.5187 between the zeros and the end)
    assert len({p for p in progress if 0 < p < 1}) >= 2, progress
    # the stages polled, and every stage the job's log names (a fast stage can fall between polls)
    stages = {j["stage"] for j in seen} | {line.split("stage ", 1)[1].strip() for line in job["log"]
                                           if "stage " in line}
    assert {"tetrahedralise", "decompose"} <= stages or {"decompose", "parameters"} <= stages, stages
    assert job["progress"] == 1 and job["attempts"] == 1 and job["error"] is None
    assert job["result"]["url"] == "/v1/spaces/gaitspace" and job["result"]["n_sources"] == 2
    assert any("published" in line for line in job["log"])
    assert any(line.startswith("source slow, fast") and "units m (detected" in line for line in job["log"]), job["log"]
    assert (job["result"]["source_units"], job["result"]["source_up"]) == ("m", "+Y")
    spaces = {s["name"]: s for s in client.get("/v1/spaces").json()["spaces"]}
    assert spaces["gaitspace"]["n_vertices"] == 1000 and spaces["gaitspace"]["parameters"][0]["name"] == "speed"
    assert client.get("/v1/spaces/gaitspace/frame", params={"format": "json", "params": "speed:1.5"}).status_code == 200
    assert list((live.data_dir / "work" / "jobs").iterdir()) == []  # staging removed
    listed = client.get("/v1/jobs", params={"status": "succeeded"}).json()["jobs"]
    assert job["id"] in [j["id"] for j in listed]
    assert client.get("/v1/jobs", params={"status": "running"}).json()["jobs"] == []
    r = client.post("/v1/jobs", json=build_request("gaitspace"), headers=AUTH)
    assert r.status_code == 409 and "already exists" in r.json()["detail"]


def test_bad_job_requests_name_the_problem(client):
    cases = [
        (build_request("x", dataset="nope"), 404, "no dataset 'nope'"),
        ({**build_request("x"), "spec": {**build_request("x")["spec"], "sources": ["slow", "walk"],
                                         "parameters": {**build_request("x")["spec"]["parameters"],
                                                        "chain": ["slow", "walk"]}}}, 422, "'walk'"),
        ({**build_request("x"), "kind": "paint"}, 422, "kind"),
        ({**build_request("../x")}, 422, "space"),
        ({**build_request("x"), "spec": {"sources": ["slow", "fast"], "parameters": {"layout": "chain",
                                                                                  "measures": ["speed"]}}},
         422, "chain"),
        ({**build_request("x"), "spec": {"sources": ["slow", "fast"], "rest": "../../etc/passwd"}}, 422, "rest"),
        # every name a job writes is one the endpoints can address (found by a docs-only user)
        (build_request("a..b"), 422, "'a..b': '..' is not allowed in names"),
        ({"kind": "ingest", "dataset": "gaits", "output": "d..x"}, 422, "'..' is not allowed"),
        ({"kind": "align", "datasets": ["gaits"], "output": "x..y"}, 422, "'..' is not allowed"),
        ({"kind": "graph", "graph": "g..h", "nodes": [{"name": "a", "space": "s"}, {"name": "b", "space": "t"}],
          "edges": [["a", "b"]]}, 422, "'..' is not allowed"),
        # the layout is checked as `morphspace build` checks a spec, before anything is queued
        ({**build_request("x"), "spec": {"sources": ["slow", "fast"], "parameters": {
            "layout": "chain", "chain": ["slow", "jog"], "measures": ["speed"]}}}, 422,
         "parameters refer to 'jog', which is not among the sources"),
        ({**build_request("x"), "spec": {"sources": ["slow", "fast", "walk"], "parameters": {
            "layout": "chain", "chain": ["slow", "fast"], "measures": ["speed"]}}}, 422,
         "the chain layout leaves out 'walk'"),
        ({**build_request("x"), "spec": {"sources": ["slow", "fast"], "parameters": {
            "layout": "chain", "chain": ["slow", "fast"], "left": "slow", "measures": ["speed"]}}}, 422,
         "left is not part of a chain layout"),
        ({"kind": "graph", "graph": "g", "nodes": [{"name": "a", "space": "s"}, {"name": "b", "space": "t"},
                                                   {"name": "c", "space": "s"}],
          "edges": [["a", "b"], ["b", "a"]]}, 422, "node 'c' cannot be reached from 'a' along the edges"),
        ({"kind": "align", "datasets": ["gaits"], "output": "aligned", "root": "zzz:9"}, 422,
         "root zzz:9: no sequence 'zzz'; sequences are "),
        ({"kind": "align", "datasets": ["gaits"], "output": "aligned", "root": "slow:x"}, 422,
         "root slow:x: frame must be an integer"),
        ({"kind": "align", "datasets": ["gaits"], "output": "aligned", "root": "slow:0", "root_choice": "race"}, 422,
         "root_choice race: the root is given (root slow:0), so no root is chosen"),
        # sequences and the root's frame as `morphspace align` checks them, before anything is queued
        # (both were queued and failed a second later; found by a docs-only user)
        ({"kind": "align", "datasets": ["gaits"], "output": "aligned", "only": ["nope"]}, 422,
         '"datasets/gaits: no sequence(s) nope; it has '),
        ({"kind": "align", "datasets": ["gaits"], "output": "aligned", "root": "slow:999"}, 422,
         "root slow:999: sequence slow has frames 0.."),
        ({"kind": "align", "datasets": ["gaits"], "output": "aligned", "only": ["fast"], "root": "slow:0"}, 422,
         "root slow:0: no sequence 'slow'; sequences are fast"),
    ]
    for body, status, words in cases:
        r = client.post("/v1/jobs", json=body, headers=AUTH)
        assert r.status_code == status, (body, r.text)
        assert words in r.text, (words, r.text)
    assert client.get("/v1/jobs/doesnotexist").status_code == 404
    assert client.post("/v1/jobs/doesnotexist/cancel", headers=AUTH).status_code == 404


def test_cancel_a_running_and_a_queued_job(client, live):
    running = client.post("/v1/jobs", json=build_request("cancelled_space"), headers=AUTH).json()
    queued = client.post("/v1/jobs", json=build_request("never_space"), headers=AUTH).json()
    job = wait_for(client, running["id"], lambda j: j["status"] == "running" and (j["worker"] or {}).get("pid"))
    pid = job["worker"]["pid"]
    assert client.get(f"/v1/jobs/{queued['id']}").json()["status"] == "queued"  # one local worker slot
    r = client.post(f"/v1/jobs/{queued['id']}/cancel", headers=AUTH)
    assert r.status_code == 200 and r.json()["status"] == "cancelled"
    assert client.post(f"/v1/jobs/{running['id']}/cancel").status_code == 401
    r = client.post(f"/v1/jobs/{running['id']}/cancel", headers=AUTH)
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "cancelled" and r.json()["error"] == "cancelled by request"
    assert wait_dead(pid), "the worker process outlived the cancel"
    assert client.post(f"/v1/jobs/{running['id']}/cancel", headers=AUTH).status_code == 409
    assert not (live.data_dir / "spaces" / "cancelled_space.mspace").exists()
    assert not (live.data_dir / "work" / "jobs" / running["id"]).exists()
    names = [s["name"] for s in client.get("/v1/spaces").json()["spaces"]]
    assert "cancelled_space" not in names and "never_space" not in names


def test_a_killed_worker_fails_the_job_and_the_server_goes_on(client, live):
    job = client.post("/v1/jobs", json=build_request("killed_space"), headers=AUTH).json()
    job = wait_for(client, job["id"], lambda j: j["status"] == "running" and (j["worker"] or {}).get("pid"))
    os.kill(job["worker"]["pid"], signal.SIGKILL)
    job = wait_for(client, job["id"], lambda j: j["status"] in FINAL, timeout=30)
    assert job["status"] == "failed", job
    assert "SIGKILL" in job["error"] and f"pid {job['worker']['pid']}" in job["error"], job["error"]
    assert client.get("/v1/health").json()["status"] == "ok"
    assert not (live.data_dir / "spaces" / "killed_space.mspace").exists()
    assert not (live.data_dir / "work" / "jobs" / job["id"]).exists()


def test_ingest_normalises_a_dataset(client, live):
    r = client.post("/v1/jobs", json={"kind": "ingest", "dataset": "gaits", "output": "gaits_clean"}, headers=AUTH)
    assert r.status_code == 202, r.text
    job = wait_for(client, r.json()["id"], lambda j: j["status"] in FINAL, timeout=60)
    assert job["status"] == "succeeded", job
    assert job["result"]["frames"] == sum(s["frames"] for s in client.get("/v1/datasets/gaits").json()["sequences"])
    info = client.get("/v1/datasets/gaits_clean").json()
    assert info["templates"] == ["body.obj"] and info["buildable"] == sorted(SEQUENCES)
    root = live.data_dir / "datasets" / "gaits_clean"
    meta = json.loads((root / "sequences" / "slow" / "meta.json").read_text())
    assert meta["cyclic"] is True and meta["fps"] == 10.0 and meta["source_frames"][0] == "frame_0000.obj"
    assert (meta["units"], meta["up"], meta["input"]["units_from"]) == ("m", "+Y", "detected")
    body = json.loads((root / "manifest.json").read_text())["body"]
    assert (body["units"], body["up"]) == ("m", "+Y") and 1.5 < body["model_size"] < 2.0


def test_ingest_records_the_units_and_up_axis_it_finds(client, live):
    """A dataset in millimetres with +Z up is written as it is, and says so (it used to say m, +Y)."""
    client.post("/v1/datasets", params={"name": "gaits_mm"}, content=capture_zip(units="mm", up="z"),
                headers={**AUTH, "Content-Type": "application/zip"}).raise_for_status()
    r = client.post("/v1/jobs", json={"kind": "ingest", "dataset": "gaits_mm", "output": "gaits_mm_clean"},
                    headers=AUTH)
    job = wait_for(client, r.json()["id"], lambda j: j["status"] in FINAL, timeout=60)
    assert job["status"] == "succeeded", job
    root = live.data_dir / "datasets" / "gaits_mm_clean"
    for name in SEQUENCES:
        meta = json.loads((root / "sequences" / name / "meta.json").read_text())
        assert (meta["units"], meta["up"]) == ("mm", "+Z")
    body = json.loads((root / "manifest.json").read_text())["body"]
    assert (body["units"], body["up"]) == ("mm", "+Z") and 1.5 < body["model_size"] < 2.0  # metres
    assert any("template/body.obj: units mm (detected" in line for line in job["log"]), job["log"]
    for name in SEQUENCES:  # what was found, per sequence
        assert any(line.startswith(f"sequence {name} (") and "units mm (detected" in line and "up +Z (detected" in line
                   for line in job["log"]), job["log"]
    # coordinates copied exactly (the upload's files, read back, against the ingested ones)
    from engine.mesh_io import read_frames

    for name in SEQUENCES:
        before = read_frames(live.data_dir / "datasets" / "gaits_mm" / "sequences" / name / "consistent")
        after = read_frames(root / "sequences" / name / "consistent")
        for a, b in zip(before, after, strict=True):
            np.testing.assert_array_equal(a.vertices, b.vertices)


def test_ingest_of_a_dataset_with_a_textured_template(client, live, dataset_zip, tmp_path):
    """An uploaded template may come textured (OBJ, MTL and image side by side in template/): the
    ingest reads the mesh with its texture and writes it as body.obj with vertex colours."""
    from engine.mesh_io import read_mesh
    from engine.mesh_io.atlas import write_textured

    frame = read_mesh(live.data_dir / "datasets" / "gaits" / "sequences" / "slow" / "consistent" / "frame_0000.obj")
    colours = np.tile([[0.2, 0.5, 0.8]], (len(frame.vertices), 1))
    write_textured(tmp_path / "body.obj", frame.vertices, frame.faces, colours)
    buffer = io.BytesIO(dataset_zip)
    with zipfile.ZipFile(buffer, "a") as archive:
        for path in sorted(tmp_path.iterdir()):
            archive.write(path, f"template/{path.name}")
    client.post("/v1/datasets", params={"name": "gaits_textured"}, content=buffer.getvalue(),
                headers={**AUTH, "Content-Type": "application/zip"}).raise_for_status()
    assert sorted(p.name for p in (live.data_dir / "datasets" / "gaits_textured" / "template").iterdir()) == \
        ["body.mtl", "body.obj", "body.png"]
    r = client.post("/v1/jobs", json={"kind": "ingest", "dataset": "gaits_textured", "output": "gaits_textured_clean"},
                    headers=AUTH)
    job = wait_for(client, r.json()["id"], lambda j: j["status"] in FINAL, timeout=60)
    assert job["status"] == "succeeded", job
    template = live.data_dir / "datasets" / "gaits_textured_clean" / "template"
    assert sorted(p.name for p in template.iterdir()) == ["body.obj"]
    body = read_mesh(template / "body.obj")
    assert len(body.vertices) == len(frame.vertices) and np.abs(body.colors - colours).max() < 0.01


def test_an_upload_cannot_take_the_name_a_queued_job_will_write(client, live, dataset_zip):
    running = client.post("/v1/jobs", json=build_request("busy_space"), headers=AUTH).json()
    queued = client.post("/v1/jobs", json={"kind": "ingest", "dataset": "gaits", "output": "pending_out"},
                         headers=AUTH).json()
    try:
        wait_for(client, running["id"], lambda j: j["status"] == "running")
        assert client.get(f"/v1/jobs/{queued['id']}").json()["status"] == "queued"  # one local worker slot
        r = client.post("/v1/datasets", params={"name": "pending_out"}, content=dataset_zip,
                        headers={**AUTH, "Content-Type": "application/zip"})
        assert r.status_code == 409 and "used by a queued or running job" in r.json()["detail"], r.text
        assert not (live.data_dir / "datasets" / "pending_out").exists()
    finally:
        for job in (queued, running):
            client.post(f"/v1/jobs/{job['id']}/cancel", headers=AUTH)


def test_a_job_left_running_by_a_crashed_server_is_run_again(tmp_path, dataset_zip):
    data = tmp_path / "crash-data"
    first = LiveServer(data, env={"MORPHSPACE_TOKEN": TOKEN}).start()
    try:
        with httpx.Client(base_url=first.url, timeout=30.0) as client:
            client.post("/v1/datasets", params={"name": "gaits"}, content=dataset_zip,
                        headers={**AUTH, "Content-Type": "application/zip"}).raise_for_status()
            job = client.post("/v1/jobs", json=build_request("after_crash"), headers=AUTH).json()
            # well into the build, so the second attempt has work left to redo
            job = wait_for(client, job["id"], lambda j: j["status"] == "running" and j["progress"] >= 0.3, 90)
        worker = job["worker"]["pid"]
        os.kill(first.process.pid, signal.SIGKILL)  # the server only: the worker must notice by itself
        first.process.wait(10)
        assert wait_dead(worker), "the worker outlived its server"
    finally:
        first.stop()
    assert not (data / "spaces" / "after_crash.mspace").exists()
    with LiveServer(data, env={"MORPHSPACE_TOKEN": TOKEN}) as second, \
            httpx.Client(base_url=second.url, timeout=30.0) as client:
        record = client.get(f"/v1/jobs/{job['id']}").json()
        assert record["status"] != "running" or record["worker"]["pid"] != worker, record
        seen = []
        record = wait_for(client, job["id"], lambda j: j["status"] in FINAL, timeout=90, seen=seen)
        assert record["status"] == "succeeded", record
        assert record["attempts"] == 2
        assert any("interrupted" in line and "exited" in line for line in record["log"]), record["log"]
        assert "after_crash" in [s["name"] for s in client.get("/v1/spaces").json()["spaces"]]


def test_align_job_writes_a_buildable_dataset(client, live, dataset_zip):
    """Three frames of each sequence, uploaded as unstructured captures, aligned into one mesh."""
    small = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(dataset_zip)) as source, zipfile.ZipFile(small, "w") as archive:
        for name in source.namelist():
            seq, leaf = name.split("/")
            if leaf in ("frame_0000.obj", "frame_0001.obj", "frame_0002.obj"):
                archive.writestr(f"{seq}/unstructured/{leaf}", source.read(name))
    r = client.post("/v1/datasets", params={"name": "raw", "fps": 10}, content=small.getvalue(),
                    headers={**AUTH, "Content-Type": "application/zip"})
    assert r.status_code == 201 and r.json()["buildable"] == [], r.text
    bad = client.post("/v1/jobs", headers=AUTH, json={"kind": "align", "datasets": ["raw"], "output": "x",
                                                      "units": "inch"})
    assert bad.status_code == 422 and "units" in bad.text
    r = client.post("/v1/jobs", headers=AUTH, json={"kind": "align", "datasets": ["raw"], "output": "raw_aligned",
                                                    "patches": 10, "levels": 2, "retries": 0, "units": "m"})
    assert r.status_code == 202, r.text
    seen = []
    job = wait_for(client, r.json()["id"], lambda j: j["status"] in FINAL, timeout=90, seen=seen)
    assert job["status"] == "succeeded", job
    assert {"histograms", "align"} <= {j["stage"] for j in seen} | {line[6:] for line in job["log"]
                                                                   if line.startswith("stage ")}
    info = client.get("/v1/datasets/raw_aligned").json()
    assert info["kind"] == "aligned" and info["buildable"] == sorted(SEQUENCES) and info["frames"] == 6
    assert info["templates"] == ["body.obj"]
    # its pictures (figs. 1c, 1d, 2), served as PNG; nothing else of the directory is
    assert info["pictures"] == ["similarity.png", "tree.png", "aligned_pattern.png"]
    for picture in info["pictures"]:
        r = client.get(f"/v1/datasets/raw_aligned/pictures/{picture}")
        assert r.status_code == 200 and r.headers["content-type"] == "image/png" and r.content[:8] == b"\x89PNG\r\n\x1a\n"
    for bad in ("manifest.json", "tree.jpg"):
        r = client.get(f"/v1/datasets/raw_aligned/pictures/{bad}")
        assert r.status_code == 404 and "similarity.png" in r.json()["detail"], r.text
    assert client.get("/v1/datasets/raw_aligned/pictures/..%2F..%2Fjobs.sqlite").status_code == 404
    assert client.get("/v1/datasets/raw/pictures/tree.png").status_code == 404  # not aligned: none
    assert client.get("/v1/datasets/raw").json()["pictures"] == []
    assert job["result"]["url"] == "/v1/datasets/raw_aligned" and job["result"]["frames"] == 6
    for name in SEQUENCES:  # units as asked for, the up axis detected, said in the log
        units = job["result"]["input"][name]
        assert (units["units"], units["units_from"], units["up"], units["up_from"]) == ("m", "given", "+Y", "detected")
    assert job["result"]["display_unit"] == "mm"
    said = [line for line in job["log"] if line.startswith("input fast, slow: units m (given")]
    assert said and "up +Y (detected" in said[0], job["log"]
    assert 0 < job["result"]["residual_mean_pct"] < 1
    # the confidence as `morphspace align` writes it per sequence, in the summary and the log
    served = live.data_dir / "datasets" / "raw_aligned"
    result = job["result"]
    assert set(result["flagged"]) == set(SEQUENCES)
    for name in SEQUENCES:
        meta = json.loads((served / "sequences" / name / "meta.json").read_text())
        assert result["flagged"][name] == meta["alignment"]["flagged_frames"]
        # the written frames, not the upload's: 3 consistent frames of the root mesh's structure
        assert (meta["frames"], meta["topology"], meta["units"], meta["up"]) == (3, "consistent", "m", "+Y")
        assert meta["vertices"] == len(read_mesh(served / "template" / "body.obj").vertices)
        assert info["sequences"][[s["name"] for s in info["sequences"]].index(name)]["vertices"] == meta["vertices"]
    assert result["flagged_frames"] == sum(len(f) for f in result["flagged"].values())
    assert 0 <= result["confidence_min"] <= 1 and 0 <= result["repaired_frames"] <= 6
    assert result["repair_alignments"] >= result["repaired_frames"]  # tried, kept or not
    assert set(result["repair_stopped"]) <= {"root", "others"}
    repaired = (f"confidence: {count_text(result['repaired_frames'], 'frame')} repaired "
                f"({count_text(result['repair_alignments'], 'alignment')} tried{stopped_text(result)})")
    assert any(repaired in line for line in job["log"]), job["log"]  # "1 frame", "1 alignment" in the singular
    pulled = np.load(served / "alignment.npz")["pulled"]
    assert result["pulled_frames"] == int(np.sum(pulled > 0))
    seq, frame = result["root_frame"].split(":")
    assert seq in SEQUENCES and 0 <= int(frame) < 3
    assert any(line.startswith("confidence: ") and "still below 0.5" in line for line in job["log"]), job["log"]
    # the same alignment by `morphspace align`: the same arrays, frames and options record
    out = live.data_dir.parent / f"{live.data_dir.name}-cli-aligned"
    assert cli_main(["align", str(live.data_dir / "datasets" / "raw"), "--out", str(out), "--patches", "10",
                     "--levels", "2", "--retries", "0", "--units", "m", "--workers", "1"]) == 0
    assert (out / "alignment.npz").read_bytes() == (served / "alignment.npz").read_bytes()
    for frame in sorted(out.rglob("consistent/*")):
        assert frame.read_bytes() == (served / frame.relative_to(out)).read_bytes(), frame
    cli, job_manifest = (json.loads((d / "manifest.json").read_text()) for d in (out, served))
    assert cli["alignment"]["options"] == job_manifest["alignment"]["options"]
    assert list(cli["alignment"]["options"]) == list(job_manifest["alignment"]["options"])  # same key order
    assert cli["fps"] == job_manifest["fps"] == 10


def test_a_build_of_looping_and_one_shot_sources_is_refused_when_queued(client, live):
    """A build mixing cyclic and non-cyclic sources used to be queued (202) and fail at run time,
    in its read stage (the Dask trial, session 18): it is refused at once, naming the sources."""
    mixed = live.data_dir / "datasets" / "mixed_gaits"
    shutil.copytree(live.data_dir / "datasets" / "gaits", mixed)
    meta = json.loads((mixed / "sequences" / "fast" / "meta.json").read_text())
    (mixed / "sequences" / "fast" / "meta.json").write_text(json.dumps({**meta, "cyclic": not meta["cyclic"]}))
    r = client.post("/v1/jobs", json=build_request("mixed", dataset="mixed_gaits"), headers=AUTH)
    assert r.status_code == 422, r.text
    assert "sources must be all cyclic or all non-cyclic" in r.json()["detail"], r.text
    assert "fast" in r.json()["detail"] and "slow" in r.json()["detail"]


def test_a_refused_request_is_not_sent_back_whole(client):
    """A 422 repeats each refused value, cut to 200 characters of its JSON (a request of 200,000
    sources got back a 20 MB answer; found by a docs-only user)."""
    sources = [f"s{k}" for k in range(200_000)]
    r = client.post("/v1/jobs", json={**build_request("x"), "spec": {"sources": sources}}, headers=AUTH)
    assert r.status_code == 422 and len(r.content) < 2000, len(r.content)
    (error,) = r.json()["detail"]
    assert error["loc"] == ["body", "build", "spec", "sources"] and "at most 16" in error["msg"]
    assert error["input"].startswith('["s0","s1",') and error["input"].endswith(" characters)")
    r = client.post("/v1/jobs", json={**build_request("x"), "space": "../x"}, headers=AUTH)
    assert r.status_code == 422 and r.json()["detail"][0]["input"] == "../x"   # short values as they were
