"""Where an alignment's error lies (engine.align.breakdown)."""

import numpy as np
import pytest

from engine.align.breakdown import error_breakdown, flag_calibration, part_labels, tree_depth


def test_flag_calibration_counts_exactly():
    frame_mean = np.array([0.5, 2.5, 3.5, 1.0, 4.0])
    flagged = np.array([False, True, True, True, False])
    c = flag_calibration(frame_mean, flagged, thresholds=(2.0, 3.0))
    assert c["over_2pct"] == {"bad": 3, "flagged": 3, "flagged_bad": 2, "precision": 0.667, "recall": 0.667}
    assert c["over_3pct"] == {"bad": 2, "flagged": 3, "flagged_bad": 1, "precision": 0.333, "recall": 0.5}
    none = flag_calibration(np.zeros(3), np.zeros(3, dtype=bool))
    assert none["over_2pct"]["precision"] is None and none["over_2pct"]["recall"] is None


def test_a_part_that_holds_the_whole_tail():
    # 3 frames (root 0) of 10 vertices: 8 on the body at 1 cm, 2 on a sleeve at 10 cm
    errors = np.full((3, 10), 0.01)
    errors[:, 8:] = 0.10
    errors[0] = 0.0
    labels = np.array([0] * 8 + [1] * 2)
    b = error_breakdown(errors, 0, 1.0, labels=labels, names=["body", "sleeve"], depth=np.array([0, 1, 2]),
                        confidence=np.array([1.0, 0.9, 0.2]))
    assert b["mean_pct"] == pytest.approx(100 * (0.8 * 0.01 + 0.2 * 0.10), abs=1e-3)
    sleeve, body = b["per_part"]["sleeve"], b["per_part"]["body"]
    assert sleeve["share_of_vertices"] == 0.2 and sleeve["mean_pct"] == pytest.approx(10.0)
    assert body["share_of_tail"] == 0.0  # everything over the 95th percentile is on the sleeve
    assert sleeve["p95_without_pct"] == pytest.approx(1.0)  # without the sleeve only the body's 1 cm is left
    assert [row["depths"] for row in b["per_depth"]] == ["1", "2-4"]
    assert [f["frame"] for f in b["worst_frames"]] == [1, 2] or [f["frame"] for f in b["worst_frames"]] == [2, 1]
    assert b["confidence"]["over_2pct"]["flagged"] == 1  # frame 2 (the root is left out)


def test_tree_depth_follows_parents():
    assert tree_depth(np.array([-1, 0, 1, 1, 3]), 0).tolist() == [0, 1, 2, 2, 3]
    assert tree_depth(np.array([1, -1, 1]), 1).tolist() == [1, 0, 1]


def test_part_labels_from_the_template():
    # two triangles far apart, part "a" (vertices 0-2) and part "b" (3-5)
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 0, 0], [6, 0, 0], [5, 1, 0]], dtype=float)
    F = np.array([[0, 1, 2], [3, 4, 5]])
    P = np.array([[0.2, 0.2, 0.01], [5.2, 0.2, -0.01]])
    assert part_labels(P, V, F, {"a": 3, "b": 3}).tolist() == [0, 1]
