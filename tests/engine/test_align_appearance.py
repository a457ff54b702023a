"""The colours' disagreement an aligned frame shows (engine.align.appearance) and how the
confidence reads it (engine.align.repair.alignment_badness)."""

import numpy as np
import pytest

from engine.align import TargetSurface
from engine.align.appearance import colour_disagreement, colour_distance, colour_floor
from engine.align.repair import COLOUR_FREE, COLOUR_SCALE, TAIL_SCALE, TAIL_WITH_COLOUR, alignment_confidence


def _checked_tube(along=60, around=48, radius=0.1, length=1.2):
    """A closed-ring tube (open ends) with red and cream checks, 12 around and 10 along."""
    s = np.linspace(0.0, length, along)
    a = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    S, A = np.meshgrid(s, a, indexing="ij")
    V = np.stack([radius * np.cos(A), S, radius * np.sin(A)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(along - 1), np.arange(around), indexing="ij")
    a0, a1 = i * around + j, i * around + (j + 1) % around
    b0, b1 = a0 + around, a1 + around
    F = np.concatenate([np.stack([a0, b0, a1], -1).reshape(-1, 3), np.stack([a1, b0, b1], -1).reshape(-1, 3)])
    check = ((np.floor(A / (2 * np.pi) * 12) + np.floor(S / length * 10)) % 2).reshape(-1, 1)
    colours = check * np.array([0.75, 0.15, 0.18]) + (1 - check) * np.array([0.95, 0.9, 0.8])
    return V, F, colours


def _turned(V, degrees):
    t = np.radians(degrees)
    c, s = np.cos(t), np.sin(t)
    return V @ np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]).T


def test_the_floor_is_the_root_on_itself_and_a_slid_alignment_shows_more():
    V, F, C = _checked_tube()
    target = TargetSurface(V, F, C)
    floor = colour_floor(V, F, C)
    assert floor == pytest.approx(colour_disagreement(V, C, target))
    assert 0.0 < floor < 0.2  # within a face the checks' edges mix
    # the same surface, every vertex turned half a check about the axis: on the surface, wrong colours
    slid = colour_disagreement(_turned(V, 15.0), C, target)
    assert slid > 3.0 * floor
    a_little = colour_disagreement(_turned(V, 3.0), C, target)
    assert floor < a_little < slid
    assert np.isnan(colour_distance(V, None, target))  # NaN without colours
    assert np.isnan(colour_disagreement(V, C, TargetSurface(V, F, None)))
    assert np.isnan(colour_floor(V, F, None))


def test_the_confidence_reads_the_colours_against_the_floor():
    floor = 0.1
    ratios = np.array([1.0, COLOUR_FREE, COLOUR_FREE + COLOUR_SCALE, COLOUR_FREE + np.log(2) * COLOUR_SCALE])
    c = alignment_confidence(np.zeros(4), np.zeros(4), 1.7, colour=ratios * floor, colour_floor=floor)
    assert c[0] == 1.0 and c[1] == 1.0  # up to COLOUR_FREE times the floor costs nothing
    assert c[2] == pytest.approx(np.exp(-1.0))
    assert c[3] == pytest.approx(0.5)


def test_with_colours_only_a_large_tear_counts():
    tails = np.array([TAIL_SCALE, TAIL_WITH_COLOUR * TAIL_SCALE, (TAIL_WITH_COLOUR + 1) * TAIL_SCALE])
    without = alignment_confidence(np.zeros(3), tails, 1.7)
    assert without == pytest.approx(np.exp(-np.array([1.0, TAIL_WITH_COLOUR, TAIL_WITH_COLOUR + 1])))
    floor = 0.1
    agreeing = np.full(3, floor)
    with_colours = alignment_confidence(np.zeros(3), tails, 1.7, colour=agreeing, colour_floor=floor)
    assert with_colours == pytest.approx([1.0, 1.0, np.exp(-1.0)])
    # a frame without colours in a capture with them (NaN) keeps the tail as it is
    mixed = alignment_confidence(np.zeros(3), tails, 1.7, colour=np.array([np.nan, floor, floor]), colour_floor=floor)
    assert mixed[0] == pytest.approx(np.exp(-1.0))
    # no usable floor: the colours are ignored
    assert alignment_confidence(np.zeros(3), tails, 1.7, colour=agreeing, colour_floor=float("nan")) == \
        pytest.approx(without)


def test_colours_too_coarse_for_the_cues_add_to_the_tail_and_excuse_nothing():
    from engine.align.repair import colour_terms

    class Aligned:
        root = 0
        colour = np.array([0.1, 0.1, 0.2, 0.2])

    tails = np.array([0.0, 3.0, 0.0, 3.0]) * TAIL_SCALE
    colour, floor, tail_free = colour_terms(Aligned, cues=False)
    assert tail_free == 0.0 and floor == 0.1
    without = alignment_confidence(np.zeros(4), tails, 1.7)
    coarse = alignment_confidence(np.zeros(4), tails, 1.7, colour=colour, colour_floor=floor, tail_free=tail_free)
    assert np.all(coarse <= without)  # never more trusting than the fit and the tail alone
    assert coarse[1] == pytest.approx(without[1]) and coarse[2] < 0.5 and coarse[3] < coarse[1]
    # with the cues on the same colours excuse a tail up to TAIL_WITH_COLOUR
    assert colour_terms(Aligned, cues=True)[2] == TAIL_WITH_COLOUR
    Aligned.colour = np.array([np.nan, 0.1, 0.2, 0.2])  # no colours: nothing to read
    assert colour_terms(Aligned, cues=False) == (None, None, 0.0)


def test_a_step_that_loses_the_roots_colours_is_aligned_again_and_the_better_colours_win():
    from engine.align.options import PairAlignment, better_alignment
    from engine.align.pieces import COLOUR_RETRY, COLOUR_STEP, _colour_slipped

    def result(colour, quality=1.0):
        return PairAlignment(V=None, X=None, residual=0.05 * quality, residual_max=0.0, colour_mean=colour)

    floor = 0.1
    high = (COLOUR_RETRY + 0.1) * floor
    assert _colour_slipped(result(high), None, floor)  # a parent outside the piece: the level alone
    assert _colour_slipped(result(high), high - (COLOUR_STEP + 0.1) * floor, floor)  # this step lost it
    assert not _colour_slipped(result(high), high - 0.1 * floor, floor)  # inherited from the parent
    assert not _colour_slipped(result(COLOUR_RETRY * floor), 0.0, floor)
    assert not _colour_slipped(result(high), None, float("nan"))  # no colour cues
    assert better_alignment(result(0.2, quality=5.0), result(0.3, quality=1.0), floor)  # colours decide ...
    assert not better_alignment(result(0.3, quality=1.0), result(0.2, quality=5.0), floor)
    assert not better_alignment(result(0.29, quality=5.0), result(0.3, quality=1.0), floor)  # ... when clearly apart
    assert better_alignment(result(0.31, quality=1.0), result(0.3, quality=5.0), floor)
    assert not better_alignment(result(0.2, quality=5.0), result(0.3, quality=1.0), float("nan"))  # else the quality


def test_regions_take_out_light_and_exposure_but_not_a_slide():
    from engine.align.appearance import region_gains

    V, F, C = _checked_tube()
    regions = (V[:, 1] > 0.6).astype(np.int64) * 2 + (V[:, 0] > 0).astype(np.int64)   # four quarters
    # the same cloth photographed in another frame: one side brighter, the other darker, and the
    # whole frame exposed 5% lower
    light = np.where(V[:, 0] > 0, 1.2, 0.85) * 0.95
    lit = np.clip(C * light[:, None], 0.0, 1.0)
    target = TargetSurface(V, F, lit)
    floor = colour_floor(V, F, C, regions)
    assert floor == pytest.approx(colour_floor(V, F, C), rel=0.05)   # the root on itself: gains near 1
    raw = colour_disagreement(V, C, target)
    evened = colour_disagreement(V, C, target, regions)
    assert raw > 1.5 * floor              # read raw, the light looks like a wrong alignment
    assert evened < 1.3 * floor           # the regions' gains take it out
    slid = colour_disagreement(_turned(V, 15.0), C, target, regions)
    assert slid > 3.0 * floor             # a check off is still seen
    gains = region_gains(lit, C, regions)
    assert gains.shape == (4,) and np.all((gains > 0.7) & (gains < 1.2))
    # a region without colour (black) keeps a gain of 1; gains stay within their range
    np.testing.assert_array_equal(region_gains(np.ones((2, 3)), np.zeros((2, 3)), np.array([0, 1])), [1.0, 1.0])
    assert region_gains(np.ones((1, 3)), np.full((1, 3), 0.01), np.array([0]))[0] == 2.0
