"""Task runners (engine.tasks): the split stages give the same result through a runner as without."""

import pickle

import numpy as np
import pytest

from engine.align import align_tree, chain_tree
from engine.align.similarity import dissimilarity_matrix, frame_histograms
from engine.tasks import Rebuilt, SerialRunner, check_parents


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
    assert copy._value is None and copy.value == (1, 2, 3)  # rebuilt, not the value it held


def _make_pair(a, b):
    return (a, b, a + b)


def test_histograms_and_matrix_blocks_through_a_runner_equal_the_plain_run(walk_capture):
    _, _, frames = walk_capture
    meshes = [(V, F) for V, F, _ in frames]
    runner = CountingRunner()
    H, radius = frame_histograms(meshes, chunk=1)
    H_tasks, radius_tasks = frame_histograms(meshes, chunk=1, runner=runner)
    assert radius_tasks == radius and np.array_equal(H_tasks, H)
    D, yaw = dissimilarity_matrix(H, chunk=1)
    D_tasks, yaw_tasks = dissimilarity_matrix(H, chunk=1, runner=runner)
    assert np.array_equal(D_tasks, D) and np.array_equal(yaw_tasks, yaw)
    assert [name for name, _ in runner.calls] == ["histogram_task", "distance_task"]
    assert runner.calls[0][1] == len(frames) and runner.calls[1][1] > 1


def test_tree_pieces_through_a_runner_equal_the_plain_run(walk_capture, walk_aligner):
    _, _, frames = walk_capture
    tree = chain_tree([3], root=1)  # pieces 1 | 0 | 2, two of them waiting for the first
    plain = align_tree(walk_aligner, frames[:3], tree, chunk=1)
    runner = CountingRunner()
    ticks = []
    tasks = align_tree(walk_aligner, frames[:3], tree, chunk=1, runner=runner, progress=lambda d, t: ticks.append(d))
    assert runner.calls == [("piece_task", 3)] and ticks == [1, 2, 3]
    for name in ("vertices", "residual", "residual_max", "distortion", "distortion_tail", "parent", "retried"):
        assert np.array_equal(getattr(tasks, name), getattr(plain, name)), name
    assert all(np.array_equal(tasks.poses[k], plain.poses[k]) for k in plain.poses)


def test_repairs_in_waves_through_a_runner_equal_the_serial_pass(walk_aligner):
    """Frames 2 and 3 slipped; with frame distance as the dissimilarity, frame 3's trusted sources
    change once frame 2 is repaired, so the runner needs a second wave: the result is the same."""
    import copy

    from engine.align import repair_alignment
    from engine.synthetic import SequenceSpec, build_body, generate_sequence_data

    from test_align_repair import _slipped

    data = generate_sequence_data(build_body(1000), SequenceSpec("walk", "gait", {"speed": 1.0, "cycles": 0.34,
                                                                                  "start_phase": 0.1}),
                                  fps=15, seed=1)
    meshes = data["unstructured"][:5]
    aligned = _slipped(walk_aligner, meshes, [2, 3])
    D = np.abs(np.subtract.outer(np.arange(5), np.arange(5))).astype(float)
    serial, tasks = copy.deepcopy(aligned), copy.deepcopy(aligned)
    repair_alignment(walk_aligner, meshes, serial, dissimilarity=D, candidates=2)
    runner = CountingRunner()
    repair_alignment(walk_aligner, meshes, tasks, dissimilarity=D, candidates=2, runner=runner)
    assert serial.repaired[[2, 3]].all()
    assert runner.calls and all(name == "repair_task" for name, _ in runner.calls)
    for name in ("vertices", "residual", "distortion_tail", "parent", "confidence", "repaired"):
        assert np.array_equal(getattr(tasks, name), getattr(serial, name)), name
