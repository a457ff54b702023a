"""Scoring against ground truth and the aligned-pattern pictures (paper fig. 2)."""

import numpy as np

from engine.align import pattern_colors, pattern_frames, pattern_sheet
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
