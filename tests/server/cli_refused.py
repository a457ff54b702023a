"""``refused``: a command line that must be refused as the CLI promises (docs/cli.md): exit status 2,
one line on stderr naming the problem, nothing on stdout, no traceback."""

from __future__ import annotations

from server.cli import main


def refused(capsys, argv, *expected):
    """Run ``morphspace *argv`` (each item as a string) and check it is refused with one line that
    contains every ``expected`` text; returns that line (stderr)."""
    assert main([str(a) for a in argv]) == 2
    captured = capsys.readouterr()
    err = captured.err
    assert captured.out == "" and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for text in expected:
        assert text in err, err
    return err
