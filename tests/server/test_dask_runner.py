"""Align and build jobs split into Dask tasks (server/jobs/dask_runner.py) give the local result.

A LocalCluster in this process (two workers, one thread each). The job's own task (``dask_entry``)
submits the histogram chunks, matrix blocks, tree pieces and decompositions to the cluster; the
outputs are compared with the same job run here without a runner: equal bit for bit, apart from
the timings they record.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from server.cli import main  # noqa: E402
from server.jobs.tasks import Reporter, dask_entry, run_task  # noqa: E402


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None,
                                  silence_logs=40) as local, distributed.Client(local) as client:
        yield client


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """A data directory holding the tiny preset's walk and run at 3 fps."""
    data = tmp_path_factory.mktemp("dask-runner-data")
    status = main(["synth", "--preset", "tiny", "--only", "walk", "run", "--fps", "3", "--no-previews",
                   "--workers", "1", "--out", str(data / "datasets" / "tiny")])
    assert status == 0
    return data


def payload(data_dir, kind, params, where):
    staging = data_dir / "work" / "jobs" / where / "attempt-1"
    return {"id": where, "kind": kind, "attempt": 1, "params": params, "data_dir": str(data_dir),
            "staging": str(staging)}


def run_both(cluster, data_dir, kind, params, name):
    """(local staging, Dask staging, names of the Dask tasks that ran, progress events)."""
    local = payload(data_dir, kind, params, f"{name}-local")
    run_task(local, Reporter(kind, lambda message: None))
    remote = payload(data_dir, kind, params, f"{name}-dask")
    events = []
    topic = f"morphspace-job-{name}-1"
    cluster.subscribe_topic(topic, lambda event: events.append(event[1]))
    with distributed.get_task_stream(cluster) as stream:
        answer = json.loads(cluster.submit(dask_entry, json.dumps(remote), topic, key=topic, pure=False)
                            .result(timeout=300))
    assert "result" in answer, answer
    deadline = time.monotonic() + 10.0  # worker events arrive on their own, shortly after the answer
    while not any(e.get("stage") == "write" for e in events) and time.monotonic() < deadline:
        time.sleep(0.05)
    names = {task["key"].split("-")[-3] + "-" + task["key"].split("-")[-2] for task in stream.data
             if task["key"].startswith(topic + "-")}
    return Path(local["staging"]), Path(remote["staging"]), names, events


def test_align_job_split_on_dask_equals_the_local_run(cluster, data_dir):
    params = {"datasets": ["tiny"], "output": "aligned", "only": None, "root": None, "sequential": False,
              "tree": "mst", "window": 2, "patches": 10, "levels": 2, "retries": 1, "seed": 0, "units": "auto",
              "up": "auto"}
    local, remote, names, events = run_both(cluster, data_dir, "align", params, "align")
    assert {"histogram-task", "distance-task", "piece-task"} <= names, names
    stages = {e["stage"] for e in events if e.get("t") == "progress"} | {
        e["line"][6:] for e in events if e.get("t") == "log" and e["line"].startswith("stage ")}
    assert {"histograms", "dissimilarity", "align", "repair"} <= stages, stages
    a, b = np.load(local / "dataset" / "alignment.npz"), np.load(remote / "dataset" / "alignment.npz")
    assert sorted(a.files) == sorted(b.files)
    compared = [key for key in a.files if "seconds" not in key]
    assert {"parent", "residual", "dissimilarity", "yaw"} <= set(compared), a.files
    for key in compared:
        assert np.array_equal(a[key], b[key]), key
    frames = sorted((local / "dataset").rglob("consistent/*"))
    assert len(frames) == len(a["parent"]) > 10
    for path in frames:
        assert path.read_bytes() == (remote / "dataset" / path.relative_to(local / "dataset")).read_bytes(), path


def test_build_job_split_on_dask_equals_the_local_run(cluster, data_dir):
    from engine.motion_space.container import Container

    params = {"dataset": "tiny", "space": "gaits", "replace": False,
              "spec": {"sources": ["walk", "run"], "phases": 8, "epsilon_mm": 10.0}}
    local, remote, names, events = run_both(cluster, data_dir, "build", params, "build")
    assert "decompose-task" in names, names
    assert any(e.get("stage") == "decompose" for e in events)
    with Container.open(local / "gaits.mspace") as a, Container.open(remote / "gaits.mspace") as b:
        assert sorted(a) == sorted(b) and "nl_quaternions" in a
        for key in a:
            assert np.array_equal(np.asarray(a[key]), np.asarray(b[key])), key
        untimed = [{k: v for k, v in c.metadata.items() if k != "timings"} for c in (a, b)]
        assert untimed[0] == untimed[1]


def _sleep_task(shared, seconds):
    time.sleep(seconds)
    return seconds


def _coordinator(prefix):
    """A job's coordinator in miniature: two tasks through a DaskRunner; what became of them."""
    from server.jobs.dask_runner import DaskRunner, WorkerGone

    try:
        DaskRunner(prefix).map(_sleep_task, [0.1, 30.0])
    except WorkerGone as exc:
        return f"gone: {exc}"
    return "finished"


def test_tasks_lost_with_their_worker_fail_the_job_with_a_clear_reason(cluster):
    """When a worker dies, Dask forgets the tasks whose data went with it (the Dask trial saw
    ``FuturesCancelledError ... already forgotten`` after killing a worker mid-decompose): the
    runner stops waiting and says so in words, instead of a traceback. The loss is made here
    by cancelling the running task for every client, which is what the scheduler does then."""
    coordinator = cluster.submit(_coordinator, "morphspace-test-lost", pure=False)
    deadline = time.monotonic() + 30
    key = None
    while key is None and time.monotonic() < deadline:
        keys = cluster.run_on_scheduler(lambda dask_scheduler: [str(k) for k, ts in dask_scheduler.tasks.items()
                                                                 if ts.state == "processing"])
        key = next((k for k in keys if k.startswith("morphspace-test-lost-") and k.endswith("-1")), None)
        time.sleep(0.05)
    assert key is not None, "the long task never started"
    cluster.cancel([distributed.Future(key, client=cluster)], force=True)
    answer = coordinator.result(timeout=30)
    assert answer.startswith("gone: a Dask worker was lost while this job's tasks ran"), answer
    assert "queue the job again" in answer
