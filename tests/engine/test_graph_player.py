"""The graph player: transitions played, one-shots returning, the root carried, replays exact."""

import numpy as np
import pytest

from engine.graph import GraphError, GraphPlayer, MotionGraph, SearchOptions, TransitionSearch
from engine.graph.evaluate import Request, play_requests, transition_measures
from engine.graph.recording import perform, read_recording, recording


@pytest.fixture(scope="module")
def graph(motion_graph_file):
    with MotionGraph.open(motion_graph_file) as g:
        yield g


def _play(player, seconds, fps=30.0):
    return [player.step(1.0 / fps) for _ in range(int(seconds * fps))]


def test_walk_jump_and_back_to_the_stand_by_itself(graph):
    player = GraphPlayer(graph, node="walk", params={"speed": 1.2}, mode="linear")
    _play(player, 0.5)
    answer = player.request("jump", {"jump_height": 0.4})
    assert answer["status"] == "planned" and answer["route"] == ["walk", "jump"]
    frames = _play(player, 5.0)
    events = [e for f in frames for e in f.events]
    assert events[:2] == ["leave walk -> jump", "enter jump"]
    assert events[2:] == ["leave jump -> stand", "enter stand"]  # nobody asked: the one-shot returned
    entered = next(f for f in frames if "enter jump" in f.events)
    _, realised, _, _ = graph.node("jump").solve({"jump_height": 0.4})
    assert entered.params["jump_height"] == pytest.approx(float(realised[0]))  # the target's parameters, at once
    assert frames[-1].node == "stand" and frames[-1].target is None
    blending = [f for f in frames if f.progress is not None]
    assert blending and all(0 < f.progress < 1 + 1e-9 and f.target for f in blending)


def test_root_position_and_heading_stay_continuous(graph):
    player = GraphPlayer(graph, node="walk", params={"speed": 1.5}, mode="linear")
    requests = [(0.4, "stand", {}), (1.5, "walk", {"speed": 0.9}), (3.0, "jump", {"jump_height": 0.3})]
    frames = []
    for k in range(int(6 * 30)):
        for when, node, params in requests:
            if k == int(when * 30):
                player.request(node, params)
        frames.append(player.step(1 / 30))
    root = np.array([f.root_position for f in frames])
    steps = np.linalg.norm(np.diff(root, axis=0), axis=1)
    # never faster than the fastest walk the graph has (1.6 m/s) plus the foot lock's corrections
    assert steps.max() <= 1.6 / 30 * 1.5
    assert np.abs(np.diff([f.heading for f in frames])).max() < 1e-5  # these motions go straight


def test_requests_follow_routes_and_wait_for_one_shots(graph):
    player = GraphPlayer(graph, node="stand", mode="linear")
    player.request("jump", {"jump_height": 0.3})
    _play(player, 0.5)
    assert player.node.name == "jump"
    assert player.request("walk", {"speed": 1.0})["status"] == "queued"  # no edge jump -> walk: after the stand
    frames = _play(player, 5.0)
    entered = [e for f in frames for e in f.events if e.startswith("enter")]
    assert entered == ["enter stand", "enter walk"]
    assert player.request("walk", {"speed": 1.5})["status"] == "set"  # the node it is in: just its parameters
    with pytest.raises(GraphError, match="no node 'fly'"):
        player.request("fly")
    with pytest.raises(GraphError, match="unknown parameter"):
        player.request("jump", {"height": 1})
    with pytest.raises(GraphError, match="budget"):
        player.request("stand", budget=-1)
    with pytest.raises(GraphError, match="has no parameters"):
        player.request("stand", {"speed": 1})


def test_a_recording_replays_to_identical_frames(graph):
    script = [{"frame": 10, "node": "jump", "params": {"jump_height": 0.35}, "budget": None},
              {"frame": 100, "node": "walk", "params": {"speed": 1.1}, "budget": 0.6}]
    player, digest, answers = perform(graph, start="walk", params={"speed": 1.0}, fps=30.0, steps=150, mode="hybrid",
                                      requests=script)
    document = recording(graph, player, start="walk", params={"speed": 1.0}, fps=30.0, steps=150, mode="hybrid",
                         digest=digest)
    assert [r["frame"] for r in document["requests"]] == [10, 100] and answers[0]["status"] == "planned"
    checked = read_recording(document, graph)
    _, again, _ = perform(graph, start=checked["start"], params=checked["params"], fps=checked["fps"],
                          steps=checked["steps"], mode=checked["mode"], requests=checked["requests"])
    assert again == digest
    _, other, _ = perform(graph, start="walk", params={"speed": 1.0}, fps=30.0, steps=150, mode="hybrid",
                          requests=script[:1])
    assert other != digest
    with pytest.raises(GraphError, match="not this one"):
        read_recording({**document, "graph_checksum": "0" * 32}, graph)
    with pytest.raises(GraphError, match="not a morphspace-graph-recording"):
        read_recording({"format": "x"}, graph)


def test_feet_stay_put_entering_a_jump_from_the_stand(graph):
    requests = [Request(1.0, "jump", {"jump_height": 0.3}), Request(5.0, "jump", {"jump_height": 0.45})]
    frames, transitions, _ = play_requests(graph, TransitionSearch(graph), requests, start="stand")
    measures = transition_measures(graph, frames, transitions, fps=30.0)
    assert {(m["source"], m["target"]) for m in measures} == {("stand", "jump"), ("jump", "stand")}
    assert max(m["foot_slide_m"] for m in measures) < 0.01
    assert max(m["smoothness"] for m in measures) < 1.0


def test_set_params_changes_the_shown_node_at_once_and_replays(graph):
    player = GraphPlayer(graph, node="walk", params={"speed": 1.0}, mode="linear")
    _play(player, 0.2)
    answer = player.set_params({"speed": 1.5})
    assert answer["status"] == "set" and answer["node"] == "walk" and player.pending is None
    frame = player.step(1 / 30)
    _, realised, _, _ = graph.node("walk").solve({"speed": 1.5})
    assert frame.node == "walk" and frame.params["speed"] == pytest.approx(float(realised[0]))
    assert player.params_of("walk") == {"speed": 1.5}
    player.request("jump", {"jump_height": 0.3})
    while player.blend is None:
        player.step(1 / 30)
    assert player.set_params({"jump_height": 0.45})["node"] == "jump"  # during the blend: its target
    assert player.blend.clock.weights == pytest.approx(graph.node("jump").solve({"jump_height": 0.45})[0])
    with pytest.raises(GraphError, match="unknown parameter"):
        player.set_params({"speed": 1.0})
    requests = [{"frame": 5, "node": "walk", "params": {"speed": 1.4}, "budget": None, "set": True},
                {"frame": 20, "node": "jump", "params": {"jump_height": 0.3}, "budget": None}]
    played, digest, answers = perform(graph, start="walk", params={"speed": 1.0}, fps=30.0, steps=90, mode="linear",
                                      requests=requests)
    assert answers[0]["status"] == "set" and played.requests == requests
    _, again, _ = perform(graph, start="walk", params={"speed": 1.0}, fps=30.0, steps=90, mode="linear",
                          requests=played.requests)
    assert again == digest


def test_root_local_frames_place_to_the_world_frames(graph):
    from engine.graph.clock import place

    player = GraphPlayer(graph, node="walk", params={"speed": 1.2}, mode="linear")
    player.request("jump", {"jump_height": 0.3})
    for _ in range(12):
        player.step(1 / 30)
    local, world = player.frame(placed=False), player.frame()
    np.testing.assert_array_equal(place(local.vertices, local.root_position, local.heading), world.vertices)
    player.set_mode("hybrid")
    assert player.mode == "hybrid"
    with pytest.raises(ValueError, match="unknown blend mode"):
        player.set_mode("cubic")


def test_a_one_shot_is_performed_before_it_returns(graph):
    """The jump's first frames match the stand it came from: its return must not be blended in
    before ``min_exit`` of the clip (before, a reach was left at once and never seen)."""
    player = GraphPlayer(graph, node="stand", mode="linear")
    player.request("jump", {"jump_height": 0.45})
    frames = _play(player, 5.0)
    left = next(f for f in frames if "leave jump -> stand" in f.events)
    assert left.phase >= player.search.options.min_exit - 1e-6
    with pytest.raises(ValueError, match="out of range"):
        SearchOptions(min_exit=1.5)


def test_an_unrecorded_player_keeps_no_requests(graph):
    """A stream's player (record=False) plays the same but does not grow a list per message."""
    player = GraphPlayer(graph, node="walk", params={"speed": 1.0}, mode="linear", record=False)
    for k in range(50):
        player.set_params({"speed": 1.0 + 0.01 * k})
        player.step(1 / 30)
    player.request("jump", {"jump_height": 0.3})
    assert player.requests == [] and player.pending is not None


def test_a_player_on_phase_tables_plays_the_same_frames(graph):
    """A stream's player (tables=True) reads the spaces' phase tables at weights that recur
    instead of blending every frame: the same frames up to float32 rounding, across transitions
    and at new parameters; the events identical, the root (moved by the foot lock) to a micrometre."""
    players = [GraphPlayer(graph, node="walk", params={"speed": 1.2}, mode="hybrid", tables=tables)
               for tables in (False, True)]
    script = {10: ("jump", {"jump_height": 0.35}), 100: ("walk", {"speed": 0.9}), 160: ("stand", {})}
    largest = 0.0
    for k in range(240):
        if k in script:
            for player in players:
                player.request(*script[k])
        exact, tabled = (player.step(1 / 30, placed=False) for player in players)
        assert tabled.events == exact.events and tabled.node == exact.node
        np.testing.assert_allclose(tabled.root_position, exact.root_position, atol=1e-6)  # the foot lock's rounding
        largest = max(largest, float(np.abs(tabled.vertices - exact.vertices).max()))
    assert largest < 2e-5  # metres: float32 rounding of one interpolation
    assert players[1].clock.tables and graph.node("stand").space.frame_blender("hybrid").hits > 0


class _Recording:
    """A search that records how it was called."""

    def __init__(self, search):
        self.inner, self.options, self.calls = search, search.options, []

    def search(self, *args, **kwargs):
        self.calls.append((args[0], args[3], kwargs))
        return self.inner.search(*args, **kwargs)


def test_a_one_shot_left_for_another_node_may_leave_early(graph_spaces, tmp_path):
    """Asked for a cyclic node along another edge than its return (jump -> walk here), a one-shot
    is left as the latency weight says, early where the seam allows; its own return is performed
    (from min_exit, no latency cost), asked for or not."""
    from engine.graph.tiny import TINY_EDGES, build_tiny_graph

    path = tmp_path / "abort.mgraph"
    build_tiny_graph(graph_spaces, path, edges=TINY_EDGES + [("jump", "walk")])
    with MotionGraph.open(path) as g:
        search = _Recording(TransitionSearch(g))
        player = GraphPlayer(g, node="stand", mode="linear", search=search)
        player.request("jump", {"jump_height": 0.3})
        while player.node.name != "jump" or player.blend is not None:
            player.step(1 / 30)
        source, target, kwargs = search.calls[-1]  # planned on entering the jump: its return
        assert (source, target) == ("jump", "stand") and not kwargs["early"] and kwargs["latency_weight"] == 0.0
        player.request("stand")
        assert not search.calls[-1][2]["early"]  # its own return, asked for: still performed
        player.request("walk", {"speed": 1.2})
        source, target, kwargs = search.calls[-1]
        assert (source, target) == ("jump", "walk") and kwargs["early"] and kwargs["latency_weight"] is None
        # early, but not through a worse seam than leaving from min_exit on would give
        plan = player.pending[0]
        late = TransitionSearch(g).search("jump", player.clock.weights, player.clock.phase, "walk",
                                          plan.target_weights, latency_weight=0.0)
        assert plan.leave_phase >= g.node("jump").samples.phases[0] and (
            plan.leave_phase >= search.options.min_exit or plan.dissimilarity <= late.dissimilarity + 1e-12)


def test_the_latest_request_wins_and_says_what_it_dropped(graph):
    player = GraphPlayer(graph, node="walk", params={"speed": 1.2}, mode="linear")
    assert player.request("stand")["dropped"] is None
    answer = player.request("jump", {"jump_height": 0.3})  # before the stand's transition started
    assert answer["status"] == "planned" and answer["dropped"] == "planned"
    while player.blend is None:
        player.step(1 / 30)
    waiting = player.request("walk", {"speed": 1.0})      # during the blend into the jump: waits
    assert waiting["status"] == "queued" and waiting["dropped"] is None  # the jump is carried out
    latest = player.request("stand")
    assert latest["status"] == "queued" and latest["dropped"] == "queued"
    events = []
    while not any(e.startswith("plan queued") for e in events):
        events = player.step(1 / 30).events
    assert events == ["enter jump", "plan queued stand"] and player.queued is None
    assert player.planned["status"] == "planned" and player.planned["route"] == ["jump", "stand"]
