"""Run-time transition search: the cheapest plan over every candidate, budgets, constraints."""

import itertools

import pytest

from engine.graph import GraphError, MotionGraph, SearchOptions, TransitionSearch


@pytest.fixture(scope="module")
def graph(motion_graph_file):
    with MotionGraph.open(motion_graph_file) as g:
        yield g


def _brute_force(graph, search, source, weights, phase, target, target_weights):
    """Every (leave sample, entry sample, length) with its cost, enumerated one by one."""
    a, b = graph.node(source), graph.node(target)
    D = graph.edges[(source, target)][a.sample_of(weights), :, b.sample_of(target_weights), :]
    duration = a.space.root_track.duration(weights)
    o = search.options
    best = None
    for j, e, length in itertools.product(range(len(a.samples.phases)), range(len(b.samples.phases)), o.lengths):
        if not b.cyclic and b.samples.phases[e] > o.max_entry + 1e-9:
            continue
        wait = ((a.samples.phases[j] - phase) % 1.0) * duration
        cost = D[j, e] / graph.model_size * o.reference_length / length + o.latency_weight * (wait + length)
        if best is None or cost < best[0]:
            best = (cost, wait, b.samples.phases[e], length)
    return best


@pytest.mark.parametrize("weight", [0.0, 0.3, 3.0])
def test_search_finds_the_cheapest_candidate(graph, weight):
    """Without playing candidates (``candidates=0``) the plan is the cheapest by seam and latency."""
    search = TransitionSearch(graph, SearchOptions(latency_weight=weight, candidates=0))
    walk, jump = graph.node("walk"), graph.node("jump")
    w, target = walk.samples.weights[2], jump.samples.weights[4]
    phase = walk.samples.phases[5]  # on a sample: leaving now is the sample itself
    plan = search.search("walk", w, phase, "jump", target)
    cost, wait, enter, length = _brute_force(graph, search, "walk", w, phase, "jump", target)
    assert plan.cost == pytest.approx(cost, rel=1e-5)
    assert (plan.leave_in, plan.enter_phase, plan.length) == pytest.approx((wait, enter, length))
    assert plan.enter_phase <= search.options.max_entry  # a one-shot is entered near its start


def test_latency_weight_trades_seam_for_time(graph):
    walk, idle = graph.node("walk"), graph.node("stand")
    args = ("walk", walk.samples.weights[0], 0.3, "stand", idle.samples.weights[0])
    patient = TransitionSearch(graph, SearchOptions(latency_weight=0.0)).search(*args)
    hasty = TransitionSearch(graph, SearchOptions(latency_weight=50.0)).search(*args)
    assert hasty.latency <= patient.latency and hasty.dissimilarity >= patient.dissimilarity
    assert hasty.leave_in == 0.0


def test_budget_and_finish_by_are_kept(graph):
    search = TransitionSearch(graph, SearchOptions(latency_weight=0.0))
    walk, idle = graph.node("walk"), graph.node("stand")
    args = ("walk", walk.samples.weights[0], 0.3, "stand", idle.samples.weights[0])
    assert search.search(*args, budget=0.4).latency <= 0.4 + 1e-9
    assert search.search(*args, budget=0.01).latency == min(search.options.lengths)  # nothing fits: quickest
    jump = graph.node("jump")
    plan = search.search("jump", jump.samples.weights[0], 0.6, "stand", idle.samples.weights[0], finish_by=0.6)
    assert plan.leave_phase >= search.options.min_exit and plan.latency <= 0.6 + 1e-9
    # from phase 0.5 nothing ends within 0.6 s (a one-shot is not left before min_exit): the quickest
    plan = search.search("jump", jump.samples.weights[0], 0.5, "stand", idle.samples.weights[0], finish_by=0.6)
    first = jump.samples.phases[jump.samples.phases >= search.options.min_exit][0]
    assert plan.leave_phase == pytest.approx(first) and plan.length == min(search.options.lengths)


def test_no_edge_is_a_clear_error(graph):
    with pytest.raises(GraphError, match="no edge jump -> walk; from jump: stand"):
        TransitionSearch(graph).search("jump", [0.5, 0.5], 0.2, "walk", [0.5, 0.5])
