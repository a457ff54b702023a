"""Motion graph files: windows, dissimilarity tables, the .mgraph container and its errors."""

import numpy as np
import pytest

from engine.graph import GraphError, MotionGraph, NodeSpec, WindowOptions, build_graph
from engine.graph.features import dissimilarity, node_samples, window
from engine.motion_space import MotionSpace


def test_dissimilarity_is_the_rms_difference_of_windows():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 3, 30)), rng.normal(size=(3, 2, 30))
    D = dissimilarity(a, b)
    assert D.shape == (2, 3, 3, 2)
    brute = np.sqrt(((a[1, 2] - b[0, 1]) ** 2).sum() / 10)  # 30 numbers = 10 3-vectors
    assert D[1, 2, 0, 1] == pytest.approx(brute, rel=1e-5)
    assert np.abs(np.diagonal(dissimilarity(a, a).reshape(6, 6))).max() < 1e-3


def test_a_standing_window_stays_put_and_a_walking_one_travels(graph_spaces):
    options = WindowOptions()
    vertices = np.arange(0, 1000, 10)
    with MotionSpace.open(graph_spaces / "walk.mspace") as walk, MotionSpace.open(graph_spaces / "stand.mspace") as idle:
        def travel(space, weights):
            w = window(space, weights, 0.0, options, vertices)
            placed = w[: options.frames * len(vertices) * 3].reshape(options.frames, -1, 3)
            return float(np.linalg.norm(placed[-1].mean(0) - placed[0].mean(0)))
        seconds = (options.frames - 1) * options.step
        assert travel(walk, [1.0, 0.0]) == pytest.approx(0.9 * seconds, rel=0.3)
        assert travel(idle, [0.5, 0.5]) < 0.005
        samples = node_samples(walk, options)
        assert samples.weights.shape == (5, 2) and samples.params[:, 0] == pytest.approx(np.sort(samples.params[:, 0]))
        assert node_samples(idle, options).weights.shape == (1, 2)  # no parameters: one sample


def test_graph_file_round_trip(motion_graph_file, graph_spaces):
    with MotionGraph.open(motion_graph_file) as graph:
        assert [n.name for n in graph.nodes] == ["walk", "stand", "jump"]
        assert graph.node("jump").meta["return_to"] == "stand"  # the first cyclic node it has an edge to
        there, back = graph.edges[("walk", "stand")], graph.edges[("stand", "walk")]
        assert np.array_equal(there, back.transpose(2, 3, 0, 1))
        assert graph.route("walk", "jump") == ["walk", "jump"] and graph.route("jump", "walk") == ["jump", "stand",
                                                                                                   "walk"]
        # standing still and the jump's standing start are alike; walking and standing are not
        jump_from_stand = graph.edges[("stand", "jump")]
        assert jump_from_stand.min() < 0.01 < graph.edges[("walk", "stand")].min()
        recorded = graph.node("stand").meta["space"]  # relative to the graph file
        assert (motion_graph_file.parent / recorded).resolve() == (graph_spaces / "stand.mspace").resolve()


def test_bad_graphs_are_refused_with_the_reason(graph_spaces, tmp_path):
    walk, jump = NodeSpec("walk", graph_spaces / "walk.mspace"), NodeSpec("jump", graph_spaces / "jump.mspace")
    with pytest.raises(GraphError, match="both ends must be nodes"):
        build_graph(tmp_path / "g.mgraph", [walk, jump], [("walk", "run")], name="g")
    with pytest.raises(GraphError, match="no edge to a cyclic node"):
        build_graph(tmp_path / "g.mgraph", [walk, jump], [("walk", "jump")], name="g")
    with pytest.raises(GraphError, match="return_to is for one-shot"):
        build_graph(tmp_path / "g.mgraph", [NodeSpec("walk", walk.space, "jump"), jump], [("jump", "walk")], name="g")
    assert not (tmp_path / "g.mgraph").exists()


def test_truncated_foreign_and_stale_files_say_so(motion_graph_file, graph_spaces, tmp_path):
    data = motion_graph_file.read_bytes()
    (tmp_path / "cut.mgraph").write_bytes(data[: len(data) // 2])
    with pytest.raises(GraphError, match="truncated"):
        MotionGraph.open(tmp_path / "cut.mgraph")
    with pytest.raises(GraphError, match="not a morphspace-motion-graph"):
        MotionGraph.open(graph_spaces / "walk.mspace")
    (tmp_path / "text.mgraph").write_text("hello")
    with pytest.raises(GraphError, match="text.mgraph"):
        MotionGraph.open(tmp_path / "text.mgraph")
    # a graph whose space was rebuilt since
    copy = tmp_path / "spaces"
    copy.mkdir()
    for name in ("walk", "jump"):
        (copy / f"{name}.mspace").write_bytes((graph_spaces / f"{name}.mspace").read_bytes())
    nodes = [NodeSpec("walk", copy / "walk.mspace"), NodeSpec("jump", copy / "jump.mspace")]
    build_graph(copy / "g.mgraph", nodes, [("walk", "jump"), ("jump", "walk")], name="g")
    (copy / "jump.mspace").write_bytes((graph_spaces / "stand.mspace").read_bytes())
    with pytest.raises(GraphError, match="changed since the graph was built"):
        MotionGraph.open(copy / "g.mgraph")


def test_the_same_graph_build_gives_the_same_bytes(graph_spaces, tmp_path):
    """Built twice from the same spaces: the same file, byte for byte (the build's time is only in
    the returned report)."""
    copy = tmp_path / "spaces"
    copy.mkdir()
    for name in ("walk", "jump"):
        (copy / f"{name}.mspace").write_bytes((graph_spaces / f"{name}.mspace").read_bytes())
    nodes = [NodeSpec("walk", copy / "walk.mspace"), NodeSpec("jump", copy / "jump.mspace")]
    first = build_graph(copy / "a.mgraph", nodes, [("walk", "jump"), ("jump", "walk")], name="g")
    build_graph(copy / "b.mgraph", nodes, [("walk", "jump"), ("jump", "walk")], name="g")
    assert (copy / "a.mgraph").read_bytes() == (copy / "b.mgraph").read_bytes()
    assert first["build_s"] > 0 and "build_s" not in MotionGraph.open(copy / "a.mgraph").metadata


def test_a_different_mesh_structure_says_what_differs():
    """Spaces with the same vertex count but other faces (the body's vertices renumbered): the
    message says the faces differ (it showed '1000 vs 1000 vertices')."""
    from types import SimpleNamespace

    from engine.graph.build import check_graph

    faces = np.array([[0, 1, 2], [0, 2, 3]])
    a = SimpleNamespace(n_vertices=4, faces=faces, cyclic=True)
    b = SimpleNamespace(n_vertices=4, faces=faces[:, ::-1], cyclic=True)
    c = SimpleNamespace(n_vertices=5, faces=faces, cyclic=True)
    nodes = [NodeSpec("a", "a.mspace"), NodeSpec("b", "b.mspace")]
    with pytest.raises(GraphError, match=r"\(the same 4 vertices, joined by other faces\)"):
        check_graph(nodes, [("a", "b"), ("b", "a")], [a, b])
    with pytest.raises(GraphError, match=r"\(5 vs 4 vertices\)"):
        check_graph(nodes, [("a", "b"), ("b", "a")], [a, c])
    assert check_graph(nodes, [("a", "b"), ("b", "a")], [a, a]) == ([(0, 1), (1, 0)], [-1, -1])
