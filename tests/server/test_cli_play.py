"""`morphspace play` on a motion space: the clip played, and requests outside the reachable domain
said, whether they come from --set or from a scripted --at."""

import json

from server.cli import main


def _play(capsys, *args):
    assert main(["play", *map(str, args), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_play_reports_the_clip_and_its_path(built_spaces, capsys):
    report = _play(capsys, built_spaces / "speed.mspace", "--set", "speed=1.5", "--seconds", 1, "--fps", 20)
    assert report["frames"] == 21 and abs(report["seconds"] - 1.0) < 1e-9 and report["notes"] == []
    assert abs(report["end"]["realised"][0] - 1.5) < 0.05 and report["path_length_m"] > 1.0


def test_a_clamped_request_is_said_from_set_and_from_at(built_spaces, capsys):
    report = _play(capsys, built_spaces / "speed.mspace", "--set", "speed=10", "--seconds", 0.5, "--fps", 20)
    assert len(report["notes"]) == 1 and report["notes"][0].startswith("t=0.00 s: ")
    assert "clamped: speed 10 m/s ->" in report["notes"][0]
    report = _play(capsys, built_spaces / "speed.mspace", "--set", "speed=1", "--at", 0.2, "speed=10",
                   "--seconds", 0.5, "--fps", 20)
    assert len(report["notes"]) == 1 and report["notes"][0].startswith("t=0.20 s: ")
    assert main(["play", str(built_spaces / "speed.mspace"), "--set", "speed=10", "--seconds", "0.2"]) == 0
    assert "  note: t=0.00 s: outside the reachable domain, clamped: speed 10 m/s" in capsys.readouterr().out


def test_a_request_after_the_play_ends_is_said_not_dropped(built_spaces, capsys):
    report = _play(capsys, built_spaces / "speed.mspace", "--set", "speed=1", "--at", 0.8, "speed=1.5",
                   "--seconds", 0.5, "--fps", 20)
    assert report["notes"] == ["t=0.80 s: speed=1.5 not applied: --seconds ended the play at 0.50 s"]
