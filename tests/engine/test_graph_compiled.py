"""The held feet's compiled kernels (engine/graph/compiled.py) against the numpy formulations they
replace: the joints' ring means, the feet placed in the world, the contacts' least moves; a held
foot read without moving the legs is exactly where the legs' move puts it; the server's warm-up
compiles every signature a graph stream calls."""

import math

import numpy as np
import pytest

from engine.graph import MotionGraph
from engine.graph import compiled
from engine.graph.clock import contact_moves, foot_vertices, place
from engine.graph.legs import LegRig


@pytest.fixture(scope="module")
def graph(motion_graph_file):
    with MotionGraph.open(motion_graph_file) as g:
        yield g


def frames(graph, count, seed):
    """Random root-local float32 frames of the graph's nodes."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        node = graph.nodes[int(rng.integers(len(graph.nodes)))]
        w = node.samples.weights[int(rng.integers(len(node.samples.weights)))]
        yield np.array(node.space.blender("hybrid").blend(w, float(rng.uniform())), dtype=np.float32), rng


def test_ring_means_are_the_rings_centroids(graph):
    rest = np.asarray(graph.nodes[0].space.container["rest"])
    rig = LegRig(rest, foot_vertices(rest))
    for mesh, _ in frames(graph, 20, seed=1):
        for k, leg in enumerate(rig.legs):
            expected = [mesh[leg["rings"][name]].astype(np.float64).mean(axis=0) for name in ("hip", "knee", "ankle")]
            np.testing.assert_allclose(rig.joints(mesh, k), expected, rtol=0, atol=1e-12)
            np.testing.assert_allclose(rig.joints(mesh.astype(np.float64), k), expected, rtol=0, atol=1e-12)


def test_feet_in_the_world_are_the_placed_feet_and_a_held_foot_is_where_the_legs_put_it(graph):
    rest = np.asarray(graph.nodes[0].space.container["rest"])
    feet = foot_vertices(rest)
    rig = LegRig(rest, feet)
    index = np.concatenate(feet).astype(np.int64)
    bounds = np.cumsum([0] + [len(f) for f in feet]).astype(np.int64)
    held = 0
    for mesh, rng in frames(graph, 40, seed=2):
        position, heading = rng.normal(size=3) * [3.0, 0.0, 3.0], float(rng.uniform(-math.pi, math.pi))
        world = compiled.feet_world(mesh, index, bounds, position, heading)
        np.testing.assert_allclose(world, place(mesh[index], position, heading), rtol=0, atol=2e-6)
        offsets = np.zeros((2, 3))
        offsets[:, [0, 2]] = rng.normal(scale=0.05, size=(2, 2))
        shares, joints = rig.reach(mesh, offsets)
        moved = mesh.copy()
        rig.move(moved, offsets, shares, joints)
        # read without moving the legs: bit for bit the feet the move writes
        local = compiled.feet_world(mesh, index, bounds, np.zeros(3), 0.0, (offsets, shares))
        assert np.array_equal(local, moved[index])
        held += int((shares > 0).sum())
    assert held > 0


def test_contact_moves_are_the_numpy_ones():
    rng = np.random.default_rng(3)
    bounds = [0, 30, 30, 70]  # a foot without vertices among them
    for _ in range(50):
        before = rng.normal(scale=0.05, size=(70, 3)).astype(np.float32)
        after = (before + rng.normal(scale=0.01, size=(70, 3))).astype(np.float32)
        moves, found = compiled.contact_moves(before, after, 0.0, bounds)
        expected = contact_moves(before, after, 0.0, bounds)
        assert found.tolist() == [m is not None for m in expected]
        for move, ok, want in zip(moves, found, expected):
            if ok:
                assert np.array_equal(move, want)


def test_warm_up_compiles_every_signature_a_graph_stream_calls(graph):
    """After ``warm_up`` (a server's start), a held frame's calls compile nothing new."""
    compiled.warm_up()
    from engine.graph import terms

    kernels = (compiled._ring_means, compiled._move_legs, compiled._feet_world, compiled._contact_moves,
               terms._play_blends)
    before = [len(kernel.signatures) for kernel in kernels]
    assert all(before)
    from engine.graph import GraphPlayer

    player = GraphPlayer(graph, record=False, tables=True)
    held = 0  # (the requests' searches play their candidates: terms.predict)
    for node in ("jump", "walk", "stand", "walk"):
        if node in {n.name for n in graph.nodes}:
            player.request(node)
        for _ in range(90):
            player.step(1 / 30, placed=False)
            held += player.pins.holding()
    assert held > 0  # frames with a foot held: every kernel ran
    assert [len(kernel.signatures) for kernel in kernels] == before


def test_predicted_candidates_are_the_numpy_plays(graph):
    """The search's compiled play of candidate blends (terms.predict) gives exactly the numbers of
    the numpy formulation (terms._play and the same reductions), over every edge."""
    from engine.graph import terms
    from engine.graph.search import TransitionSearch

    search = TransitionSearch(graph)
    rng = np.random.default_rng(5)
    for a, b in graph.edges:
        pa, pb = search._profiles[a], search._profiles[b]
        for _ in range(10):
            ka, kb = int(rng.integers(pa.points.shape[0])), int(rng.integers(pb.points.shape[0]))
            phase_a, phase_b = rng.random(8), rng.random(8)
            lengths = rng.choice([0.15, 0.3, 0.5, 0.7], 8)
            frames = np.maximum(np.rint(lengths / terms.FRAME).astype(int), 1)
            count = int(frames.max())
            steps, feet, down = terms._play(pa, ka, phase_a, pb, kb, phase_b, frames, count)
            inside = np.arange(count)[None, :] < frames[:, None]
            ratio = np.where(inside, steps, 0.0).max(1) / max(pa.largest[ka], pb.largest[kb], 1e-9)
            moved = np.sqrt(((feet[:, 1:] - feet[:, :-1]) ** 2).sum(-1))
            held = down[:, 1:] & down[:, :-1] & inside[:, :, None]
            drift = np.where(held, moved, 0.0).sum(1).max(-1)
            got_ratio, got_drift = terms.predict(pa, ka, phase_a, pb, kb, phase_b, lengths)
            assert np.array_equal(got_ratio, ratio) and np.array_equal(got_drift, drift)
