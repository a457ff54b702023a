"""The command line as a whole: a malformed command line gets the command's own usage, and a
reader that goes away (`| head`) ends a command quietly."""

import subprocess
import sys

import pytest

from server.cli import COMMANDS, main


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_an_unknown_option_prints_the_commands_usage(command, capsys):
    with pytest.raises(SystemExit) as exited:
        main([command, "--no-such-option"])
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"usage: morphspace {command} "), err[:200]
    # (a command with required arguments names those first)
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"morphspace {command}: error: ") and ("unrecognized arguments: --no-such-option" in last
                                                                 or "arguments are required" in last), last


def test_a_reader_that_goes_away_ends_the_command_quietly(built_spaces):
    """`morphspace play ... | head -1`: once the reader has gone, writing fails with EPIPE; the
    command ends with status 141 and says nothing about it (it said '[Errno 32] Broken pipe')."""
    process = subprocess.Popen([sys.executable, "-m", "server.cli", "play", str(built_spaces / "speed.mspace"),
                                "--seconds", "2", "--fps", "30"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()   # the reader goes away before anything is written
    _, err = process.communicate(timeout=120)
    assert process.returncode == 141, err
    assert err.decode().strip() == ""
