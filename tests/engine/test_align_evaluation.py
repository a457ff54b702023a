"""Scoring against ground truth and the aligned-pattern pictures (paper fig. 2)."""

import numpy as np
import pytest

from engine.align import body_frame, pattern_colors, pattern_frames, pattern_sheet
from engine.rotations import rot_y
from engine.synthetic import build_body


def test_pattern_frames_take_frames_from_every_sequence():
    picks = pattern_frames([10, 40, 5, 3], 6)
    assert len(picks) == 6 and len(set(picks)) == 6
    starts = np.array([0, 10, 50, 55])
    sequences = {int(np.searchsorted(starts, k, side="right") - 1) for k in picks}
    assert sequences == {0, 1, 2, 3}
    assert pattern_frames([2], 6) == [0, 1]  # fewer frames than asked for


def test_pattern_colours_follow_the_rest_positions_and_tell_left_from_right():
    body = build_body(1000)
    colors = pattern_colors(body.V)
    assert colors.shape == (len(body.V), 3) and colors.min() >= 0 and colors.max() <= 1
    left, right = body.V[:, 0] < -0.05, body.V[:, 0] > 0.05
    left_colours = {tuple(c) for c in colors[left]}
    right_colours = {tuple(c) for c in colors[right]}
    assert len(left_colours) == 2 and len(right_colours) == 2 and not left_colours & right_colours
    # moving the frames does not move the pattern: it is fixed on the root (frame 0 here)
    frames = np.stack([body.V, body.V + [0.3, 0.0, 0.0], body.V @ rot_y(0.5).T])
    image = pattern_sheet(frames, body.F, 0, [3], ["still"], size=300)
    assert image.shape == (300, 300, 3) and image.std() > 10


def test_pattern_frames_spread_over_many_sequences():
    lengths = [10] * 14
    picks = pattern_frames(lengths, 6)
    sequences = sorted(k // 10 for k in picks)
    assert len(set(sequences)) == 6 and sequences[0] == 0 and sequences[-1] == 13


@pytest.mark.parametrize("degrees", [90, 180, -120])
def test_the_pattern_follows_the_body_turned_about_the_vertical(degrees):
    body = build_body(1000)
    turned = body.V @ rot_y(np.radians(degrees)).T
    colors = pattern_colors(body.V)
    np.testing.assert_array_equal(pattern_colors(turned), colors)  # every vertex keeps its colour
    _, left = body_frame(turned)
    red_green = (colors == [0.90, 0.30, 0.35]).all(axis=1) | (colors == [0.25, 0.65, 0.45]).all(axis=1)
    across = (turned - turned.mean(axis=0)) @ left
    assert np.all(across[red_green] > -0.02) and np.all(across[~red_green] < 0.02)  # the body's left is red/green
    # and the picture shows the turned root from its front, as the unturned one
    still = pattern_sheet(np.stack([body.V, body.V]), body.F, 0, [2], size=200, title="")
    again = pattern_sheet(np.stack([turned, turned]), body.F, 0, [2], size=200, title="")
    assert np.abs(still.astype(float) - again.astype(float)).mean() < 1.0


def test_part_errors_score_each_part_of_the_body_apart():
    """Two parts (a body of 4 vertices and a 'sleeve' of 4): only the sleeve is off by 3 cm in
    frame 1, so the sleeve's mean is 3 cm there and the body's is 0."""
    from engine.align import score_alignment
    from engine.align.evaluation import part_errors

    tetra = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    V = np.concatenate([tetra, tetra + [3.0, 0, 0]])
    faces = np.concatenate([F, F + 4])
    truth = np.stack([V, V + [0.0, 0.5, 0]])
    aligned = truth.copy()
    aligned[1, 4:] += [0.03, 0, 0]
    errors, summary = score_alignment(aligned, 0, V, truth, faces, 4.0)
    parts = part_errors(errors, 0, V, truth, faces, {"body": 4, "sleeve": 4}, 4.0)
    assert parts["body"]["vertices"] == parts["sleeve"]["vertices"] == 4
    assert parts["body"]["mean_mm"] == pytest.approx(0.0, abs=1e-9)
    assert parts["sleeve"]["mean_mm"] == pytest.approx(30.0) and parts["sleeve"]["mean_pct"] == pytest.approx(0.75)
    assert summary["mean_mm"] == pytest.approx(15.0)
