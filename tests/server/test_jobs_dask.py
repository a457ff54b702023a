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


@pytest.fixture(scope="module")
def built(live):
    """A build run to its end on the cluster: (its job record, every record polled, the space's
    stage timings from its summary)."""
    from engine.motion_space.container import Container

    with httpx.Client(base_url=live.url, timeout=30.0) as client:
        job = client.post("/v1/jobs", json=build_request("dask_space"), headers=AUTH).json()
        seen = []
        # polled often: the build takes a few seconds (its tets' split is compiled since session 55)
        job = wait_for(client, job["id"], lambda j: j["status"] in FINAL, timeout=300, seen=seen, every=0.01)
    timings = {}
    if job["status"] == "succeeded":
        timings = job["result"]["stage_seconds"]
        with Container.open(live.data_dir / "spaces" / "dask_space.mspace") as space:
            assert "timings" not in space.metadata  # the file holds only what the input decides
    return job, seen, timings


def test_build_runs_on_dask_with_progress(built, client, live, cluster):
    job, seen, _ = built
    assert job["status"] == "succeeded", job
    assert job["executor"] == "dask" and job["worker"]["key"].startswith("morphspace-job-")
    assert job["worker"]["address"] in cluster.scheduler_info["workers"]  # the worker reported itself
    progress = [j["progress"] for j in seen if j["status"] == "running"]
    assert progress == sorted(progress) and len({p for p in progress if 0 < p < 1}) >= 3, progress
    assert "dask_space" in [s["name"] for s in client.get("/v1/spaces").json()["spaces"]]
    assert list((live.data_dir / "work" / "jobs").iterdir()) == []


def test_cancel_on_dask(built, client, live, cluster):
    """A build cancelled while it decomposes its sources: the task notices its cancel file, stops
    before it writes, and the worker is free well before the build would have ended.

    Waits are on conditions, bounded only against a hang. "Well before" is measured in this run:
    the worker's threads must be idle within half of what the same build, run to its end here,
    spent after it began decomposing (decompose, hybrid, parameters; on a loaded host everything
    is slower, and a fixed 5 s failed there). A cancelled Dask task's thread goes on until the task
    returns although the scheduler forgets it at once, so the worker's own running threads are
    looked at, not only the scheduler's view. That the task stopped rather than ran out is checked
    on its own events: it never reached its write stage. (A cancel during tetrahedralisation, one
    call into pytetwild, is noticed when that ends.)"""
    _, _, timings = built
    assert timings, "the uncancelled build failed"
    job = client.post("/v1/jobs", json=build_request("dask_cancelled"), headers=AUTH).json()
    running = wait_for(client, job["id"], lambda j: j["status"] == "running" and j["stage"] == "decompose",
                       timeout=300, every=0.01)
    cancelled_at = time.monotonic()
    r = client.post(f"/v1/jobs/{job['id']}/cancel", headers=AUTH)
    assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
    assert not (live.data_dir / "spaces" / "dask_cancelled.mspace").exists()
    with distributed.Client(cluster.scheduler_address, timeout=10) as dask:
        deadline = time.monotonic() + 120.0  # a hang bound; the timing is checked below
        while time.monotonic() < deadline and (any(dask.processing().values()) or executing(dask)):
            time.sleep(0.05)
        freed = time.monotonic() - cancelled_at
        assert not any(dask.processing().values()) and not executing(dask), (dask.processing(), executing(dask))
        remaining = timings["decompose_s"] + timings["hybrid_s"] + timings.get("parameters_s", 0.0)
        assert freed <= 0.5 * remaining, (freed, timings)
        stages = {event.get("stage") for _, event in dask.get_events(running["worker"]["key"])
                  if isinstance(event, dict)}
        assert "decompose" in stages and "write" not in stages, stages
    job = client.post("/v1/jobs", json={"kind": "ingest", "dataset": "gaits", "output": "gaits2"}, headers=AUTH).json()
    job = wait_for(client, job["id"], lambda j: j["status"] in FINAL, timeout=120)
    assert job["status"] == "succeeded", job
    assert not (live.data_dir / "spaces" / "dask_cancelled.mspace").exists()
    print(f"cancel: worker free {freed:.2f} s after the cancel; the build spent {remaining:.2f} s from decompose on")


def executing(dask):
    """Keys of the tasks a thread of a worker is still running (a cancelled task's thread goes on
    until the task returns; the scheduler forgets it at once)."""
    return {address: list(keys) for address, keys in
            dask.run(lambda dask_worker: list(dask_worker.active_threads.values())).items() if keys}


def test_a_job_dask_starts_again_on_another_worker_says_so_in_its_log(tmp_path):
    """A Dask worker that dies while it runs a job's coordinator: the scheduler runs the job again
    on another worker, in the same attempt (the Dask trial saw only its stages start over); the
    job's log names both workers. The coordinator announces its worker at its start."""
    from server.jobs.service import JobService, _Running
    from server.settings import Settings

    service = JobService(Settings(data_dir=tmp_path), registry=None)
    state = _Running({"id": "job", "log": []})
    service._on_message(state, {"t": "worker", "info": {"scheduler": "tcp://127.0.0.1:8786", "key": "k"}})
    service._on_message(state, {"t": "worker", "info": {"address": "tcp://127.0.0.1:40001", "pid": 11}})
    assert list(state.log) == []
    service._on_message(state, {"t": "worker", "info": {"address": "tcp://127.0.0.1:40002", "pid": 12}})
    assert list(state.log) == ["the Dask worker running the job (tcp://127.0.0.1:40001) was lost; Dask started "
                               "the job again on tcp://127.0.0.1:40002 (from its first stage, in the same attempt)"]
    assert state.worker["pid"] == 12 and state.worker["scheduler"] == "tcp://127.0.0.1:8786"


def test_health_reports_the_cluster(live, client, cluster):
    """/v1/health's ``jobs`` names the scheduler, says it answered, and counts its workers and
    threads (the trial's operator could not tell a cluster without workers from a slow job)."""
    from test_rest import DOC, _documented_keys

    jobs = client.get("/v1/health").json()["jobs"]
    assert set(jobs) == _documented_keys(DOC.read_text(), "Dask: `{")
    assert jobs["executor"] == "dask" and jobs["scheduler"] == cluster.scheduler_address
    assert jobs["reachable"] is True and jobs["error"] is None
    assert (jobs["workers"], jobs["threads"]) == (1, 1) and jobs["checked_ago"] < 10


def _capacity(address):
    import asyncio

    from server.jobs.executors import DaskExecutor

    async def ask():
        executor = DaskExecutor(address)
        await executor.start()
        try:
            return executor.capacity(), executor.status()
        finally:
            await executor.stop()

    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as thread:  # a loop of its own (another test may have left one running here)
        return thread.submit(asyncio.run, ask()).result(timeout=60)


def test_as_many_jobs_run_as_the_cluster_has_threads():
    """Three jobs on a 2-worker cluster ran one after another in the Dask trial: the executor asked
    the asynchronous client for the workers it had not fetched, and fell back on one job. It now
    asks the scheduler."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, protocol="tcp://",
                                  dashboard_address=None, silence_logs=40) as local:
        capacity, status = _capacity(local.scheduler_address)
    assert capacity == 2 and (status["workers"], status["threads"]) == (2, 2), status


def test_a_clean_stop_during_a_dask_job_loses_nothing(tmp_path, cluster):
    """The Dask trial stopped the server (SIGTERM) while a build ran: the job was queued again in
    the same attempt, whose task key the old task (which Dask cannot stop) still held, so the new
    run got the old run's end and the job ended cancelled. Each run now has its own key and
    staging directory: the server started again runs the job to its end, in the same attempt."""
    env = {"MORPHSPACE_TOKEN": TOKEN, "MORPHSPACE_DASK_SCHEDULER": cluster.scheduler_address}
    data = tmp_path / "data"
    with LiveServer(data, env=env) as server, httpx.Client(base_url=server.url, timeout=30.0) as c:
        c.post("/v1/datasets", params={"name": "gaits"}, content=capture_zip(),
               headers={**AUTH, "Content-Type": "application/zip"}).raise_for_status()
        job = c.post("/v1/jobs", json=build_request("restarted"), headers=AUTH).json()
        first = wait_for(c, job["id"], lambda j: j["status"] == "running" and j["stage"] == "decompose", timeout=300,
                         every=0.01)
    with LiveServer(data, env=env) as server, httpx.Client(base_url=server.url, timeout=30.0) as c:
        job = wait_for(c, job["id"], lambda j: j["status"] in FINAL, timeout=300)
    assert job["status"] == "succeeded", job
    assert job["attempts"] == 1 and job["worker"]["key"] != first["worker"]["key"], (job["worker"], first["worker"])
    assert any("attempt 1 stopped: the server" in line and "queued again" in line for line in job["log"]), job["log"]
    assert (data / "spaces" / "restarted.mspace").is_file()
    assert list((data / "work" / "jobs").iterdir()) == []


def test_jobs_wait_for_the_scheduler_and_one_it_lost_is_queued_again(tmp_path):
    """A scheduler that cannot be reached keeps the jobs queued (health says why); when it is
    there they run. One that goes away while a job runs (the cluster closed under a build) sends
    the job back to the queue, its attempt counted, and it runs again when the scheduler is back
    at its address."""
    from live_server import free_port

    port = free_port()
    address = f"tcp://127.0.0.1:{port}"

    def cluster_at_port():
        return distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, scheduler_port=port,
                                        host="127.0.0.1", dashboard_address=None, silence_logs=50)

    env = {"MORPHSPACE_TOKEN": TOKEN, "MORPHSPACE_DASK_SCHEDULER": address}
    with LiveServer(tmp_path / "data", env=env) as server, httpx.Client(base_url=server.url, timeout=30.0) as c:
        c.post("/v1/datasets", params={"name": "gaits"}, content=capture_zip(),
               headers={**AUTH, "Content-Type": "application/zip"}).raise_for_status()
        jobs = c.get("/v1/health").json()["jobs"]
        assert jobs["reachable"] is False and "cannot reach the Dask scheduler" in jobs["error"], jobs
        job = c.post("/v1/jobs", json=build_request("waited"), headers=AUTH).json()
        time.sleep(3.0)  # two dispatcher rounds
        assert c.get(f"/v1/jobs/{job['id']}").json()["status"] == "queued"
        with cluster_at_port():
            wait_for(c, job["id"], lambda j: j["status"] == "running" and j["stage"] == "decompose", timeout=300,
                     every=0.01)
        lost = wait_for(c, job["id"], lambda j: j["status"] != "running", timeout=60)
        assert lost["status"] == "queued", lost
        assert any("attempt 1 interrupted: the Dask scheduler" in line for line in lost["log"]), lost["log"]
        with cluster_at_port():
            job = wait_for(c, job["id"], lambda j: j["status"] in FINAL, timeout=300)
            assert c.get("/v1/health").json()["jobs"]["reachable"] is True
    assert job["status"] == "succeeded" and job["attempts"] == 2, job
