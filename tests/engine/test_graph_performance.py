"""Comparing a played performance with the generator's true one: exact cases first."""

import numpy as np
import pytest

from engine.graph.performance import performance_distance, performance_requests, summarise_distance


def _walk(frames=40, n=50, fps=20.0, speed=1.0, seed=0):
    """A rigid point cloud moving along +Z at ``speed``, its root with it."""
    cloud = np.random.default_rng(seed).normal(size=(n, 3)) * 0.2
    root = np.zeros((frames, 3))
    root[:, 2] = speed * np.arange(frames) / fps
    return cloud[None] + root[:, None], root


def test_identical_frames_are_zero_distance():
    V, root = _walk()
    d = performance_distance(V, V, fps=20.0, root=root, true_root=root)
    for key in ("aligned_m", "slack_m", "pose_aligned_m", "pose_slack_m"):
        np.testing.assert_allclose(d[key], 0.0, atol=1e-6)
    assert d["end_offset_m"] == 0.0


def test_a_path_offset_is_in_the_world_distance_not_the_pose():
    V, root = _walk()
    shifted, shifted_root = V + [0.3, 0.0, 0.4], root + [0.3, 0.0, 0.4]
    d = performance_distance(shifted, V, fps=20.0, root=shifted_root, true_root=root)
    np.testing.assert_allclose(d["aligned_m"], 0.5, atol=1e-5)
    np.testing.assert_allclose(d["pose_aligned_m"], 0.0, atol=1e-5)
    assert d["end_offset_m"] == pytest.approx(0.5)


def test_slack_forgives_a_late_start_within_the_window():
    V, root = _walk(frames=60)
    late = np.concatenate([V[:1].repeat(3, axis=0), V[:-3]])  # the same walk 3 frames (0.15 s) late
    d = performance_distance(late, V, fps=20.0, window=0.5)
    assert d["aligned_m"][10:].min() > 0.1  # 0.15 m behind at the same time
    np.testing.assert_allclose(d["slack_m"][3:], 0.0, atol=1e-6)  # but a true frame 3 earlier is it
    tight = performance_distance(late, V, fps=20.0, window=0.1)  # 2 frames of slack are not enough
    assert tight["slack_m"][10:].min() > 0.04
    summary = summarise_distance(d, model_size=1.75)
    assert summary["frames"] == 60 and summary["slack"]["p50_mm"] == pytest.approx(0.0, abs=1e-3)
    assert "pose_slack" not in summary  # no roots given


def test_requests_follow_the_true_events():
    events = {"stop_frame": 30, "jump_frame": 111, "start_frame": 239}
    requests = performance_requests(events, 30.0, speed=1.2, jump_params={"jump_height": 0.4},
                                    walk_params={"turn_rate": 0.0})
    assert [(r.time, r.node, r.params) for r in requests] == [
        (1.0, "stand", {}), (3.7, "jump", {"jump_height": 0.4}), (239 / 30, "walk", {"speed": 1.2, "turn_rate": 0.0})]
