"""`morphspace play` on a motion space: the clip played, and requests outside the reachable domain
said, whether they come from --set or from a scripted --at; bad input (numbers, paths, recordings,
of a space or a graph) refused in one line before anything is played."""

import json

import numpy as np
import pytest
from cli_refused import refused

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


# Bad input: one line naming the option or file, exit status 2, nothing played or written.


@pytest.fixture(scope="module")
def renamed_space(tmp_path_factory):
    """A space without parameters built as o.mspace (its name inside stays "o"), then renamed cube.mspace."""
    from engine.motion_space import SourceClip, build_motion_space

    root = tmp_path_factory.mktemp("renamed")
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]) * 0.8
    F = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [2, 3, 7], [2, 7, 6], [1, 2, 6],
                  [1, 6, 5], [0, 4, 7], [0, 7, 3]])
    clips = [SourceClip(name, np.stack([V * s + [0.0, 0.0, 0.03 * i] for i in range(3)]), 15.0, False)
             for name, s in (("a", 1.0), ("b", 1.05))]
    build_motion_space(root / "o.mspace", clips, F, name="o")
    (root / "o.mspace").rename(root / "cube.mspace")
    return root / "cube.mspace"


@pytest.mark.parametrize("argv,message", [
    (["--seconds", "inf"], "--seconds must be a finite positive number of seconds, got inf"),
    (["--seconds", "nan"], "--seconds must be a finite positive number of seconds, got nan"),
    (["--seconds", "1e9"], "--seconds 1e+09 at --fps 60 is 60000000001 frames; at most 100000 per play"),
    (["--fps", "1e9"], "10 s (the default --seconds) at --fps 1e+09 is 10000000001 frames; at most 100000 per play"),
    (["--fps", "nan"], "--fps must be a finite positive number of frames per second, got nan"),
    (["--fps", "1e308", "--seconds", "1e308"], "is more than 100000 frames; at most 100000 per play"),
    (["--at", "nan", "speed=1.2"], "--at nan: the time must be a finite number of seconds >= 0"),
    (["--at", "-1", "speed=1.2"], "--at -1: the time must be a finite number of seconds >= 0"),
    (["--trail-every", "0"], "--trail-every must be a positive number of seconds, got 0"),
    (["--trail-every", "-1"], "--trail-every must be a positive number of seconds, got -1"),
    (["--smoothing", "nan"], "--smoothing must be a non-negative number of seconds, got nan"),
    (["--set", "speed=nan"], "speed: 'nan' is not a finite number"),
    # a repeated --set took the last value, a bare --at did nothing, both without a word (a docs-only user)
    (["--set", "speed=2", "--set", "speed=3"], "speed is given twice (speed=2, speed=3); give each parameter once"),
    (["--at", "1"], "--at 1: give NAME=VALUE after the time"),
])
def test_bad_numbers_of_a_space_play_are_refused(built_spaces, capsys, argv, message):
    refused(capsys, ["play", built_spaces / "speed.mspace", *argv], message)


def test_bad_output_paths_of_a_space_play_are_refused_up_front(built_spaces, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.obj").write_text("v 0 0 0\n")
    (tmp_path / "dir").mkdir()
    space = built_spaces / "speed.mspace"
    for argv, message in [(["--frames", "a.obj"], "--frames a.obj: exists and is not a directory"),
                          (["--frames", "a.obj/f"], "--frames a.obj/f: a.obj is not a directory"),
                          (["--trail", "dir"], "--trail dir: is a directory; give a file name"),
                          (["--trail", "t.nope"], "--trail t.nope: not a picture file name")]:
        refused(capsys, ["play", space, "--seconds", 0.2, *argv], message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.obj", "dir"] and not any((tmp_path / "dir").iterdir())


def test_a_renamed_space_is_named_by_its_file(renamed_space, capsys):
    err = refused(capsys, ["play", renamed_space, "--seconds", 0.2],
                   f"{renamed_space}: the space has no parameter map")
    assert "error: o:" not in err


@pytest.fixture()
def graph_recording(built_graph, tmp_path, capsys):
    """A short recording of the tiny graph (and the graph's path)."""
    graph = built_graph / "tiny.mgraph"
    assert main(["play", str(graph), "--seconds", "0.2", "--fps", "15", "--record", str(tmp_path / "r.json")]) == 0
    capsys.readouterr()
    return graph, tmp_path / "r.json"


def test_bad_input_of_a_graph_play_is_refused(graph_recording, tmp_path, capsys, monkeypatch):
    graph, recording = graph_recording
    monkeypatch.chdir(tmp_path)
    (tmp_path / "binary.json").write_bytes(bytes(range(128, 256)))
    (tmp_path / "a.obj").write_text("v 0 0 0\n")
    (tmp_path / "dir").mkdir()
    huge = json.loads(recording.read_text())
    huge["steps"] = 10 ** 12
    (tmp_path / "huge.json").write_text(json.dumps(huge))
    unordered = json.loads(recording.read_text())
    unordered["requests"] = [{"frame": 2, "node": "stand", "params": {}, "budget": None},
                             {"frame": 1, "node": "walk", "params": {}, "budget": None}]
    (tmp_path / "unordered.json").write_text(json.dumps(unordered))
    before = sorted(p.name for p in tmp_path.iterdir())
    refused(capsys, ["play", graph, "--replay", "missing.json"], "--replay missing.json: no such file")
    refused(capsys, ["play", graph, "--replay", "dir"], "--replay dir: is a directory, not a recording")
    refused(capsys, ["play", graph, "--replay", "binary.json"], "--replay binary.json: not a text file")
    refused(capsys, ["play", graph, "--replay", "huge.json"],
             "--replay huge.json: recording: 1000000000001 frames; at most 100000 per play")
    refused(capsys, ["play", graph, "--seconds", 0.2, "--record", "dir"], "--record dir: is a directory")
    refused(capsys, ["play", graph, "--seconds", 0.2, "--frames", "a.obj"], "--frames a.obj: exists and is not a")
    refused(capsys, ["play", graph, "--seconds", 0.2, "--trail", "t.png"], "--trail is for motion spaces")
    refused(capsys, ["play", graph, "--at", "nan", "jump"], "--at nan: the time must be a finite number")
    refused(capsys, ["play", graph, "--at", "1e300", "jump"], "at most 100000 per play")
    refused(capsys, ["play", graph, "--fps", "inf"], "--fps must be a finite positive number")
    # found by a docs-only user: each was ignored or reordered without a word
    refused(capsys, ["play", graph, "--replay", "unordered.json"],
            "--replay unordered.json: recording: requests must be in frame order; request 1 (frame 1) comes after")
    refused(capsys, ["play", graph, "--smoothing", "0.1"], "--smoothing is for motion spaces (.mspace)")
    refused(capsys, ["play", graph, "--loop"], "--loop is for motion spaces (.mspace)")
    refused(capsys, ["play", graph, "--at", "1", "jump", "jump_height=0.3", "jump_height=0.4"],
            "jump_height is given twice")
    assert sorted(p.name for p in tmp_path.iterdir()) == before and not any((tmp_path / "dir").iterdir())


def test_a_graph_request_after_the_play_ends_is_said_not_dropped(built_graph, capsys):
    report = _play(capsys, built_graph / "tiny.mgraph", "--at", 5, "jump", "--seconds", 1, "--fps", 15)
    assert report["notes"] == ["t=5.00 s: jump not applied: --seconds ended the play at 1.00 s"]
    assert main(["play", str(built_graph / "tiny.mgraph"), "--at", "5", "jump", "--seconds", "1", "--fps", "15"]) == 0
    assert "  note: t=5.00 s: jump not applied: --seconds ended the play at 1.00 s" in capsys.readouterr().out


def test_a_play_says_what_was_asked_and_a_graph_its_clamped_start(built_spaces, built_graph, capsys):
    """The report's 'asked' is the request as given (not the smoothed, clamped value the player
    moves towards); a graph's start parameters out of reach are noted as a space's are."""
    report = _play(capsys, built_spaces / "speed.mspace", "--set", "speed=10", "--seconds", 0.5, "--fps", 20)
    assert report["end"]["asked"] == [10.0] and report["end"]["requested"][0] < 10.0
    assert main(["play", str(built_spaces / "speed.mspace"), "--set", "speed=10", "--seconds", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "(asked 10)" in out
    timeline = [line for line in out.splitlines() if line.startswith("  t ")]
    assert len(timeline) == len(set(timeline))   # the last row once
    assert main(["play", str(built_spaces / "speed.mspace"), "--at", "0.4", "speed=1", "--seconds", "0.5"]) == 0
    timeline = [line for line in capsys.readouterr().out.splitlines() if line.startswith("  t ")]
    assert "(default " in timeline[0] and "(asked" not in timeline[0]   # nothing asked yet: not "asked"
    assert "(asked 1)" in timeline[-1]
    report = _play(capsys, built_graph / "tiny.mgraph", "--set", "speed=10", "--seconds", 0.5, "--fps", 15)
    assert len(report["notes"]) == 1 and report["notes"][0].startswith("t=0.00 s: start ")
    assert "clamped: speed 10" in report["notes"][0]


def test_frames_of_an_earlier_play_are_not_mixed_with_a_new_one(built_spaces, built_graph, tmp_path, capsys):
    """A second play into the same --frames directory is refused; with --force the earlier
    frames go (a shorter play left the first one's last frames behind: one sequence to the eye)."""
    frames = tmp_path / "frames"
    (tmp_path / "frames").mkdir()
    (frames / "notes.txt").write_text("mine")
    for target in (built_spaces / "speed.mspace", built_graph / "tiny.mgraph"):
        assert main(["play", str(target), "--seconds", "1", "--fps", "10", "--frames", str(frames), "--force"]) == 0
        assert len(list(frames.glob("frame_*.obj"))) == 11
        capsys.readouterr()
        refused(capsys, ["play", target, "--seconds", "0.5", "--fps", "10", "--frames", frames],
                f"--frames {frames}: holds the frames of an earlier play; pass --force")
        assert len(list(frames.glob("frame_*.obj"))) == 11
        capsys.readouterr()
        assert main(["play", str(target), "--seconds", "0.5", "--fps", "10", "--frames", str(frames), "--force"]) == 0
        assert sorted(p.name for p in frames.glob("frame_*.obj")) == [f"frame_{k:05d}.obj" for k in range(6)]
        assert (frames / "notes.txt").read_text() == "mine"   # only frames are replaced


def test_a_request_that_replaces_an_earlier_one_says_so(built_graph, capsys):
    """Two requests at once: the second replaces the first before it was carried out, and the play
    says so, as the stream's `superseded` notice does (the first's plan was printed, then nothing)."""
    assert main(["play", str(built_graph / "tiny.mgraph"), "--at", "0.5", "stand", "--at", "0.5", "jump",
                 "--seconds", "1", "--fps", "15"]) == 0
    out = capsys.readouterr().out
    assert "request stand" in out and "request jump" in out
    assert "    note: replaces the request planned before it (dropped before it was carried out)" in out
