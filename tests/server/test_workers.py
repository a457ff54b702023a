"""``morphspace serve --workers 2`` for real: streams served by both processes, health adding
them up, jobs run once by the queue's worker, a killed worker started again and reported, and no
process outliving the supervisor."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import subprocess
import sys
import time

import httpx
import pytest
from live_server import LiveServer, data_dir_with_spaces
from test_jobs import AUTH, TOKEN, build_request, capture_zip, pid_alive, wait_dead, wait_for
from test_stream import run

from server.client import StreamClient

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="--workers needs Linux")
FINAL = ("succeeded", "failed", "cancelled")


def health(server):
    return httpx.get(server.url + "/v1/health", timeout=10).json()


# every worker record's keys (docs/rest.md), also while a worker is down between its end and restart
WORKER_KEYS = {"index", "pid", "alive", "jobs", "started_at", "restarts", "last_exit", "published_ago",
               "connections", "frames_sent", "frames_dropped", "stream_errors", "scheduler"}


def wait_health(server, until, timeout=30.0):
    """Poll /v1/health until ``until(record)``; fails after ``timeout`` s. Every record on the way
    must carry every documented key of every worker."""
    deadline, record = time.monotonic() + timeout, None
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError):
            record = health(server)
            for worker in record["workers"]:
                assert set(worker) == WORKER_KEYS, (worker, record)
            if until(record):
                return record
        time.sleep(0.1)
    raise AssertionError(f"health did not get there in {timeout} s: {record}")


def all_alive(record):
    return len(record["workers"]) == 2 and all(w["alive"] for w in record["workers"])


@pytest.fixture(scope="module")
def two_workers(built_spaces, tmp_path_factory):
    data = data_dir_with_spaces(tmp_path_factory.mktemp("workers-data"), built_spaces)
    with LiveServer(data, env={"MORPHSPACE_TOKEN": TOKEN}, args=["--workers", "2"]) as live:
        wait_health(live, all_alive)
        yield live


def stream_many(server, clients, frames):
    """Open ``clients`` streams at once, read ``frames`` frames on each, then look at /v1/health
    while every one is still open. Returns (frames read per client, health)."""
    async def one(ready, release):
        async with StreamClient.connect(server.ws_url, "speed", codec="q16", rate=30) as client:
            got = [await client.next_frame() for _ in range(frames)]
            ready.release()
            await release.wait()
            return len(got)

    async def go():
        ready, release = asyncio.Semaphore(0), asyncio.Event()
        tasks = [asyncio.create_task(one(ready, release)) for _ in range(clients)]
        for _ in range(clients):
            await ready.acquire()
        await asyncio.sleep(0.6)  # a publication interval and more: every worker has published
        record = await asyncio.to_thread(health, server)
        release.set()
        return await asyncio.gather(*tasks), record

    return run(go())


def test_streams_are_served_by_both_workers_and_health_adds_them_up(two_workers):
    before = health(two_workers)
    counts, during = stream_many(two_workers, clients=16, frames=5)
    assert counts == [5] * 16
    workers = during["workers"]
    assert [w["index"] for w in workers] == [0, 1] and len({w["pid"] for w in workers}) == 2
    assert during["connections"] == sum(w["connections"] for w in workers) == 16
    assert all(w["connections"] >= 1 for w in workers), workers  # the kernel spread them over both
    assert during["frames_sent"] == sum(w["frames_sent"] for w in workers)
    assert during["frames_sent"] - before["frames_sent"] >= 16 * 5
    assert during["scheduler"]["frames"] == sum(w["scheduler"]["frames"] for w in workers)
    # a peak is the largest over the workers, not their sum
    assert during["scheduler"]["transport_bytes_max"] == max(w["scheduler"]["transport_bytes_max"] for w in workers) > 0
    after = wait_health(two_workers, lambda r: r["connections"] == 0)
    assert after["status"] == "ok" and after["restarts"] == 0
    assert after["frames_sent"] >= during["frames_sent"]


def test_http_requests_reach_both_workers(two_workers):
    answered = set()
    for _ in range(60):  # a new connection each time: the kernel picks a worker by its port
        r = httpx.get(two_workers.url + "/v1/spaces", timeout=10)
        assert r.status_code == 200 and {s["name"] for s in r.json()["spaces"]} == {"speed", "jump"}
        answered.add(r.headers["x-morphspace-worker"])
        if len(answered) == 2:
            break
    assert answered == {"0", "1"}


def file_mappings(pid, directory):
    """{path: {"Rss": kB, "Shared_Clean": kB, "Anonymous": kB, ...}} summed over the mappings of
    files under ``directory`` in process ``pid`` (/proc/<pid>/smaps)."""
    out, current = {}, None
    with open(f"/proc/{pid}/smaps") as smaps:
        for line in smaps:
            fields = line.split()
            if "-" in fields[0] and len(fields) >= 5:  # a mapping's first line: range perms offset dev inode [path]
                path = fields[5] if len(fields) >= 6 else ""
                current = out.setdefault(path, {}) if path.startswith(str(directory)) else None
            elif current is not None and fields[0].endswith(":") and len(fields) == 3:
                current[fields[0][:-1]] = current.get(fields[0][:-1], 0) + int(fields[1])
    return out


def test_workers_share_the_mapped_space_and_its_derived_arrays(two_workers):
    answered = set()
    for _ in range(60):  # non-linear frames from both workers (a new connection each time)
        r = httpx.get(two_workers.url + "/v1/spaces/speed/frame", params={"mode": "nonlinear", "format": "json"},
                      timeout=30)
        assert r.status_code == 200, r.text
        answered.add(r.headers["x-morphspace-worker"])
        if answered == {"0", "1"}:
            break
    assert answered == {"0", "1"}
    data = two_workers.data_dir.resolve()
    maps = [file_mappings(w["pid"], data) for w in health(two_workers)["workers"]]
    space = str(data / "spaces" / "speed.mspace")
    (derived,) = [p for p in maps[0] if p.startswith(str(data / "work" / "derived")) and p.endswith(".nonlinear.mspace")]
    for mapping in maps:  # both map the same files read-only: no private copies, the pages shared
        for path in (space, derived):
            figures = mapping[path]
            shared = figures["Shared_Clean"] + figures["Shared_Dirty"]  # dirty: the copy is not written back yet
            assert figures["Anonymous"] == 0 and shared >= 0.5 * figures["Rss"] > 0, (path, figures)


def test_jobs_queued_at_either_worker_run_once_in_worker_0(two_workers):
    with httpx.Client(base_url=two_workers.url, timeout=30.0) as client:
        r = client.post("/v1/datasets", params={"name": "gaits"}, content=capture_zip(),
                        headers={**AUTH, "Content-Type": "application/zip"})
        assert r.status_code == 201, r.text
    jobs, answered = [], set()
    for k in range(12):  # new connections until both workers have queued at least two jobs
        with httpx.Client(base_url=two_workers.url, timeout=30.0) as client:
            r = client.post("/v1/jobs", json={"kind": "ingest", "dataset": "gaits", "output": f"clean_{k}"},
                            headers=AUTH)
        assert r.status_code == 202, r.text
        jobs.append(r.json()["id"])
        answered.add(r.headers["x-morphspace-worker"])
        if k >= 3 and answered == {"0", "1"}:
            break
    assert answered == {"0", "1"}
    owner = health(two_workers)["workers"][0]["pid"]
    with httpx.Client(base_url=two_workers.url, timeout=30.0) as client:
        for job_id in jobs:
            job = wait_for(client, job_id, lambda j: j["status"] in FINAL, timeout=120)
            assert job["status"] == "succeeded", job
            assert job["attempts"] == 1, job
            started = [line for line in job["log"] if " started on " in line]
            assert started == [f"attempt 1 started on local executor (server pid {owner})"], job["log"]


def test_a_queued_job_is_cancelled_from_either_worker(two_workers):
    """A running job cancelled through whichever worker answers: the owner stops it."""
    with httpx.Client(base_url=two_workers.url, timeout=30.0) as client:
        if client.get("/v1/datasets/gaits").status_code == 404:
            client.post("/v1/datasets", params={"name": "gaits"}, content=capture_zip(),
                        headers={**AUTH, "Content-Type": "application/zip"}).raise_for_status()
        spec = {"sources": ["slow", "fast"], "phases": 8, "epsilon_mm": 10.0,
                "parameters": {"layout": "chain", "chain": ["slow", "fast"], "measures": ["speed"], "resolution": 5}}
        job = client.post("/v1/jobs", json={"kind": "build", "dataset": "gaits", "space": "never", "spec": spec},
                          headers=AUTH).json()
        job = wait_for(client, job["id"], lambda j: j["status"] == "running" and (j["worker"] or {}).get("pid"))
    for _ in range(40):  # cancel through worker 1 (new connections until it answers)
        with httpx.Client(base_url=two_workers.url, timeout=30.0) as client:
            r = client.get("/v1/health")
            if r.headers["x-morphspace-worker"] != "1":
                continue
            r = client.post(f"/v1/jobs/{job['id']}/cancel", headers=AUTH)
            if r.headers["x-morphspace-worker"] == "1":
                break
    assert r.headers["x-morphspace-worker"] == "1"
    assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
    assert wait_dead(job["worker"]["pid"])
    assert not (two_workers.data_dir / "spaces" / "never.mspace").exists()


def test_a_killed_worker_is_started_again_and_reported(built_spaces, tmp_path):
    data = data_dir_with_spaces(tmp_path / "data", built_spaces)
    with LiveServer(data, env={"MORPHSPACE_TOKEN": TOKEN}, args=["--workers", "2"]) as live:
        record = wait_health(live, all_alive)
        stream_many(live, clients=8, frames=3)
        sent = wait_health(live, lambda r: r["connections"] == 0)["frames_sent"]
        with httpx.Client(base_url=live.url, timeout=30.0) as client:
            client.post("/v1/datasets", params={"name": "gaits"}, content=capture_zip(),
                        headers={**AUTH, "Content-Type": "application/zip"}).raise_for_status()
            job = client.post("/v1/jobs", json=build_request("after_kill"), headers=AUTH).json()
            job = wait_for(client, job["id"], lambda j: j["status"] == "running" and (j["worker"] or {}).get("pid"))
        first_owner = record["workers"][0]["pid"]
        # the job queue's worker first, as soon as its build runs (a tiny build now ends in a few
        # seconds: killed second, after worker 1's restart, it had finished once in CI), then a
        # streaming worker while the new worker 0 may already run the job again
        for index in (0, 1):
            pid = record["workers"][index]["pid"]
            os.kill(pid, signal.SIGKILL)
            record = wait_health(live, lambda r: all_alive(r) and r["workers"][index]["pid"] != pid)
            restarted = record["workers"][index]
            # the kill is reported; a restarted worker that then ends again is restarted again (seen
            # once in a clean-clone run under load: restarts 2; not reproduced since in 28 runs, 16
            # of them beside the full suite), and then the server log must say how each one ended
            log = live.log.read_text()
            ends = [line for line in log.splitlines() if line.startswith(f"morphspace: worker {index} (pid ")]
            assert ends and ends[0].startswith(f"morphspace: worker {index} (pid {pid}) was killed by SIGKILL"), log[-3000:]
            assert 1 <= restarted["restarts"] <= len(ends), (restarted, ends, log[-3000:])  # (log read after health)
            assert record["frames_sent"] >= sent  # the dead worker's counters are kept
        assert record["restarts"] >= 2 and record["status"] == "ok"
        assert wait_dead(job["worker"]["pid"]), "the job's process outlived its server worker"
        counts, _ = stream_many(live, clients=4, frames=3)  # both serve again
        assert counts == [3] * 4
        with httpx.Client(base_url=live.url, timeout=30.0) as client:  # the new worker 0 runs the job again
            job = wait_for(client, job["id"], lambda j: j["status"] in FINAL, timeout=180)
        assert job["status"] == "succeeded" and job["attempts"] == 2, job
        started = [line for line in job["log"] if " started on " in line]
        assert started == [f"attempt 1 started on local executor (server pid {first_owner})",
                           f"attempt 2 started on local executor (server pid {record['workers'][0]['pid']})"], job
        assert any("interrupted" in line for line in job["log"]), job["log"]
        pids = [w["pid"] for w in health(live)["workers"]]
    assert all(wait_dead(pid) for pid in pids), "a worker outlived the supervisor's stop"


def test_workers_end_with_a_killed_supervisor(built_spaces, tmp_path):
    data = data_dir_with_spaces(tmp_path / "data", built_spaces, names=("speed",))
    live = LiveServer(data, args=["--workers", "2"]).start()
    try:
        pids = [w["pid"] for w in wait_health(live, all_alive)["workers"]]
        os.kill(live.process.pid, signal.SIGKILL)
        live.process.wait(10)
        assert all(wait_dead(pid) for pid in pids), "a worker outlived its supervisor"
    finally:
        live.stop()
        for pid in pids:
            if pid_alive(pid):
                os.kill(pid, signal.SIGKILL)


def test_the_supervisor_gives_up_on_workers_that_cannot_start(tmp_path):
    """A data directory that is a file: every worker fails at start; the supervisor backs off,
    then stops and exits with status 1 naming the worker and how it ended."""
    (tmp_path / "data").write_text("not a directory")
    process = subprocess.run(
        [sys.executable, "-m", "server.cli", "serve", "--data-dir", str(tmp_path / "data"), "--port", "0",
         "--workers", "2", "--log-level", "critical"], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert process.returncode == 1, process.stderr[-2000:]
    assert "starting it again in" in process.stderr
    assert "giving up: worker" in process.stderr and "5 times in a row within 10 s of starting" in process.stderr
    assert "exited with status 3" in process.stderr


def test_a_second_server_on_the_same_port_is_refused(two_workers, tmp_path):
    """Workers join their port with SO_REUSEPORT, which would let a second ``serve --workers``
    share it silently: the supervisor refuses a port something is bound to, naming it."""
    port = str(two_workers.port)
    process = subprocess.run(
        [sys.executable, "-m", "server.cli", "serve", "--data-dir", str(tmp_path), "--port", port,
         "--workers", "2", "--log-level", "critical"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert process.returncode == 2, process.stderr[-2000:]
    assert f"127.0.0.1:{port} is already in use" in process.stderr
    assert health(two_workers)["status"] == "ok"  # the first server serves on
    # a single-process server is refused the same way, before its start-up
    process = subprocess.run(
        [sys.executable, "-m", "server.cli", "serve", "--data-dir", str(tmp_path), "--port", port,
         "--log-level", "critical"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert process.returncode == 2, process.stderr[-2000:]
    assert f"127.0.0.1:{port} is already in use" in process.stderr and "serving" not in process.stdout
    assert health(two_workers)["status"] == "ok"
