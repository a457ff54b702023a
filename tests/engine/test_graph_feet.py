"""Feet held across transitions (engine/graph/feet.py): the legs found on the rest mesh, the
clips' contacts, a planted foot held and let go, and the player's transitions without sliding."""

import numpy as np
import pytest

from engine.graph import GraphPlayer, MotionGraph, TransitionSearch
from engine.graph.clock import foot_vertices
from engine.graph.evaluate import Request, own_motion_step, play_requests, transition_measures
from engine.graph.feet import FootPins, contact_table, leg_weights


@pytest.fixture(scope="module")
def graph(motion_graph_file):
    with MotionGraph.open(motion_graph_file) as g:
        yield g


@pytest.fixture(scope="module")
def rest(graph):
    return np.asarray(graph.nodes[0].space.container["rest"])


def test_legs_carry_the_whole_offset_at_the_feet_and_none_above_the_knee(rest):
    feet = foot_vertices(rest)
    legs = leg_weights(rest, feet)
    height = rest[:, 1].max() - rest[:, 1].min()
    for foot, (index, weights), side in zip(feet, legs, (1, -1)):
        assert set(foot) <= set(index.tolist())
        assert np.all(weights[np.isin(index, foot)] == 1.0)        # the foot moves as a whole
        assert np.all(np.sign(rest[index, 0]) == side)             # one leg, its own side
        assert rest[index, 1].max() - rest[:, 1].min() < 0.27 * height
        assert weights.min() >= 0.0 and weights.max() == 1.0


def test_a_standing_idle_plants_both_feet_and_a_jump_lifts_them(graph, rest):
    feet = foot_vertices(rest)
    ground = float(rest[:, 1].min()) + 0.01
    stand = contact_table(graph.node("stand").space, feet, ground)
    assert stand.all()
    jump = contact_table(graph.node("jump").space, feet, ground)
    assert jump[:, 0].all() and jump[:, -1].all()           # standing before and after
    assert not jump.all(axis=(0, 2)).all()                  # in the air in between
    walk = contact_table(graph.node("walk").space, feet, ground)
    assert 0.2 < walk.mean() < 0.9                           # each foot down for part of the stride


def test_a_planted_foot_is_held_and_let_go_in_the_air(rest):
    feet = foot_vertices(rest)
    pins = FootPins(rest, feet, float(rest[:, 1].min()) + 0.01, release=1.0, creep=0.02)
    down = [rest[f].astype(float) for f in feet]
    slid = [d + [0.03, 0.0, 0.0] for d in down]               # both feet slide 3 cm along x
    change = pins.update(down, slid, np.array([True, True]), 1 / 30, blending=True)
    np.testing.assert_allclose(change, [[-0.03, 0.0], [-0.03, 0.0]], atol=1e-9)
    assert pins.holding()
    mesh = rest.astype(np.float32).copy()
    pins.shift(mesh, pins.offsets, heading=np.pi / 2)         # world -x is root-local +z at a quarter turn
    np.testing.assert_allclose(mesh[feet[0]] - rest[feet[0]], [[0.0, 0.0, -0.03]] * len(feet[0]), atol=1e-6)
    up = [d + [0.0, 0.2, 0.0] for d in down]                  # in the air: shrinks at 1 m/s
    change = pins.update(up, up, np.array([False, False]), 1 / 100, blending=False)
    np.testing.assert_allclose(np.hypot(*pins.offsets.T), [0.02, 0.02], atol=1e-9)
    change = pins.update(down, down, np.array([True, True]), 0.5, blending=False)  # planted after it: creeps
    np.testing.assert_allclose(np.hypot(*pins.offsets.T), [0.01, 0.01], atol=1e-9)
    pins.update(up, up, np.array([False, False]), 1.0, blending=False)
    assert not pins.holding()


def test_walking_into_a_stand_and_out_again_keeps_the_feet_and_the_root(graph):
    """The tiny graph blends its walk straight into its stand (no captured stop): the hardest
    case for the feet. None slides on the ground across the transitions, and no root step is
    larger than the two nodes' own (the root moves as the blend says)."""
    requests = [Request(1.0, "stand", {}), Request(3.0, "walk", {"speed": 1.5}), Request(5.0, "jump", {}),
                Request(8.5, "walk", {"speed": 1.0})]
    frames, transitions, _ = play_requests(graph, TransitionSearch(graph), requests, start="walk",
                                           params={"speed": 1.2})
    measures = transition_measures(graph, frames, transitions, fps=30.0)
    assert {("walk", "stand"), ("stand", "walk"), ("walk", "jump")} <= {(m["source"], m["target"]) for m in measures}
    assert max(m["foot_slide_m"] for m in measures) < 1e-4
    assert max(m["root_ratio"] for m in measures) <= 1.0 + 1e-6


def test_without_the_hold_the_blend_slides_the_feet(graph):
    """What the hold is for: the same walk -> stand with foot_lock off slides a foot."""
    player = GraphPlayer(graph, node="walk", params={"speed": 1.2}, mode="linear", foot_lock=False)
    held = GraphPlayer(graph, node="walk", params={"speed": 1.2}, mode="linear")
    from engine.graph.clock import foot_slide

    feet = foot_vertices(np.asarray(graph.nodes[0].space.container["rest"]))
    ground = float(np.asarray(graph.nodes[0].space.container["rest"])[:, 1].min()) + 0.01
    slides = {False: 0.0, True: 0.0}
    for p, key in ((player, False), (held, True)):
        for _ in range(15):
            p.step(1 / 30)
        p.request("stand", {})
        before = p.frame().vertices
        while p.blend is not None or p.pending is not None:
            now = p.step(1 / 30).vertices
            slides[key] += sum(foot_slide(before[f], now[f], ground)[0] for f in feet)
            before = now
    assert slides[True] < 1e-4 < slides[False]


def test_the_root_reference_is_the_largest_step_at_any_phase(graph):
    _, root = own_motion_step(graph, "walk", graph.node("walk").solve({"speed": 1.6})[0], 30.0)
    _, coarse = own_motion_step(graph, "walk", graph.node("walk").solve({"speed": 1.6})[0], 30.0, offsets=1)
    assert root >= coarse > 1.5 / 30 * 0.8
