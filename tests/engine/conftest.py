"""Fixtures shared by the alignment tests: a short walk of a small synthetic body."""

import pytest

from engine.align import PairwiseAligner
from engine.synthetic import SequenceSpec, build_body, generate_sequence_data
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
