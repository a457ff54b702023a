"""The CLI's stage bars (server.progress.StageBars) keep logs short."""

from server.progress import StageBars


def test_a_stage_bar_is_redrawn_at_most_every_half_second_and_ends_full(capsys):
    """build's hybrid bar was redrawn on every step: 72 redraws in 2 s in one docs-only trial's log."""
    bars = StageBars()
    for done in range(1, 2001):
        bars("hybrid", done, done + 5 if done < 2000 else 2000)   # a total that grows, as the bisection's
    bars.close()
    err = capsys.readouterr().err
    draws = [line for line in err.replace("\r", "\n").splitlines() if line.startswith("hybrid:")]
    assert 2 <= len(draws) <= 8, draws   # the first draw, the last, and few between
    assert "2000/2000" in draws[-1] and "100%" in draws[-1]


def test_a_bar_moved_back_shows_where_it_is(capsys):
    bars = StageBars()
    bars("decompose", 10, 10)
    bars("decompose", 4, 10)   # a stage restarted (a job run again) goes back, not forward
    assert bars.bar.n == 4
    bars.close()
