"""Jobs on a Dask cluster: a live server with MORPHSPACE_DASK_SCHEDULER pointing at a LocalCluster
(worker processes, one worker, one thread). The build runs as a Dask task, reports progress
through worker events, and is published by the server like a local job."""

from __future__ import annotations

import time

import httpx
import pytest
from live_server import LiveServer
from test_jobs import AUTH, FINAL, TOKEN, build_request, capture_zip, wait_for

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as local:
        yield local


@pytest.fixture(scope="module")
def live(tmp_path_factory, cluster):
    env = {"MORPHSPACE_TOKEN": TOKEN, "MORPHSPACE_DASK_SCHEDULER": cluster.scheduler_address}
    with LiveServer(tmp_path_factory.mktemp("dask-data"), env=env) as server:
        with httpx.Client(base_url=server.url, timeout=30.0) as client:
            client.post("/v1/datasets", params={"name": "gaits"}, content=capture_zip(),
                        headers={**AUTH, "Content-Type": "application/zip"}).raise_for_status()
        yield server


@pytest.fixture()
def client(live):
    with httpx.Client(base_url=live.url, timeout=30.0) as c:
        yield c


def test_build_runs_on_dask_with_progress(client, live, cluster):
    job = client.post("/v1/jobs", json=build_request("dask_space"), headers=AUTH).json()
    seen = []
    job = wait_for(client, job["id"], lambda j: j["status"] in FINAL, timeout=90, seen=seen)
    assert job["status"] == "succeeded", job
    assert job["executor"] == "dask" and job["worker"]["key"].startswith("morphspace-job-")
    assert job["worker"]["address"] in cluster.scheduler_info["workers"]  # the worker reported itself
    progress = [j["progress"] for j in seen if j["status"] == "running"]
    assert progress == sorted(progress) and len({p for p in progress if 0 < p < 1}) >= 3, progress
    assert "dask_space" in [s["name"] for s in client.get("/v1/spaces").json()["spaces"]]
    assert list((live.data_dir / "work" / "jobs").iterdir()) == []


def test_cancel_on_dask(client, live, cluster):
    job = client.post("/v1/jobs", json=build_request("dask_cancelled"), headers=AUTH).json()
    wait_for(client, job["id"], lambda j: j["status"] == "running" and j["progress"] > 0.3, timeout=60)
    r = client.post(f"/v1/jobs/{job['id']}/cancel", headers=AUTH)
    assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
    assert not (live.data_dir / "spaces" / "dask_cancelled.mspace").exists()
    # the task noticed its cancel file and stopped: the worker is free well before the build would end
    with distributed.Client(cluster.scheduler_address, timeout=10) as dask:
        deadline = time.monotonic() + 5.0
        while any(dask.processing().values()) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(dask.processing().values()), dask.processing()
    job = client.post("/v1/jobs", json={"kind": "ingest", "dataset": "gaits", "output": "gaits2"}, headers=AUTH).json()
    job = wait_for(client, job["id"], lambda j: j["status"] in FINAL, timeout=60)
    assert job["status"] == "succeeded", job
    assert not (live.data_dir / "spaces" / "dask_cancelled.mspace").exists()
