"""The shape similarity tree: threshold, pruning, reconnection, minimum spanning tree, root."""

import numpy as np
import pytest
from scipy.sparse.csgraph import minimum_spanning_tree

from engine.align.similarity_tree import (
    chain_tree,
    pruned_graph,
    pruning_threshold,
    reconnect_components,
    similarity_tree,
    tree_root,
)
from engine.align.pictures import tree_image


def _symmetric(upper):
    D = np.array(upper, dtype=float)
    return D + D.T


# 5 frames; the minimum spanning tree is 0-1 (1), 1-2 (2), 1-3 (3), 3-4 (1.5)
HAND_MADE = _symmetric([[0, 1, 4, 6, 7],
                        [0, 0, 2, 3, 8],
                        [0, 0, 0, 5, 9],
                        [0, 0, 0, 0, 1.5],
                        [0, 0, 0, 0, 0]])


def _undirected(edges):
    return {tuple(sorted(map(int, e))) for e in edges}


def test_minimum_spanning_tree_of_a_hand_made_matrix():
    tree = similarity_tree(HAND_MADE, kind="mst")
    assert _undirected(tree.edges) == {(0, 1), (1, 2), (1, 3), (3, 4)}
    assert tree.weights.sum() == pytest.approx(7.5)
    assert tree.root == 1  # smallest sum of path lengths: 1 + 2 + 3 + 4.5
    assert tree.parent[tree.root] == -1
    # every frame comes after its parent in the order; depths and costs add up
    position = np.empty(5, dtype=int)
    position[tree.order] = np.arange(5)
    for child in range(5):
        if child != tree.root:
            assert position[tree.parent[child]] < position[child]
            assert tree.depth[child] == tree.depth[tree.parent[child]] + 1
            assert tree.cost[child] == pytest.approx(tree.cost[tree.parent[child]] + HAND_MADE[child, tree.parent[child]])


def test_threshold_is_the_largest_best_match_and_every_frame_keeps_its_best_match():
    rng = np.random.default_rng(3)
    D = _symmetric(np.triu(rng.uniform(0.1, 1.0, (30, 30)), 1))
    off = D + np.diag(np.full(30, np.inf))
    threshold = pruning_threshold(D)
    assert threshold == pytest.approx(off.min(axis=1).max())
    graph = pruned_graph(D, threshold)
    kept = graph + graph.T
    for i in range(30):
        assert kept[i, int(np.argmin(off[i]))] > 0


def test_split_components_are_reconnected_by_their_cheapest_edges():
    # two tight clusters {0,1,2} and {3,4}; cheapest cross edge 2-3 (5.0), then 1-4 (5.5)
    D = _symmetric([[0, 1, 1.2, 9, 8],
                    [0, 0, 1.1, 7, 5.5],
                    [0, 0, 0, 5.0, 6],
                    [0, 0, 0, 0, 1],
                    [0, 0, 0, 0, 0]])
    threshold = pruning_threshold(D)
    assert threshold == pytest.approx(1.1)
    graph, components = reconnect_components(D, pruned_graph(D, threshold))
    assert components == 2
    tree = similarity_tree(D, kind="mst")
    assert tree.components == 2
    assert (2, 3) in _undirected(tree.edges)
    # the pruned + reconnected tree has the weight of the unpruned minimum spanning tree
    assert tree.weights.sum() == pytest.approx(minimum_spanning_tree(D).sum())


def test_pruned_tree_equals_the_full_minimum_spanning_tree_on_random_matrices():
    rng = np.random.default_rng(0)
    for n in (2, 7, 40):
        points = rng.normal(size=(n, 3))
        D = np.linalg.norm(points[:, None] - points[None], axis=2)
        tree = similarity_tree(D, kind="mst")
        assert len(tree.edges) == n - 1
        assert tree.weights.sum() == pytest.approx(minimum_spanning_tree(D).sum())


def test_root_choice_given_and_central():
    path = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    assert tree_root(path, np.ones(4), 5) == 2
    assert tree_root(path, np.ones(4), 5, criterion="center") == 2
    assert tree_root(path, np.array([1.0, 1.0, 1.0, 10.0]), 5, criterion="center") == 3
    tree = similarity_tree(HAND_MADE, root=4, kind="mst")
    assert tree.root == 4 and tree.depth.max() == 3
    with pytest.raises(ValueError, match="root"):
        similarity_tree(HAND_MADE, root=9)


def test_chain_tree_is_frame_to_frame_tracking_from_the_root():
    tree = chain_tree([3, 4], root=2)
    assert tree.parent.tolist() == [1, 2, -1, 2, 3, 4, 5]
    assert tree.depth.tolist() == [2, 1, 0, 1, 2, 3, 4]


def test_tree_image():
    image = tree_image(similarity_tree(HAND_MADE), [2, 3], ["a", "b"], size=300)
    assert image.shape == (300, 300, 3) and image.dtype == np.uint8


def _long_performance(n=300, seed=2):
    """Dissimilarities of one long take (25 fps): a smooth path through pose space that revisits poses."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 25.0
    frequency, phase = rng.uniform(0.2, 1.5, size=4), rng.uniform(0.0, 2 * np.pi, size=4)
    poses = np.sin(t[:, None] * frequency * 2 * np.pi + phase) + 0.02 * rng.normal(size=(n, 4))
    return np.linalg.norm(poses[:, None] - poses[None], axis=2)


def test_paths_tree_is_each_frames_cheapest_path_and_much_shallower_than_the_mst():
    from scipy.sparse.csgraph import dijkstra

    D = _long_performance()
    mst = similarity_tree(D, kind="mst")
    paths = similarity_tree(D, kind="paths", power=3.0)
    assert paths.root == mst.root and len(paths.edges) == len(D) - 1
    assert sorted(paths.order.tolist()) == list(range(len(D)))
    # every frame's path cost is the cheapest over the pruned, reconnected graph
    graph, _ = reconnect_components(D, pruned_graph(D, paths.threshold))
    graph.data = (graph.data / paths.threshold) ** 3
    best = dijkstra(graph, directed=False, indices=paths.root)
    cost = np.zeros(len(D))
    for node in paths.order[1:]:
        parent = paths.parent[node]
        cost[node] = cost[parent] + (D[parent, node] / paths.threshold) ** 3
    np.testing.assert_allclose(cost, best, rtol=1e-9, atol=1e-12)
    assert paths.depth.mean() < 0.8 * mst.depth.mean()  # 15.2 against 21.2 frames deep
    assert paths.weights.mean() < 1.1 * mst.weights.mean()  # and no giant steps instead


def test_tree_kind_is_checked():
    with pytest.raises(ValueError, match="kind"):
        similarity_tree(HAND_MADE, kind="star")
