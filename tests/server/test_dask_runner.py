"""Align and build jobs split into Dask tasks (server/jobs/dask_runner.py) give the local result.

A LocalCluster in this process (two workers, one thread each). The job's own task (``dask_entry``)
submits the histogram chunks, matrix blocks, tree pieces and decompositions to the cluster; the
outputs are compared with the same job run here without a runner: equal bit for bit, apart from
the timings they record.
"""

from __future__ import annotations

import functools
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
    staging = data_dir / "work" / "jobs" / where / "attempt-1-run"
    staging.mkdir(parents=True)  # the server makes it before it starts the job
    return {"id": where, "kind": kind, "attempt": 1, "run": "1-run", "params": params, "data_dir": str(data_dir),
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


def test_align_job_split_on_dask_equals_the_local_run(cluster, data_dir, monkeypatch):
    from engine.align import captures, root_race, root_trial

    # the walk's 12 frames, with a smaller trial and race than a capture's own, in both runs alike
    # (the cluster's workers are threads of this process): a trial from 12 frames on, two candidates
    # of two probes each, and the finalists raced (asked for: one take) on 4 of the 12 frames (the
    # subset race) before the winner aligns them all
    monkeypatch.setattr(root_trial, "TRIAL_MIN_FRAMES", 12)
    monkeypatch.setattr(captures, "trial_candidates", functools.partial(root_trial.trial_candidates, count=2))
    monkeypatch.setattr(captures, "trial_probes", functools.partial(root_trial.trial_probes, count=2))
    monkeypatch.setattr(root_race, "RACE_FRAMES", 4)
    params = {"datasets": ["tiny"], "output": "aligned", "only": ["walk"], "root": None, "sequential": False,
              "tree": "mst", "window": 2, "patches": 10, "levels": 2, "retries": 1, "seed": 0, "units": "auto",
              "up": "auto", "root_choice": "race"}
    local, remote, names, events = run_both(cluster, data_dir, "align", params, "align")
    # the root trial's candidates are tasks too, and the race's finalists align in pieces like the
    # final run
    assert {"histogram-task", "distance-task", "trial-task", "piece-task"} <= names, names
    stages = {e["stage"] for e in events if e.get("t") == "progress"} | {
        e["line"][6:] for e in events if e.get("t") == "log" and e["line"].startswith("stage ")}
    assert {"histograms", "dissimilarity", "trial", "race"} <= stages, stages
    a, b = np.load(local / "dataset" / "alignment.npz"), np.load(remote / "dataset" / "alignment.npz")
    assert sorted(a.files) == sorted(b.files)
    compared = [key for key in a.files if "seconds" not in key]
    assert {"parent", "residual", "dissimilarity", "yaw"} <= set(compared), a.files
    for key in compared:
        assert np.array_equal(a[key], b[key]), key
    frames = sorted((local / "dataset").rglob("consistent/*"))
    assert len(frames) == len(a["parent"]) == 12
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


def _coordinator(prefix, reruns):
    """A job's coordinator in miniature: two tasks through a DaskRunner; what became of them, and
    the lines it logged."""
    from server.jobs.dask_runner import DaskRunner, WorkerGone

    lines = []
    try:
        results = DaskRunner(prefix, log=lines.append, reruns=reruns).map(_sleep_task, [0.1, 3.0])
    except WorkerGone as exc:
        return f"gone: {exc}", lines
    return f"finished: {results}", lines


def _lose_the_long_task(cluster, prefix, times):
    """Cancel the running long task (its key ends in -1, -3, ... as the runner numbers them) for
    every client, ``times`` times: what the scheduler does when a worker dies with its data."""
    for n in range(times):
        deadline, key = time.monotonic() + 30, None
        while key is None and time.monotonic() < deadline:
            keys = cluster.run_on_scheduler(lambda dask_scheduler: [str(k) for k, ts in dask_scheduler.tasks.items()
                                                                     if ts.state == "processing"])
            key = next((k for k in keys if k.startswith(prefix) and k.endswith(f"-{2 * n + 1}")), None)
            time.sleep(0.05)
        assert key is not None, f"the long task never started (loss {n + 1})"
        cluster.cancel([distributed.Future(key, client=cluster)], force=True)


def test_tasks_lost_with_their_worker_run_again(cluster):
    """When a worker dies, Dask forgets the tasks whose data went with it (the Dask trial saw
    ``FuturesCancelledError ... already forgotten`` after killing a worker mid-decompose, and the
    job failed each time): the runner runs the stage again, says so in the job's log, and the
    results are the stage's results."""
    coordinator = cluster.submit(_coordinator, "morphspace-test-rerun", 2, pure=False)
    _lose_the_long_task(cluster, "morphspace-test-rerun", 1)
    answer, lines = coordinator.result(timeout=60)
    assert answer == "finished: [0.1, 3.0]", answer
    assert len(lines) == 1 and lines[0].startswith("a Dask worker was lost while this job's tasks ran"), lines
    assert lines[0].endswith("running the stage's 2 tasks again (1 of at most 2)"), lines


def test_tasks_lost_again_and_again_fail_the_job_with_a_clear_reason(cluster):
    """A stage that loses a worker more often than it may run again fails the job in words, not
    with a traceback."""
    coordinator = cluster.submit(_coordinator, "morphspace-test-lost", 1, pure=False)
    _lose_the_long_task(cluster, "morphspace-test-lost", 2)
    answer, lines = coordinator.result(timeout=60)
    assert answer.startswith("gone: a Dask worker was lost while this job's tasks ran"), answer
    assert answer.endswith("the stage ran 2 times, and lost a worker each time"), answer
    assert len(lines) == 1, lines


def _checkpointed(shared, seconds):
    """A long task that calls engine.tasks.checkpoint between its steps, as the tree pieces and
    decompositions do."""
    from engine.tasks import checkpoint

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        checkpoint()
        time.sleep(0.02)
    return "ran to its end"


def test_a_running_task_stops_when_its_job_run_ends(cluster, tmp_path):
    """Dask cannot stop a running task, so a tree piece of a stopped or cancelled job held its
    worker's thread until it ended (about 100 s in the session 18 trial). The runner's tasks look
    at the run's staging directory at their checkpoints and stop once it is gone."""
    from engine.tasks import Stopped
    from server.jobs.dask_runner import run_stoppable

    staging = tmp_path / "attempt-1-run"
    staging.mkdir()
    future = cluster.submit(run_stoppable, _checkpointed, str(staging), None, None, 60.0, pure=False)
    deadline = time.monotonic() + 30  # until a worker has it (processing() lists every worker, busy or not)
    while not any(cluster.processing().values()) and time.monotonic() < deadline:
        time.sleep(0.05)
    staging.rmdir()
    with pytest.raises(Stopped):  # within 30 s: run to its end, it would take 60
        future.result(timeout=30)
    kept = cluster.submit(run_stoppable, _checkpointed, str(tmp_path), None, None, 0.3, pure=False)
    assert kept.result(timeout=30) == "ran to its end"


def _steps(shared, steps):
    """A task of ``steps`` checkpoints, 0.05 s apart (a tree piece's frames, in miniature)."""
    from engine.tasks import checkpoint

    for _ in range(steps):
        checkpoint()
        time.sleep(0.05)
    return steps


def _progress_of(prefix):
    """A coordinator running two 40-step tasks through a DaskRunner; the progress it reported."""
    from server.jobs.dask_runner import DaskRunner

    seen = []
    DaskRunner(prefix).map(_steps, [40, 40], sizes=[40, 40], progress=lambda done, total: seen.append((done, total)))
    return seen


def test_progress_moves_within_a_long_task(cluster):
    """A tree piece of hundreds of frames held a Dask job's progress still until it ended (the
    session 17 trial: 116 s at 0): the tasks report the checkpoints they pass, and the runner's
    progress counts them, never past a running task's size, never backwards, and whole at the end."""
    seen = cluster.submit(_progress_of, "morphspace-test-ticks", pure=False).result(timeout=60)
    done = [d for d, _ in seen]
    assert {t for _, t in seen} == {80} and done == sorted(done) and done[-1] == 80, seen
    assert any(0 < d < 40 or 40 < d < 80 for d in done), seen  # between the tasks' ends
