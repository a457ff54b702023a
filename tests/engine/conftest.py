"""Fixtures shared by engine tests: a short walk of a small synthetic body; a hand hanging and
reaching (the limb tests); small motion spaces and a motion graph over them."""

import pytest

from engine.align import PairwiseAligner
from engine.synthetic import SequenceSpec, animate, build_body, generate_sequence_data
from engine.synthetic.reaches import reach
from engine.tetmesh import tetrahedralize


@pytest.fixture(scope="session")
def walk_capture():
    """(body, template vertices (3, n, 3), unstructured frames [(V, F, colors)] * 3) of a walk."""
    body = build_body(1000)
    data = generate_sequence_data(body, SequenceSpec("walk", "gait", {"speed": 1.0, "cycles": 0.2,
                                                                      "start_phase": 0.1}),
                                  fps=15, seed=1)
    return body, data["vertices"], data["unstructured"]


@pytest.fixture(scope="session")
def walk_aligner(walk_capture):
    """A PairwiseAligner on the walk's first unstructured frame."""
    _, _, frames = walk_capture
    V, F, C = frames[0]
    return PairwiseAligner(V, F, C, tets=tetrahedralize(V, F, resolution=48))


@pytest.fixture(scope="module")
def reach_pair():
    """The plain 1,000-vertex body with its right hand hanging, and reaching forward at 1.4 m."""
    body = build_body(1000)
    motion = reach(body.skeleton, 1.4, fps=15)
    frames = animate(body, motion)
    V0, V1 = frames[0], frames[motion.events["peak_frame"]]
    return body, V0, V1, tetrahedralize(V0, body.F, resolution=48)


@pytest.fixture(scope="session")
def export_spaces(built_spaces):
    """{"speed": a cyclic two-gait speed chain, "jump": a one-shot two-jump distance chain}: open
    MotionSpaces of a 1,000-vertex body at 15 fps, for the export and player tests (the shared built_spaces)."""
    from engine.motion_space import MotionSpace

    spaces = {name: MotionSpace.open(built_spaces / f"{name}.mspace") for name in ("speed", "jump")}
    yield spaces
    for space in spaces.values():
        space.close()


@pytest.fixture(scope="session")
def graph_spaces(built_graph):
    """Directory with the tiny graph's walk, stand and jump spaces (engine.graph.tiny; the shared
    built_graph's directory, which also holds reach.mspace and tiny.mgraph)."""
    return built_graph


@pytest.fixture(scope="session")
def motion_graph_file(graph_spaces, tmp_path_factory):
    """The tiny .mgraph over the graph spaces (walk <-> stand -> jump -> stand, walk -> jump)."""
    from engine.graph.tiny import build_tiny_graph

    path = tmp_path_factory.mktemp("graph") / "tiny.mgraph"
    build_tiny_graph(graph_spaces, path)
    return path
