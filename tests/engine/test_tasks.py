"""Task runners (engine.tasks): the split stages give the same result through a runner as without,
whatever the order in which the tasks run and finish, and with tasks running at the same time on
several threads of one process (as on a Dask worker with several threads, or a cluster of
in-process workers)."""

import pickle
import queue
import random
import sys
import threading

import numpy as np
import pytest

from engine.align import align_tree, chain_tree
from engine.align.similarity import dissimilarity_matrix, frame_histograms
from engine.tasks import Rebuilt, SerialRunner, check_parents, shared_value


class CountingRunner(SerialRunner):
    """A SerialRunner that records which tasks it ran and checks the parents' results."""

    def __init__(self):
        self.calls = []

    def map(self, function, jobs, **kwargs):
        self.calls.append((function.__name__, len(jobs)))
        return super().map(function, jobs, **kwargs)

    def tree(self, function, jobs, parents, **kwargs):
        self.calls.append((function.__name__, len(jobs)))
        return super().tree(function, jobs, parents, **kwargs)


class ThreadRunner:
    """Runs the tasks on ``threads`` threads at once, started in a shuffled order and finishing in
    whatever order they finish; results placed by task index, progress on the calling thread as
    tasks finish (as ``DaskRunner`` does).

    Every thread starts together (a barrier) and first takes its own ``shared_value(shared)`` of a
    :class:`Rebuilt`: the threads are alive at the same time, so two of them holding the same
    object means two tasks could use one solver's scratch buffers at once (what made a Dask
    build's result differ from the local run's now and then). That is checked on every call, so it
    fails every time rather than when the interleaving happens to hit. A tiny switch interval makes
    the threads interleave often inside the tasks too.
    """

    def __init__(self, threads=3, seed=0):
        self.threads, self.random = threads, random.Random(seed)
        self.calls = []

    def map(self, function, jobs, *, shared=None, sizes=None, progress=None):
        self.calls.append((function.__name__, len(jobs)))
        return self._run(lambda job, parent: function(shared, job), jobs, [-1] * len(jobs), shared, sizes, progress)

    def tree(self, function, jobs, parents, *, shared=None, sizes=None, progress=None):
        check_parents(parents)
        self.calls.append((function.__name__, len(jobs)))
        return self._run(lambda job, parent: function(shared, job, parent), jobs, parents, shared, sizes, progress)

    def _run(self, call, jobs, parents, shared, sizes, progress):
        sizes = list(sizes) if sizes is not None else [1] * len(jobs)
        total, done = int(sum(sizes)), 0
        results, finished = [None] * len(jobs), 0
        children = [[] for _ in jobs]
        for t, p in enumerate(parents):
            if p >= 0:
                children[p].append(t)
        ready, answers = queue.Queue(), queue.Queue()
        start = threading.Barrier(self.threads)
        held = {}

        def work():
            start.wait(timeout=30)
            if isinstance(shared, Rebuilt):
                held[threading.get_ident()] = shared_value(shared)
            while (t := ready.get()) is not None:
                try:
                    answers.put((t, call(jobs[t], None if parents[t] < 0 else results[parents[t]]), None))
                except BaseException as error:  # noqa: BLE001 - handed to the calling thread
                    answers.put((t, None, error))

        def release(tasks):
            tasks = list(tasks)
            self.random.shuffle(tasks)
            for t in tasks:
                ready.put(t)

        workers = [threading.Thread(target=work, daemon=True) for _ in range(self.threads)]
        interval = sys.getswitchinterval()
        sys.setswitchinterval(1e-5)
        try:
            for worker in workers:
                worker.start()
            release(t for t, p in enumerate(parents) if p < 0)
            while finished < len(jobs):
                t, result, error = answers.get(timeout=300)
                if error is not None:
                    raise error
                results[t], finished, done = result, finished + 1, done + sizes[t]
                release(children[t])
                if progress is not None:
                    progress(done, total)
        finally:
            for _ in workers:
                ready.put(None)
            for worker in workers:
                worker.join(timeout=60)
            sys.setswitchinterval(interval)
        values = list(held.values())
        assert len({id(v) for v in values}) == len(values) == (self.threads if isinstance(shared, Rebuilt) else 0), \
            "threads running at the same time were handed the same set-up object"
        return results


@pytest.fixture(params=["serial", "threads"])
def make_runner(request):
    return CountingRunner if request.param == "serial" else ThreadRunner


def test_a_rebuilt_value_belongs_to_one_thread():
    made = []
    built = Rebuilt(lambda: made.append(object()) or made[-1], (), value="the caller's")
    assert built.value == "the caller's"
    seen = []
    threads = [threading.Thread(target=lambda: seen.extend([built.value, built.value])) for _ in range(2)]
    for thread in threads:
        thread.start()
        thread.join()
    assert len(made) == 2 and seen == [made[0], made[0], made[1], made[1]]
    assert built.value == "the caller's"


def test_a_thread_runner_places_results_by_index_whatever_order_tasks_finish_in():
    import time

    runner = ThreadRunner(threads=3, seed=1)
    ticks = []
    results = runner.map(lambda shared, job: (time.sleep(0.01 * (5 - job)), job * shared)[1], list(range(6)),
                         shared=2, progress=lambda d, t: ticks.append(d))
    assert results == [0, 2, 4, 6, 8, 10] and ticks == [1, 2, 3, 4, 5, 6]
    results = runner.tree(lambda shared, job, parent: (parent or 0) + job, [1, 10, 100, 1000], [-1, 0, 0, 1])
    assert results == [1, 11, 101, 1011]
    with pytest.raises(AssertionError, match="same set-up object"):  # the check the tests rely on
        runner.map(lambda shared, job: job, [1, 2, 3], shared=_Unsafe())


class _Unsafe(Rebuilt):
    """A Rebuilt that hands every thread one object (what Rebuilt did before it kept one per thread)."""

    def __init__(self):
        super().__init__(object, ())
        self.one = object()

    @property
    def value(self):
        return self.one


def test_serial_runner_orders_tasks_after_their_parents():
    runner = SerialRunner()
    seen = []
    results = runner.tree(lambda shared, job, parent: (seen.append(job), (parent or 0) + job + shared)[1],
                          [1, 10, 100, 1000], [-1, 0, 0, 1], shared=5, sizes=[1, 2, 3, 4],
                          progress=lambda d, t: seen.append((d, t)))
    assert results == [6, 21, 111, 1026]
    assert seen == [1, (1, 10), 10, (3, 10), 100, (6, 10), 1000, (10, 10)]
    assert runner.map(lambda shared, job: job * shared, [1, 2, 3], shared=2) == [2, 4, 6]
    with pytest.raises(ValueError, match="task 1 has parent 1"):
        check_parents([-1, 1])


def test_rebuilt_travels_as_its_inputs_and_is_built_once():
    made = []

    built = Rebuilt(_make_pair, (3, 4))
    assert built.value == (3, 4, 7) and built.value is built.value
    copy = pickle.loads(pickle.dumps(Rebuilt(_make_pair, (1, 2), value=made)))
    assert copy.value == (1, 2, 3)  # rebuilt, not the value it held


def _make_pair(a, b):
    return (a, b, a + b)


def test_histograms_and_matrix_blocks_through_a_runner_equal_the_plain_run(walk_capture, make_runner):
    _, _, frames = walk_capture
    meshes = [(V, F) for V, F, _ in frames]
    runner = make_runner()
    H, radius = frame_histograms(meshes, chunk=1)
    H_tasks, radius_tasks = frame_histograms(meshes, chunk=1, runner=runner)
    assert radius_tasks == radius and np.array_equal(H_tasks, H)
    D, yaw = dissimilarity_matrix(H, chunk=1)
    D_tasks, yaw_tasks = dissimilarity_matrix(H, chunk=1, runner=runner)
    assert np.array_equal(D_tasks, D) and np.array_equal(yaw_tasks, yaw)
    assert [name for name, _ in runner.calls] == ["histogram_task", "distance_task"]
    assert runner.calls[0][1] == len(frames) and runner.calls[1][1] > 1


def test_tree_pieces_through_a_runner_equal_the_plain_run(walk_capture, walk_aligner, make_runner):
    _, _, frames = walk_capture
    tree = chain_tree([3], root=1)  # pieces 1 | 0 | 2, two of them waiting for the first
    plain = align_tree(walk_aligner, frames[:3], tree, chunk=1)
    runner = make_runner()
    ticks = []
    tasks = align_tree(walk_aligner, frames[:3], tree, chunk=1, runner=runner, progress=lambda d, t: ticks.append(d))
    # the stage shows at 0 before any piece has finished (a job's record names it at once), then
    # moves as the runner's pieces finish
    assert runner.calls == [("piece_task", 3)] and ticks == [0, 1, 2, 3]
    for name in ("vertices", "residual", "residual_max", "distortion", "distortion_tail", "colour", "parent", "retried"):
        assert np.array_equal(getattr(tasks, name), getattr(plain, name), equal_nan=name == "colour"), name
    assert all(np.array_equal(tasks.poses[k], plain.poses[k]) for k in plain.poses)


_DISTANCE = np.abs(np.subtract.outer(np.arange(5), np.arange(5))).astype(float)   # frame distance as the dissimilarity


@pytest.fixture(scope="module")
def serial_repairs(walk_aligner):
    """``get(strategy)``: (meshes, a fresh copy of the walk with frames 2 and 3 slipped, the serial
    pass's repair of it), the serial pass made once per strategy (it does not change with the runner)."""
    import copy

    from engine.align import repair_alignment
    from engine.synthetic import SequenceSpec, build_body, generate_sequence_data

    from test_align_repair import _slipped

    data = generate_sequence_data(build_body(1000), SequenceSpec("walk", "gait", {"speed": 1.0, "cycles": 0.34,
                                                                                  "start_phase": 0.1}),
                                  fps=15, seed=1)
    meshes = data["unstructured"][:5]
    aligned = _slipped(walk_aligner, meshes, [2, 3])
    serial = {}

    def get(strategy):
        if strategy not in serial:
            serial[strategy] = copy.deepcopy(aligned)
            repair_alignment(walk_aligner, meshes, serial[strategy], dissimilarity=_DISTANCE, candidates=2,
                             strategy=strategy)
            assert serial[strategy].repaired[[2, 3]].all()
        return meshes, copy.deepcopy(aligned), serial[strategy]

    return get


def _repaired_serially_and_through(walk_aligner, serial_repairs, runner, strategy="root_first", ticks=None):
    """Frames 2 and 3 of a walk slipped, repaired by the serial pass and through ``runner``
    (frame distance as the dissimilarity): the results compared, the frames checked mended."""
    from engine.align import repair_alignment

    meshes, tasks, serial = serial_repairs(strategy)
    repair_alignment(walk_aligner, meshes, tasks, dissimilarity=_DISTANCE, candidates=2, runner=runner,
                     strategy=strategy, progress=None if ticks is None else (lambda d, t: ticks.append((d, t))))
    for name in ("vertices", "residual", "distortion_tail", "colour", "parent", "confidence", "repaired"):
        assert np.array_equal(getattr(tasks, name), getattr(serial, name), equal_nan=name == "colour"), name


@pytest.mark.parametrize("strategy", ["root_first", "together"])
def test_repairs_in_waves_through_a_runner_equal_the_serial_pass(walk_aligner, serial_repairs, make_runner, strategy):
    """Frame 3's trusted sources change once frame 2 is repaired, so the runner needs a second
    wave: the result is the same."""
    runner = make_runner()
    ticks = []
    _repaired_serially_and_through(walk_aligner, serial_repairs, runner, strategy, ticks)
    assert runner.calls and all(name == "repair_task" for name, _ in runner.calls)
    # the bar moves with a wave's alignments as they finish, and never goes back
    assert ticks[0][0] == 0 and ticks[-1][0] == ticks[-1][1] > 0
    assert all(b[0] > a[0] or b[1] != a[1] for a, b in zip(ticks, ticks[1:])), ticks


def test_decomposition_through_a_runner_equals_the_plain_run(make_runner):
    """The build's per-source decomposition: chunks of frames as tasks (each thread sets up its own
    decomposer: a shared one's solver buffer made nl_quaternions differ now and then)."""
    from engine.blend.decompose import FrameDecomposer, VolumetricEmbedding, decompose_frames
    from engine.synthetic import animate, build_body, gait

    body = build_body(1000)
    frames = animate(body, gait(body.skeleton, 1.2, cycles=0.5, fps=15))
    decomposer = FrameDecomposer(VolumetricEmbedding.from_surface(body.V, body.F))
    plain = decompose_frames(decomposer, frames)
    runner = make_runner()
    tasks = decompose_frames(decomposer, frames, runner=runner, chunk=1)
    assert runner.calls == [("decompose_task", len(frames))]
    for a, b in zip(plain, tasks, strict=True):
        assert a.tobytes() == b.tobytes()


def _shared_and_process(shared, job):
    """``factor`` x job, this process, and how many tasks this process's ``shared`` has seen."""
    import os

    shared["seen"].append(job)
    return shared["factor"] * job, os.getpid(), len(shared["seen"])


def test_a_process_runner_places_results_by_index_and_keeps_its_processes_for_the_same_shared():
    """``ProcessRunner``: results in the jobs' order, progress as tasks finish, ``shared`` set once
    per process (every task there sees the one object: its count of tasks grows), the processes
    kept while the calls pass the same ``shared`` and started again for another; one job runs here."""
    import collections
    import os

    from engine.tasks import ProcessRunner

    ticks = []
    shared = {"factor": 3, "seen": []}
    with ProcessRunner(2) as runner:
        first = runner.map(_shared_and_process, list(range(8)), shared=shared, sizes=[2] * 8,
                           progress=lambda d, t: ticks.append((d, t)))
        assert [r[0] for r in first] == [3 * k for k in range(8)] and ticks[-1] == (16, 16) and len(ticks) == 8
        pids = {r[1] for r in first}
        assert os.getpid() not in pids and 1 <= len(pids) <= 2 and shared["seen"] == []   # the caller's is untouched
        # one shared object per process: its tasks counted 1, 2, 3, ... there
        per_process = collections.defaultdict(list)
        for _, pid, count in first:
            per_process[pid].append(count)
        assert all(sorted(counts) == list(range(1, len(counts) + 1)) for counts in per_process.values())
        same = runner.map(_shared_and_process, list(range(8)), shared=shared)
        assert {r[1] for r in same} <= pids and sum(r[2] for r in same) > sum(range(1, 9))   # counts go on
        other = runner.map(_shared_and_process, list(range(8)), shared={"factor": 5, "seen": []})
        assert [r[0] for r in other] == [5 * k for k in range(8)] and not {r[1] for r in other} & pids
        assert runner.map(_shared_and_process, [4], shared={"factor": 2, "seen": []})[0][:2] == (8, os.getpid())
    assert runner._pool is None


def test_repairs_in_local_processes_equal_the_serial_pass(walk_aligner, serial_repairs):
    """The repair's waves in two processes (as ``align_captures`` runs them with ``workers`` 2 and
    no runner) give the serial pass's result to the last bit."""
    from engine.tasks import ProcessRunner

    with ProcessRunner(2) as runner:
        _repaired_serially_and_through(walk_aligner, serial_repairs, runner)
