"""Rigid starts from a ring of placements (engine.align.ring): a body laid down on the floor is found.

The aligner's upright start turns the source about the vertical only; a frame pitched onto the
floor was aligned from there 35% of the model size off on the studio dance (docs/evaluation.md).
"""

from dataclasses import replace

import numpy as np
import pytest

from engine.align.matching import TargetSurface
from engine.align.options import AlignmentOptions
from engine.align.pairwise import PairwiseAligner
from engine.align.rigid import rodrigues
from engine.align.ring import long_axis, refine_placement, ring_start, turn_onto
from engine.surface import vertex_normals
from engine.synthetic import build_body

OPTIONS = AlignmentOptions(levels=2, patches=10)


def test_turn_onto_takes_one_direction_onto_another_by_the_smallest_angle():
    rng = np.random.default_rng(1)
    for _ in range(20):
        a, b = rng.normal(size=(2, 3))
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        R = turn_onto(a, b)
        np.testing.assert_allclose(R @ a, b, atol=1e-12)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        angle = np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))
        assert angle == pytest.approx(np.arccos(np.clip(a @ b, -1, 1)), abs=1e-9)
    up = np.array([0.0, 1.0, 0.0])
    np.testing.assert_allclose(turn_onto(up, -up) @ up, -up, atol=1e-12)   # opposite: a half turn
    np.testing.assert_allclose(turn_onto(up, up), np.eye(3))


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


def test_the_long_axis_of_a_standing_body_is_vertical_and_turns_with_it(body):
    axis = long_axis(body.V)
    assert abs(axis[1]) > 0.95
    R = rodrigues(np.array([[1.2, 0.3, 0.0]]))[0]
    assert abs(long_axis(body.V @ R.T) @ (R @ axis)) > 0.99


def laid_down(body, axis, degrees):
    """The body turned by ``degrees`` about ``axis`` and moved: a target in the root's own vertex
    order, so vertex i's true place is vertex i."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    R = rodrigues((axis * np.radians(degrees))[None])[0]
    return body.V @ R.T + np.array([0.3, -0.5, 0.2])


@pytest.fixture(scope="module")
def aligner(body):
    return PairwiseAligner(body.V, body.F, body.colors, options=OPTIONS)


@pytest.mark.parametrize("axis, degrees, colours", [([1, 0, 0], 90, True), ([1, 0, 0], 90, False),
                                                   ([0, 0, 1], 120, True), ([1, 0, 1], 180, False)])
def test_a_body_laid_down_is_aligned_from_the_ring_and_not_from_the_upright_start(body, aligner, axis, degrees,
                                                                                   colours):
    """Face down, on its side, upside down: turned about the vertical only, the upright start
    leaves the body 33-55% of the model size off (75 degrees' pitch it still finds by ICP)."""
    truth = laid_down(body, axis, degrees)
    target = TargetSurface(truth, body.F, body.colors if colours else None)
    result = aligner.align(aligner.V_tet, target)
    error = np.linalg.norm(result.V - truth, axis=1).mean() / body.size
    assert result.orientations >= 2 and error < 0.02, f"{100 * error:.1f}% of the model size"
    # without the ring, the upright start leaves it standing
    upright = PairwiseAligner(body.V, body.F, body.colors, tets=(aligner.V_tet, aligner.T),
                              options=replace(OPTIONS, ring_margin=0.0))
    alone = upright.align(upright.V_tet, target)
    assert alone.orientations == 1
    assert np.linalg.norm(alone.V - truth, axis=1).mean() / body.size > 0.1


def test_between_neighbouring_poses_the_ring_adds_no_start(body, aligner):
    turn = rodrigues(np.array([[0.0, np.radians(10.0), 0.0]]))[0]
    target = TargetSurface(body.V @ turn.T + np.array([0.05, 0.0, 0.02]), body.F, body.colors)
    rng = np.random.default_rng(0)
    sample = rng.choice(len(body.V), size=600, replace=False)
    normals = vertex_normals(body.V, body.F)[sample]
    centre = body.V.mean(axis=0)
    upright = refine_placement(body.V[sample], normals, np.eye(3), target.centre - centre, target, OPTIONS)
    assert ring_start(body.V[sample], normals, centre, target, OPTIONS, body.colors[sample], upright) is None
    assert aligner.align(aligner.V_tet, target).orientations == 1
