"""The root race: the trial's two best candidates align the capture, the more confident wins
(engine.align.root_race, engine.align.align_captures with root_choice="race")."""

import pickle

import numpy as np
import pytest

from engine.align import align_captures, root_race
from engine.align.options import AlignmentOptions
from engine.align.root_race import (
    TRACKED_SHARE,
    finalists,
    neighbour_share,
    no_race_reason,
    no_trial_reason,
    race_frames,
    race_score,
    sub_similarity,
)
from engine.mesh_io import Mesh
from engine.synthetic import SequenceSpec, build_body, generate_sequence_data

OPTIONS = AlignmentOptions(levels=1, patches=10)


@pytest.fixture(scope="module")
def walk24():
    """24 unstructured frames of a walk, 1,000 vertices: just long enough for the trial and the race."""
    body = build_body(1000)
    data = generate_sequence_data(body, SequenceSpec("walk", "gait", {"speed": 1.2, "cycles": 1.5}), fps=15, seed=3)
    frames = [Mesh(V, F) for V, F, _ in data["unstructured"]]
    assert len(frames) == 24
    return frames, np.array([len(frames)])


def test_finalists_are_the_trials_least_bad_candidates_ties_to_the_earlier():
    trial = {"candidates": [7, 3, 9, 1], "mean": [2.0, 1.5, 1.5, 3.0]}
    assert finalists(trial) == [3, 9]
    assert finalists(trial, count=3) == [3, 9, 7]
    assert finalists({"candidates": [4], "mean": [1.0]}) == [4]
    # a candidate that could not be filled with tetrahedra (infinite badness) never races
    assert finalists({"candidates": [7, 3, 9], "mean": [2.0, float("inf"), 1.0]}) == [9, 7]
    assert finalists({"candidates": [7, 3], "mean": [2.0, float("inf")]}) == [7]


def test_race_frames_are_all_of_a_short_capture_else_spread_evenly_with_the_finalists():
    assert race_frames(40, [3, 17], limit=64) == list(range(40))
    assert race_frames(128, [3, 17], limit=64) == list(range(128))  # a subset, then all again, costs more
    frames = race_frames(600, [5, 598], limit=64)
    assert len(frames) == 64 and frames == sorted(set(frames)) and {5, 598} <= set(frames)
    gaps = np.diff(frames)
    assert gaps.max() <= 2 * 600 / 62 + 1, gaps  # no stretch of the take left out


def test_race_score_is_the_mean_confidence_of_the_other_frames():
    assert race_score([1.0, 0.2, 0.4, 0.6], 0) == pytest.approx(0.4)
    assert race_score([0.3, 1.0], 1) == pytest.approx(0.3)
    assert race_score([1.0], 0) == 1.0


@pytest.fixture(scope="module")
def raced(walk24, build_once):
    """walk24 aligned with the race, one worker (asked for: a dense take is not raced by default);
    made once for all xdist workers (pickled under the run's shared directory)."""
    def race(directory):
        frames, lengths = walk24
        run = align_captures(frames, lengths, options=OPTIONS, workers=1, root_choice="race")
        (directory / "raced.pkl").write_bytes(pickle.dumps(run))

    return pickle.loads((build_once("morphspace-walk24-raced", race) / "raced.pkl").read_bytes())


def test_the_race_keeps_the_more_confident_finalist_and_its_alignment_is_that_roots_own(walk24, raced):
    frames, lengths = walk24
    run = raced
    trial = run.root_trial
    race = trial["race"]
    assert race["finalists"] == finalists(trial) and len(race["finalists"]) == 2
    assert race["frames"] == len(frames)  # a short capture is raced whole
    assert int(run.aligned.root) == race["winner"] == race["finalists"][int(np.argmax(race["confidence"]))]
    at = race["finalists"].index(race["winner"])
    assert race["confidence"][at] == round(race_score(run.aligned.confidence, run.aligned.root), 4)
    assert run.timings["race"] >= 0.0 and run.timings["align"] > 0.0
    # the winning run is kept as it is: the same as aligning from that root, given
    alone = align_captures(frames, lengths, options=OPTIONS, workers=1, root=race["winner"])
    assert np.array_equal(alone.aligned.vertices, run.aligned.vertices)
    assert np.array_equal(alone.aligned.confidence, run.aligned.confidence)
    # the trial alone stops at its own best candidate
    tried = align_captures(frames, lengths, options=OPTIONS, workers=1, root_choice="trial")
    assert "race" not in tried.root_trial and int(tried.aligned.root) == race["finalists"][0]


def test_a_long_capture_races_a_subset_then_the_winner_aligns_it_all(walk24, monkeypatch):
    frames, lengths = walk24
    monkeypatch.setattr(root_race, "RACE_FRAMES", 10)  # 24 frames: over twice 10
    run = align_captures(frames, lengths, options=OPTIONS, workers=1, root_choice="race")
    race = run.root_trial["race"]
    assert race["frames"] == 10 and int(run.aligned.root) == race["winner"]
    assert run.aligned.vertices.shape[0] == len(frames)
    alone = align_captures(frames, lengths, options=OPTIONS, workers=1, root=race["winner"])
    assert np.array_equal(alone.aligned.vertices, run.aligned.vertices)


def test_sub_similarity_is_the_frames_rows_and_columns(walk24):
    from engine.align.similarity import shape_dissimilarity

    frames, lengths = walk24
    similarity = shape_dissimilarity(frames[:8], np.array([8]), window=2, workers=1)
    picked = [1, 4, 6]
    sub = sub_similarity(similarity, picked)
    assert np.array_equal(sub.dissimilarity, similarity.dissimilarity[np.ix_(picked, picked)])
    assert np.array_equal(sub.yaw, similarity.yaw[np.ix_(picked, picked)])
    assert len(sub.histograms) == 3 and list(sub.lengths) == [3]


def test_finalists_raced_side_by_side_in_two_processes_give_the_same_alignment(walk24, raced):
    """With two workers the finalists align at the same time, one process each (a race's tree
    is one piece or two, so one finalist kept one core busy); the result is the serial race's."""
    frames, lengths = walk24
    serial = raced
    seen = []
    both = align_captures(frames, lengths, options=OPTIONS, workers=2, root_choice="race",
                          progress=lambda stage, done, total: seen.append((stage, done, total)))
    assert both.root_trial["race"] == serial.root_trial["race"]
    assert np.array_equal(both.aligned.vertices, serial.aligned.vertices)
    assert np.array_equal(both.aligned.confidence, serial.aligned.confidence)
    race = [(done, total) for stage, done, total in seen if stage == "race"]
    assert race and race[-1] == (2 * len(frames), 2 * len(frames))  # every frame of both finalists counted
    assert [done for done, _ in race] == sorted(done for done, _ in race)


def test_neighbour_share_counts_the_steps_between_neighbours_in_time_within_a_sequence():
    chain = np.array([-1, 0, 1, 2, 3])
    assert neighbour_share(chain, None) == 1.0 and neighbour_share(chain, np.array([5])) == 1.0
    # frames 2 and 3 are neighbours in the global numbering but not in time: different sequences
    assert neighbour_share(chain, np.array([3, 2])) == pytest.approx(3 / 4)
    jumps = np.array([-1, 0, 0, 1, 1])  # 1 <- 0 is a neighbour step; 2 <- 0, 3 <- 1, 4 <- 1 are not
    assert neighbour_share(jumps, None) == pytest.approx(1 / 4)
    assert neighbour_share(np.array([-1]), None) == 0.0


def test_auto_does_not_race_a_densely_tracked_take_and_race_does():
    chain = np.concatenate([[-1], np.arange(29)])        # 30 frames, every one from its neighbour
    jumps = np.concatenate([[-1], np.zeros(29, dtype=np.int64)])   # every frame from frame 0
    assert neighbour_share(chain, None) >= TRACKED_SHARE > neighbour_share(jumps, None)
    reason = no_race_reason(chain, None, "auto")
    assert reason.startswith("the trial's choice: no race on a densely tracked take (100% of the tree's steps")
    assert no_race_reason(jumps, None, "auto") is None and no_race_reason(chain, None, "race") is None
    # two sequences, each tracked frame after frame: raced all the same (the root decides which lies near it)
    two = np.concatenate([[-1], np.arange(14), [0], np.arange(15, 29)])   # 15 + 15 frames, one step between them
    assert neighbour_share(two, np.array([15, 15])) >= TRACKED_SHARE
    assert no_race_reason(two, np.array([15, 15]), "auto") is None
    assert no_race_reason(two, np.array([30]), "auto").startswith("the trial's choice")
    assert no_race_reason(two, np.array([30, 0]), "auto") is not None   # an empty sequence is not another take
    assert no_trial_reason(23) == "the spread's choice, `apart`: no trial or race on fewer than 24 frames"
    assert no_trial_reason(24) is None


def test_auto_keeps_the_trials_choice_on_a_tracked_take_and_says_why(walk24, raced, monkeypatch):
    """A tree whose steps join neighbours in time (TRACKED_SHARE of them or more) is tried but not
    raced by default: the trial's choice aligns it, exactly as root_choice="trial" does.
    walk24's tree is not a chain (a walk's frames a stride apart look alike: 52% of its steps
    join neighbours), so the share asked for is lowered to make it one."""
    frames, lengths = walk24
    monkeypatch.setattr(root_race, "TRACKED_SHARE", 0.3)
    auto = align_captures(frames, lengths, options=OPTIONS, workers=1)
    assert "race" not in auto.root_trial and "race" not in auto.timings and "trial" in auto.timings
    assert "no race on a densely tracked take" in auto.root_reason
    assert int(auto.aligned.root) == raced.root_trial["race"]["finalists"][0]   # the trial's best
    # unchanged: the default on a tree that is not a chain races, as "race" does
    assert raced.root_reason is None
