"""What the search predicts by playing its candidates (engine/graph/terms.py): smoothness and
foot drift as the evaluation measures them, and the search taking the best of its candidates."""

import numpy as np
import pytest

from engine.graph import MotionGraph, SearchOptions, TransitionSearch
from engine.graph.evaluate import Request, play_requests, transition_measures
from engine.graph.terms import node_profile, predict, tracked_vertices


@pytest.fixture(scope="module")
def graph(motion_graph_file):
    with MotionGraph.open(motion_graph_file) as g:
        yield g


class _Recorded:
    """A search that keeps every plan it returns."""

    def __init__(self, search):
        self.inner, self.options, self.plans = search, search.options, []

    def search(self, *args, **kwargs):
        plan = self.inner.search(*args, **kwargs)
        self.plans.append(plan)
        return plan


def test_the_predicted_smoothness_is_the_measured_one(graph):
    """Played by the player and measured by ``evaluate``, each transition's smoothness is close
    to what the search predicted over its few tracked vertices (they include the fastest)."""
    search = _Recorded(TransitionSearch(graph))
    requests = [Request(1.0, "stand", {}), Request(3.0, "walk", {"speed": 1.5}), Request(5.0, "jump", {}),
                Request(8.5, "walk", {"speed": 1.0})]
    frames, transitions, _ = play_requests(graph, search, requests, start="walk", params={"speed": 1.2})
    measures = transition_measures(graph, frames, transitions, fps=30.0)
    ratios = []
    for t, m in zip(transitions, measures):
        plan = next(p for p in search.plans if (p.source, p.target, p.dissimilarity, p.length)
                    == (t["source"], t["target"], t["dissimilarity"], t["length"]))
        assert plan.smoothness is not None and plan.foot_drift >= 0.0
        ratios.append(plan.smoothness / m["smoothness"])
    assert len(ratios) >= 4
    assert 0.6 < np.median(ratios) < 1.25 and min(ratios) > 0.4 and max(ratios) < 2.0, ratios


def test_own_motion_alone_and_a_stride_blended_into_feet_side_by_side(graph):
    """Played without blending, a node's predicted steps are its own (ratio at most 1); walking
    into the stand, a foot both keep on the ground drifts, standing into the stand it does not."""
    tracked = tracked_vertices(graph)
    walk, stand = node_profile(graph.node("walk"), tracked), node_profile(graph.node("stand"), tracked)
    phases = np.linspace(0.0, 0.95, 20)
    ratio, _ = predict(walk, 0, phases, walk, 0, phases, np.full(20, 0.3))
    assert np.all(ratio <= 1.0 + 1e-6) and ratio.max() > 0.5
    _, drift = predict(walk, len(graph.node("walk").samples.weights) - 1, phases, stand, 0, np.zeros(20),
                       np.full(20, 0.5))
    _, still = predict(stand, 0, phases, stand, 0, phases, np.full(20, 0.5))
    assert drift.max() > 0.05 and still.max() < 0.01


def test_the_search_takes_smoother_transitions_than_seam_and_latency_alone(graph):
    """Walk -> stand from ten phases: with the predictions weighted, the plans are predicted
    smoother on the whole than those by seam and latency alone, and cost no less by those."""
    walk, stand = graph.node("walk"), graph.node("stand")
    plain = TransitionSearch(graph, SearchOptions(candidates=0))
    played = TransitionSearch(graph, SearchOptions(candidates=5, smooth_weight=1.0, foot_weight=0.0))
    pa, pb = played._profiles["walk"], played._profiles["stand"]
    ka = walk.sample_of(walk.samples.weights[3])
    smooth_plain, smooth_played = [], []
    for phase in np.linspace(0.0, 0.9, 10):
        args = ("walk", walk.samples.weights[3], float(phase), "stand", stand.samples.weights[0])
        a, b = plain.search(*args), played.search(*args)
        assert b.smoothness is not None and a.smoothness is None
        assert b.cost >= a.cost - 1e-9  # the cheapest by seam and latency is a's
        predicted, _ = predict(pa, ka, np.array([a.leave_phase]), pb, 0, np.array([a.enter_phase]),
                               np.array([a.length]))
        smooth_plain.append(float(predicted[0]))
        smooth_played.append(b.smoothness)
    assert np.mean(smooth_played) < np.mean(smooth_plain), (smooth_played, smooth_plain)
