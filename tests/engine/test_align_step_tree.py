"""The tree of the cheapest expected error (engine/align/step_tree.py, ``kind="steps"``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from engine.align.similarity_tree import similarity_tree
from engine.align.step_tree import (STEP_HOP, STEP_UNIT, step_cost, step_graph, step_tree,
                                    temporal_neighbours)


def test_neighbours_in_time_stay_inside_their_sequence():
    pairs = temporal_neighbours([3, 2], 5, window=2)
    assert sorted(map(tuple, pairs.tolist())) == [(0, 1), (0, 2), (1, 2), (3, 4)]
    assert len(temporal_neighbours(None, 5)) == 0
    with pytest.raises(ValueError, match="5"):
        temporal_neighbours([3, 3], 5)


def test_a_step_costs_more_than_its_dissimilarity_says_and_more_between_frames_apart_in_time():
    d = np.array([0.0, 0.5, 1.0, 2.0]) * STEP_UNIT
    near, far = step_cost(d, True), step_cost(d, False)
    assert near[0] == far[0] == STEP_HOP  # no step comes free
    assert np.all(np.diff(near) > 0) and np.all(np.diff(far) > 0)
    assert far[3] > near[3]  # a big jump between frames apart in time costs most
    assert step_cost(2 * STEP_UNIT, False) - STEP_HOP > 8 * (step_cost(STEP_UNIT, False) - STEP_HOP)  # convex


def _chain_and_shortcut(n=12, gap=0.3):
    """One sequence moving steadily (each frame ``gap`` units from the last), then a second
    sequence whose frames are each a moderate jump from the first sequence's root."""
    x = np.arange(n) * gap * STEP_UNIT
    D = np.abs(x[:, None] - x[None])
    return D


def test_a_moderate_jump_beats_a_long_chain_of_small_steps():
    """The minimum spanning tree reaches the end of a steady motion through every frame; the
    steps tree jumps there from the root once a chain would add more than the jump."""
    D = _chain_and_shortcut()
    n = len(D)
    mst = similarity_tree(D, root=0, kind="mst", lengths=[n])
    steps = similarity_tree(D, root=0, kind="steps", lengths=[n])
    assert mst.depth.max() == n - 1  # the chain
    assert steps.depth.max() <= mst.depth.max() // 2  # 5 against 11
    # and every frame's path is its cheapest over the step graph
    edges, expected = step_tree(D, 0, [n])
    best = dijkstra(step_graph(D, [n]), directed=False, indices=0)
    np.testing.assert_allclose(expected, best)
    far = ~np.isin(np.abs(steps.edges[:, 0] - steps.edges[:, 1]), [1, 2])
    cost = np.zeros(n)
    for (p, c), jump in zip(steps.edges, far):
        cost[c] = cost[p] + step_cost(D[p, c], not jump)
    np.testing.assert_allclose(cost, expected)


def test_without_time_every_step_is_a_jump():
    """A subset of a capture (frames far apart, ``lengths`` None): no frame is a neighbour in time
    of another, so big steps cost the fourth power and the tree keeps them small."""
    D = _chain_and_shortcut(n=8, gap=0.3)  # (at 0.5 and above both trees are the chain: nothing to tell)
    assert step_graph(D, [8])[0, 2] == pytest.approx(step_cost(D[0, 2], True))
    assert step_graph(D)[0, 2] == pytest.approx(step_cost(D[0, 2], False))
    timed = similarity_tree(D, root=0, kind="steps", lengths=[8])
    apart = similarity_tree(D, root=0, kind="steps")
    assert not np.array_equal(apart.parent, timed.parent)
    assert apart.weights.max() <= timed.weights.max()  # 0.068 against 0.102
    assert apart.depth.max() >= timed.depth.max()  # 4 against 3


def test_the_tree_is_deterministic_and_spans_every_frame():
    rng = np.random.default_rng(4)
    poses = np.cumsum(rng.normal(scale=0.02, size=(200, 5)), axis=0)
    D = np.linalg.norm(poses[:, None] - poses[None], axis=2)
    a = similarity_tree(D, kind="steps", lengths=[120, 80])
    b = similarity_tree(D, kind="steps", lengths=[120, 80])
    assert np.array_equal(a.parent, b.parent) and a.root == b.root
    assert sorted(a.order.tolist()) == list(range(200)) and len(a.edges) == 199
