"""Tests for engine.evaluation: blend errors (Table I), heatmaps, epsilon sweep, ground truth."""

import numpy as np
import pytest

from engine import evaluation
from engine.motion_space import MotionSpace, SourceClip, build_motion_space
from engine.synthetic import animate, build_body, gait

SPEEDS = (0.8, 3.0)  # a walk and a run
EPSILON = 0.005
N_PHASES = 8


def gait_clip(body, name, speed):
    """Two cycles of a straight gait (the build finds and aligns one)."""
    motion = gait(body.skeleton, speed, cycles=2.0, start_phase=0.0)
    return SourceClip(name=name, vertices=animate(body, motion), fps=motion.fps, cyclic=True)


@pytest.fixture(scope="module")
def body():
    return build_body(1000)


@pytest.fixture(scope="module")
def space(body, tmp_path_factory):
    path = tmp_path_factory.mktemp("spaces") / "walk_run.mspace"
    clips = [gait_clip(body, "walk", SPEEDS[0]), gait_clip(body, "run", SPEEDS[1])]
    build_motion_space(path, clips, body.F, name="walk_run", n_phases=N_PHASES, epsilon=EPSILON, rest=body.V)
    with MotionSpace.open(path) as opened:
        yield opened


@pytest.fixture(scope="module")
def cache(space):
    return evaluation.BlendCache(space)


@pytest.fixture(scope="module")
def errors(space, cache):
    return evaluation.blend_errors(space, cache=cache, timing_calls=20, nonlinear_timing_calls=3)


def test_weight_grid_leaves_out_the_sources():
    np.testing.assert_allclose(evaluation.weight_grid(2), np.stack([np.arange(9, 0, -1), np.arange(1, 10)], 1) / 10)
    W = evaluation.weight_grid(3)
    assert W.shape == (12, 3)  # 15 points of a level-4 grid on a triangle, minus its 3 corners
    np.testing.assert_allclose(W.sum(axis=1), 1.0)
    assert W.max() == 0.75


def test_nonlinear_row_is_exact_and_all_methods_are_reported(errors):
    assert list(errors["methods"]) == list(evaluation.METHODS)
    assert errors["methods"]["nonlinear"]["max_error_mm"] == 0.0
    assert errors["methods"]["nonlinear"]["mean_error_mm"] == 0.0
    assert len(errors["weights"]) == 9 and len(errors["phases"]) == N_PHASES
    for row in errors["methods"].values():
        assert row["time_per_frame_ms"] > 0
        assert row["frames_per_second"] == pytest.approx(1000.0 / row["time_per_frame_ms"])
        assert row["max_error_percent"] == pytest.approx(row["max_error_mm"] / 10 / errors["model_size_m"])


def test_hybrids_lie_between_linear_and_nonlinear(errors):
    m = errors["methods"]
    assert m["linear"]["max_error_mm"] > 5.0  # a walk and a run really differ
    assert m["hybrid_1"]["references"] == 1 and m["hybrid_3"]["references"] == 3
    assert m["hybrid_1"]["max_error_mm"] <= m["linear"]["max_error_mm"]
    assert m["hybrid_3"]["max_error_mm"] <= m["hybrid_1"]["max_error_mm"]
    assert m["hybrid_1"]["mean_error_mm"] < m["linear"]["mean_error_mm"]


def test_space_hybrid_is_within_its_epsilon_on_the_grid(errors):
    hybrid = errors["methods"]["hybrid"]
    assert hybrid["epsilon_mm"] == 1000 * EPSILON
    assert hybrid["max_error_mm"] <= 1000 * EPSILON + 0.01


def test_hybrid_at_its_reference_is_exact_up_to_quantisation(space, cache):
    """At w = (0.5, 0.5) the 1-reference hybrid adds the stored D_NL: only int8 rounding remains,
    at most half a step (peak / 254) per component, the peak being at most the linear error."""
    w = np.array([0.5, 0.5])
    result = evaluation.blend_errors(space, [w], cache=cache, timing_calls=1, nonlinear_timing_calls=1)
    linear = result["methods"]["linear"]["max_error_mm"]
    assert result["methods"]["hybrid_1"]["max_error_mm"] <= np.sqrt(3) * linear / 254 + 1e-3


def test_errors_between_phase_samples(space, cache):
    result = evaluation.blend_errors(space, [[0.3, 0.7]], phases=[0.1, 0.55], cache=cache, timing_calls=1,
                                     nonlinear_timing_calls=1)
    assert result["phases"] == [0.1, 0.55]
    assert result["methods"]["nonlinear"]["max_error_mm"] == 0.0
    assert 0 < result["methods"]["hybrid_1"]["max_error_mm"] <= result["methods"]["linear"]["max_error_mm"]


def test_vertex_areas_add_up_to_the_surface_area(body):
    V, F = body.V, body.F
    total = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1).sum()
    assert evaluation.vertex_areas(V, F).sum() == pytest.approx(total)


def test_epsilon_sweep_trades_memory_for_error(space, cache):
    rows = evaluation.epsilon_sweep(space, (2, 5, 20, 1000), cache=cache)
    assert [r["epsilon_mm"] for r in rows] == [2, 5, 20, 1000]
    memory = [r["correction_bytes"] for r in rows]
    assert memory == sorted(memory, reverse=True)
    for r in rows:
        assert r["max_error_mm"] <= r["epsilon_mm"] + 0.01
        assert 0.0 <= r["corrected_area_percent"] <= 100.0
    assert rows[0]["references"] >= rows[2]["references"]
    assert rows[0]["corrected_area_percent"] > rows[2]["corrected_area_percent"] > 0
    # A threshold above every error: no references, nothing corrected, the linear blend.
    assert rows[-1]["references"] == 0 and rows[-1]["corrected_area_percent"] == 0.0
    linear = evaluation.blend_errors(space, cache=cache, timing_calls=1, nonlinear_timing_calls=1)
    assert rows[-1]["max_error_mm"] == pytest.approx(linear["methods"]["linear"]["max_error_mm"], rel=1e-4)


def test_corrected_vertices_follow_the_stored_entries(space):
    tree, corrections = space.tree, space.corrections
    for p in range(space.n_phases):
        mask = evaluation.corrected_vertices(tree, corrections, [1.0, 0.0], p, space.n_vertices)
        assert not mask.any()  # a source: no correction
    mid = tree.split_references()[0]  # the first split is at (0.5, 0.5)
    vertex, _, _ = corrections.entries(mid, 3)
    mask = evaluation.corrected_vertices(tree, corrections, [0.5, 0.5], 3, space.n_vertices)
    np.testing.assert_array_equal(np.flatnonzero(mask), np.unique(vertex))


def test_uniform_subdivision_adds_references(space, cache):
    rows = evaluation.uniform_subdivision(space, (1, 2), cache=cache)
    assert [r["references"] for r in rows] == [1, 3]
    assert rows[1]["max_error_mm"] <= rows[0]["max_error_mm"]


def test_figures_are_pictures(space, cache, errors):
    worst = errors["methods"]["hybrid_1"]
    image = evaluation.heatmap_figure(space, worst["worst_weights"], worst["worst_phase"], cache=cache,
                                      panel_width=160, panel_height=260)
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[1] > 5 * 160
    assert image.std() > 10
    rows = evaluation.epsilon_sweep(space, (3, 10), cache=cache)
    image = evaluation.sweep_figure(rows, uniform=evaluation.uniform_subdivision(space, (1,), cache=cache))
    assert image.dtype == np.uint8 and image.std() > 10


def test_ground_truth_nonlinear_is_closer_than_linear(space, body, cache):
    truth = evaluation.gait_truth(body, SPEEDS, fps=30.0)
    result = evaluation.ground_truth_comparison(space, body, truth, cache=cache)
    for source in result["sources"]:  # the truth at a source's own speed is that source
        assert source["max_mm"] < 1.0  # re-warped onto the grid: sub-sample interpolation only
        np.testing.assert_allclose(source["offset_m"], 0.0, atol=1e-4)
    rows = result["rows"]
    assert [r["params"]["speed"] for r in rows] == pytest.approx([1.35, 1.9, 2.45])
    for row in rows:
        assert row["nonlinear"]["mean_mm"] < row["linear"]["mean_mm"]
        assert row["ratio_mean"] == pytest.approx(row["linear"]["mean_mm"] / row["nonlinear"]["mean_mm"])
        # Linear blending shrinks the limbs that rotate differently in the two gaits.
        assert row["nonlinear"]["volume_error_percent"] < row["linear"]["volume_error_percent"]
        assert row["nonlinear"]["edge_error_percent"] < row["linear"]["edge_error_percent"]
    summary = result["summary"]
    assert summary["ratio_mean"] > 1.0 and summary["ratio_volume"] > 1.5


def test_ground_truth_rejects_a_foreign_body(space):
    other = build_body(1500)
    with pytest.raises(ValueError, match="vertices"):
        evaluation.ground_truth_comparison(space, other, evaluation.gait_truth(other, SPEEDS))


def test_the_bisection_blends_are_not_kept_by_the_cache(space):
    """A hybrid rebuilt for the sweep tests many weights; the cache keeps only those asked for (it
    kept them all: 22 GB on a 3-source space, found by a docs-only user)."""
    cache = evaluation.BlendCache(space)
    evaluation.epsilon_sweep(space, (2,), cache=cache)
    assert cache.blends_kept == len(evaluation.weight_grid(space.n_sources))
