"""Matches that reach past the closest point for the source's colour (engine.align.colour_reach)."""

import numpy as np

from engine.align.colour_reach import (AGREE, GAP, SPREAD, reach_colours, reach_for_colour, smoothed_colours, smoothing_passes,
                                      target_colour_tree)
from engine.align.matching import TargetSurface, correspondences
from engine.align.options import AlignmentOptions
from engine.nearest import PointTree

GREY, RED = np.array([0.5, 0.5, 0.5]), np.array([0.9, 0.2, 0.2])


def _sheet(patch_from, n=61, width=0.6):
    """A flat square sheet (y = 0), grey, with a red band from x = ``patch_from`` 6 cm wide."""
    s = np.linspace(-width / 2, width / 2, n)
    X, Z = np.meshgrid(s, s, indexing="ij")
    V = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    F = np.concatenate([np.stack([a, a + n, a + 1], 1), np.stack([a + 1, a + n, a + n + 1], 1)])
    C = np.where(((V[:, 0] >= patch_from) & (V[:, 0] < patch_from + 0.06))[:, None], RED, GREY)
    return V, F, C


def _reach(target, points, colours, scale=0.3):
    """reach_for_colour for ``points`` among 200 grey points on grey (as a body's matches are
    mostly right: they set the frame's exposure gain, here 1); the answers for ``points``."""
    s = np.linspace(-0.28, -0.12, 20)
    background = np.stack(np.meshgrid(s, [0.0], np.linspace(-0.25, 0.25, 10), indexing="ij"), -1).reshape(-1, 3)
    x = np.concatenate([points, background])
    c = np.concatenate([colours, np.tile(GREY, (len(background), 1))])
    y, m, _, _, _ = correspondences(x, np.tile([0.0, 1.0, 0.0], (len(x), 1)), target, AlignmentOptions())
    w, tangential = np.zeros(len(x)), np.zeros(len(x))
    y2, m2, replaced = reach_for_colour(x, y, m, w, tangential, target, c, scale)
    assert not replaced[len(points):].any()
    p = slice(0, len(points))
    return y[p], y2[p], replaced[p], w[p], tangential[p]


def test_smoothed_colours_are_the_mean_of_each_vertex_neighbourhood():
    V, F, C = _sheet(0.0)
    smooth = smoothed_colours(V, C, k=9)
    index = PointTree(V).query(V, k=9)[1]
    assert np.array_equal(smooth, C[index].mean(axis=1))   # to the last bit: alignments follow it
    assert np.allclose(smooth[V[:, 0] < -0.1], GREY)   # far from the band: its own colour
    # two passes: the mean of the neighbours' means
    assert np.allclose(smoothed_colours(V, C, k=9, passes=2), smooth[index].mean(axis=1))


def test_a_denser_surface_is_smoothed_over_the_same_span_so_its_checks_still_read_as_a_pattern():
    """The same sheet with 3 cm checks at 8,100, 32,400 and 73,441 vertices: one pass over 24
    neighbours spans less of the denser sheets, so their checks' centres read as plain cloth
    (and would reach for their colour a check away); the passes smoothing_passes asks for
    (1, 4, 9: vertices per model size squared of surface over DENSITY) spread as far as
    one pass does on the coarse sheet."""
    share, median = {}, {}
    for n in (90, 180, 271):
        V, F, C = _sheet(0.08, n=n)
        checks = (V[:, 0] < -0.1) & ((np.floor(V[:, 0] / 0.03) + np.floor(V[:, 2] / 0.03)) % 2 == 0)
        C = np.where(checks[:, None], [1.0, 1.0, 1.0], C)
        inside = (V[:, 0] < -0.14) & (V[:, 0] > -0.27) & (np.abs(V[:, 2]) < 0.25)
        passes = smoothing_passes(V, F, 0.6)
        for q in {1, passes}:
            spread = smoothed_colours(V, C, spread=True, passes=q)[1][inside]
            share[n, q == passes], median[n, q == passes] = (spread > SPREAD).mean(), np.median(spread)
        assert passes == {90: 1, 180: 4, 271: 9}[n]
    assert share[90, True] > 0.98 and share[180, True] > 0.98 and share[271, True] > 0.98
    assert share[180, False] < 0.8 and share[271, False] < 0.6
    assert abs(median[271, True] - median[90, True]) < 0.02 and median[271, False] < median[90, True] - 0.08


def test_a_red_point_on_grey_reaches_the_red_band_nearby_and_grey_points_stay():
    V, F, C = _sheet(0.08)
    target = TargetSurface(V, F, C)
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1], [-0.05, 0.0, 0.0]])
    colours = np.array([RED, RED, GREY])
    y, y2, replaced, w, tangential = _reach(target, points, colours)
    # the closest points are straight below, on grey; the red ones reach 8-14 cm across to red
    assert np.allclose(y[:, 0], points[:, 0], atol=1e-9)
    assert replaced.tolist() == [True, True, False]
    assert np.all((y2[:2, 0] >= 0.08) & (y2[:2, 0] < 0.14))
    assert np.allclose(y2[2], y[2])
    assert np.all(w[:2] >= 0.5) and np.all(tangential[:2] == 1.0) and w[2] == 0.0 and tangential[2] == 0.0
    # a point whose colour is already there does not look further
    on_red = np.array([[0.1, 0.0, 0.0]])
    assert not _reach(target, on_red, np.array([RED]))[2].any()


def test_a_colour_too_far_away_or_nowhere_is_not_reached_for():
    far = TargetSurface(*_sheet(0.22))     # the band 22 cm off: farther than the colour's weight allows
    points = np.array([[0.0, 0.0, 0.0]])
    assert not _reach(far, points, np.array([RED]))[2].any()
    assert _reach(far, points, np.array([RED]), scale=2.0)[2].all()   # weighed heavier, it is reached
    near = TargetSurface(*_sheet(0.08))
    blue = np.array([[0.1, 0.2, 0.9]])     # a colour the target does not show: no match agrees with it
    assert np.linalg.norm(blue[0] - RED) > AGREE and np.linalg.norm(blue[0] - GREY) > GAP
    assert not _reach(near, points, blue)[2].any()


def test_the_target_is_prepared_once_per_scale_and_the_answer_is_deterministic():
    V, F, C = _sheet(0.08)
    target = TargetSurface(V, F, C)
    smooth, tree = target_colour_tree(target, 0.3)
    assert target_colour_tree(target, 0.3)[1] is tree and target_colour_tree(target, 0.5)[1] is not tree
    assert tree.points.shape == (len(target.V), 6) and np.allclose(tree.points[:, 3:], 0.3 * smooth)
    points = np.random.default_rng(0).uniform(-0.2, 0.2, (50, 3)) * [1, 0, 1]
    colours = np.where((points[:, 2] > 0)[:, None], RED, GREY)
    first = _reach(target, points, colours)[1]
    again = _reach(TargetSurface(V, F, C), points, colours)[1]
    assert np.array_equal(first, again)


def test_a_patterned_surface_does_not_reach_its_smoothed_colour_repeats_every_stripe():
    """On checks or stripes the smoothed colour of one place is found again a stripe away, so a
    root vertex whose neighbours' colours spread widely (the skirt's checks) does not reach;
    plain cloth and skin do."""
    V, F, C = _sheet(0.08)
    checks = (V[:, 0] < -0.1) & ((np.floor(V[:, 0] / 0.02) + np.floor(V[:, 2] / 0.02)) % 2 == 0)
    C = np.where(checks[:, None], [1.0, 1.0, 1.0], C)   # white and grey checks 2 cm wide on the left
    mean, spread = smoothed_colours(V, C, spread=True)
    colours = reach_colours(V, C)
    inside = (V[:, 0] < -0.14) & (np.abs(V[:, 2]) < 0.25)
    plain = (V[:, 0] > -0.06) & (V[:, 0] < 0.06) & (np.abs(V[:, 2]) < 0.25)
    assert np.all(spread[inside] > SPREAD) and np.isnan(colours[inside]).all()
    assert np.all(spread[plain] < 0.01) and np.allclose(colours[plain], mean[plain])
    # a red point whose colour is unknown (NaN: patterned) stays on its closest point
    target = TargetSurface(V, F, _sheet(0.08)[2])
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]])
    _, _, replaced, _, _ = _reach(target, points, np.array([[np.nan] * 3, RED]))
    assert replaced.tolist() == [False, True]


def test_a_plain_tube_turned_about_its_axis_is_turned_back_by_its_colours():
    """A tube 1.6 m long with a red and a blue stripe, turned 60 degrees about its own axis: its
    surface is the same, so closest points leave it where it was (every vertex about 10 cm off
    along the surface, beyond the local colour cue's few neighbours); the stripes reaching for
    their colours turn it back. Measured with the patches stepping on their own (coupled steps,
    the default, carry the local cues' turn from patch to patch and turn it back even without
    the reach); the defaults turn it back too, the same result twice."""
    from dataclasses import replace

    from engine.align import PairwiseAligner

    from test_align_colour_cues import _tube

    V, F = _tube(False, along=100, around=48)
    angle = np.arctan2(V[:, 2], V[:, 1])
    C = np.where((np.abs(angle) < 0.5)[:, None], RED, GREY)
    C = np.where((np.abs(angle - 2.2) < 0.5)[:, None], [0.2, 0.3, 0.9], C)
    t = np.radians(60.0)
    W = V @ np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]]).T
    error, results = {}, {}
    for reach in (0.0, 0.18):
        options = replace(AlignmentOptions(patches=16, levels=3, patch_coupling=0.0), colour_weight=1.0,
                          colour_reach=reach)
        aligner = PairwiseAligner(V, F, C, options=options)
        results[reach] = aligner.align(aligner.V_tet, TargetSurface(W, F, C)).V
        error[reach] = np.linalg.norm(results[reach] - W, axis=1).mean()
    assert error[0.0] > 0.03 and error[0.18] < 0.2 * error[0.0]
    aligner = PairwiseAligner(V, F, C, options=replace(AlignmentOptions(patches=16, levels=3), colour_weight=1.0))
    default = aligner.align(aligner.V_tet, TargetSurface(W, F, C)).V
    assert np.linalg.norm(default - W, axis=1).mean() < 0.2 * error[0.0]
    assert np.array_equal(aligner.align(aligner.V_tet, TargetSurface(W, F, C)).V, default)
