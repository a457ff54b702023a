"""Feet held across transitions (engine/graph/feet.py, legs.py): the legs found on the rest mesh
and moved by a two-bone solution, the clips' contacts, a planted foot held and let go, and the
player's transitions without sliding."""

import numpy as np
import pytest

from engine.graph import GraphPlayer, MotionGraph, TransitionSearch
from engine.graph.clock import foot_vertices
from engine.graph.evaluate import Request, own_motion_step, play_requests, transition_measures
from engine.graph.feet import FootPins, contact_table
from engine.graph.legs import LegRig


@pytest.fixture(scope="module")
def graph(motion_graph_file):
    with MotionGraph.open(motion_graph_file) as g:
        yield g


@pytest.fixture(scope="module")
def rest(graph):
    return np.asarray(graph.nodes[0].space.container["rest"])


def test_the_legs_are_found_on_their_own_side_below_the_crotch(rest):
    feet = foot_vertices(rest)
    rig = LegRig(rest, feet)
    height = rest[:, 1].max() - rest[:, 1].min()
    for k, (foot, leg, side) in enumerate(zip(feet, rig.legs, (1, -1))):
        assert set(foot) <= set(leg["index"].tolist())
        assert np.all(np.sign(rest[leg["index"], 0]) == side)               # one leg, its own side
        assert rest[leg["index"], 1].max() - rest[:, 1].min() < 0.5 * height
        w = leg["weights"]                                                    # thigh, shin, foot
        assert np.all(w >= 0) and np.all(w.sum(1) <= 1 + 1e-9)
        assert np.all(w[np.isin(leg["index"], foot), 2] == 1.0)              # the foot moves as a whole
        hip, knee, ankle = rig.joints(rest, k)
        assert hip[1] > knee[1] > ankle[1] and 0.4 * height < leg["length"] < 0.6 * height


def test_a_leg_carries_its_foot_keeping_thigh_and_shin_lengths(graph, rest):
    """A walk's frame, one foot moved 8 cm forward and the other 5 cm sideways: each foot moves by
    exactly its offset and stays at its height, the thigh and the shin keep their lengths (the
    shear below the knee it replaces stretched the shin by several percent), the body above the
    crotch does not move."""
    feet = foot_vertices(rest)
    rig = LegRig(rest, feet)
    walk = graph.node("walk")
    mesh = np.array(walk.space.blender("linear").blend(walk.samples.weights[0], 0.3), dtype=np.float32)
    held = mesh.copy()
    offsets = np.array([[0.0, 0.0, 0.08], [0.05, 0.0, 0.0]])
    shares = rig.deform(held, offsets)
    np.testing.assert_allclose(shares, [1.0, 1.0])
    for foot, offset in zip(feet, offsets):
        np.testing.assert_allclose(held[foot] - mesh[foot], np.broadcast_to(offset, (len(foot), 3)), atol=1e-5)
    np.testing.assert_allclose(rig.segments(held), rig.segments(mesh), rtol=0.02)
    untouched = np.setdiff1d(np.arange(len(mesh)), rig.index)
    np.testing.assert_array_equal(held[untouched], mesh[untouched])


def test_an_offset_out_of_reach_is_shortened_to_what_the_leg_reaches(rest):
    """The standing rest pose (legs straight): the leg cannot carry its foot far sideways without
    lengthening more than ``stretch``, so only part of the offset is carried; never more than the
    cap."""
    feet = foot_vertices(rest)
    rig = LegRig(rest, feet, cap=0.2, stretch=0.0)
    mesh = rest.astype(np.float32)
    far = np.array([[0.3, 0.0, 0.0], [0.0, 0.0, 0.0]])
    held = mesh.copy()
    t = rig.deform(held, far)[0]
    assert 0.0 <= t < 1.0
    assert t * 0.3 <= 0.2 * rig.legs[0]["length"] + 1e-9
    hip, knee, ankle = rig.joints(held, 0)
    l1, l2 = rig.segments(mesh)[0]
    assert np.linalg.norm(ankle - hip) <= (l1 + l2) * 1.01                 # not stretched beyond the leg


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
    probe = FootPins(rest, feet, pins.ground)
    probe.offsets[:] = pins.offsets
    probe.apply(mesh, heading=np.pi / 2)                      # world -x is root-local +z at a quarter turn
    np.testing.assert_allclose(mesh[feet[0]] - rest[feet[0]], [[0.0, 0.0, -0.03]] * len(feet[0]), atol=1e-5)
    straight = FootPins(rest, feet, pins.ground, stretch=0.0)  # the straight legs of the rest pose: not 15 cm
    straight.offsets[:] = [[-0.15, 0.0], [0.0, 0.0]]
    mesh = rest.astype(np.float32).copy()
    straight.apply(mesh, heading=np.pi / 2)
    carried = straight.offsets[0, 0]
    assert -0.15 < carried < 0.0 and straight.shortened == pytest.approx(0.15 + carried)  # what it reaches
    np.testing.assert_allclose(mesh[feet[0]] - rest[feet[0]], [[0.0, 0.0, carried]] * len(feet[0]), atol=1e-5)
    up = [d + [0.0, 0.2, 0.0] for d in down]                  # in the air: shrinks at 1 m/s
    change = pins.update(up, up, np.array([False, False]), 1 / 100, blending=False)
    np.testing.assert_allclose(np.hypot(*pins.offsets.T), [0.02, 0.02], atol=1e-9)
    change = pins.update(down, down, np.array([True, True]), 0.5, blending=False)  # planted after it: creeps
    np.testing.assert_allclose(np.hypot(*pins.offsets.T), [0.01, 0.01], atol=1e-9)
    pins.update(up, up, np.array([False, False]), 1.0, blending=False)
    assert not pins.holding()


def test_walking_into_a_stand_and_out_again_keeps_the_feet_and_the_root(graph):
    """The tiny graph blends its walk straight into its stand (no captured stop): the hardest
    case for the feet. A foot is never held farther than the cap (a fifth of the leg), the legs
    keep their lengths within the stretch allowed, no foot slides on the ground except in the walk
    -> stand (a stride blended into feet side by side: the stride's front foot would be held more
    than the cap away, so it slides by the rest), and no root step is larger than the two nodes'
    own (the root moves as the blend says)."""
    requests = [Request(1.0, "stand", {}), Request(3.0, "walk", {"speed": 1.5}), Request(5.0, "jump", {}),
                Request(8.5, "walk", {"speed": 1.0})]
    frames, transitions, _ = play_requests(graph, TransitionSearch(graph), requests, start="walk",
                                           params={"speed": 1.2}, legs=True)
    measures = transition_measures(graph, frames, transitions, fps=30.0)
    assert {("walk", "stand"), ("stand", "walk"), ("walk", "jump")} <= {(m["source"], m["target"]) for m in measures}
    assert max(m["foot_slide_m"] for m in measures if (m["source"], m["target"]) != ("walk", "stand")) < 1e-4
    assert max(m["foot_slide_m"] for m in measures) < 0.1
    rest = np.asarray(graph.nodes[0].space.container["rest"])
    rig = LegRig(rest, foot_vertices(rest))
    assert frames["held"].max() <= 0.2 * max(leg["length"] for leg in rig.legs) + 1e-6
    assert frames["segments"].max() < 0.1 and np.median(frames["segments"][frames["held"] > 0]) < 0.02
    assert max(m["root_ratio"] for m in measures) <= 1.0 + 1e-6


def test_without_the_hold_the_blend_slides_the_feet(graph):
    """What the hold is for: the same walk -> stand with foot_lock off slides the feet about twice
    as far (held, they slide only by what is beyond the legs' reach and the cap: this direct blend
    of a stride into feet side by side needs a step it does not take)."""
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
    assert slides[True] < 0.6 * slides[False]


def test_the_root_reference_is_the_largest_step_at_any_phase(graph):
    _, root = own_motion_step(graph, "walk", graph.node("walk").solve({"speed": 1.6})[0], 30.0)
    _, coarse = own_motion_step(graph, "walk", graph.node("walk").solve({"speed": 1.6})[0], 30.0, offsets=1)
    assert root >= coarse > 1.5 / 30 * 0.8


def test_both_feet_contacts_at_once_are_foot_slides_pivots(rest):
    """clock.contact_moves over the stacked feet gives each foot's foot_slide move, bit for bit
    (None where the foot is off the ground), over random frames with feet up, down and half down."""
    from engine.graph.clock import contact_moves, foot_slide

    feet = foot_vertices(rest)
    ground = float(rest[:, 1].min()) + 0.01
    bounds = np.cumsum([0] + [len(f) for f in feet]).tolist()
    rng = np.random.default_rng(3)
    seen = set()
    for _ in range(300):
        before = (rest[np.concatenate(feet)] + rng.normal(0, 0.01, (bounds[-1], 3))).astype(np.float32)
        after = (before + rng.normal(0, 0.01, before.shape)).astype(np.float32)
        for k in range(len(feet)):
            lift = rng.choice([0.0, 0.2])  # a foot in the air
            before[bounds[k]:bounds[k + 1], 1] += lift
            after[bounds[k]:bounds[k + 1], 1] += lift
        moves = contact_moves(before, after, ground, bounds)
        for k, move in enumerate(moves):
            _, expected = foot_slide(before[bounds[k]:bounds[k + 1]], after[bounds[k]:bounds[k + 1]], ground)
            assert (move is None) == (expected is None)
            if move is not None:
                assert move.dtype == expected.dtype and move.tobytes() == expected.tobytes()
            seen.add(move is None)
    assert seen == {True, False}
