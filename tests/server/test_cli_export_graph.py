"""`morphspace export GRAPH.mgraph`: a recorded or scripted graph performance in every format
from a real subprocess; bad recordings are one-line errors naming the problem; nothing is
written outside --out."""

import json
import subprocess
import sys
import zipfile

import pytest


def cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "server.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=300)


SCRIPT = ["--at", "0.5", "jump", "jump_height=0.4", "--at", "2", "reach", "budget=1.5", "--seconds", "4", "--fps", "15"]


def test_a_recording_and_its_script_export_the_same_bytes_in_every_format(built_graph, tmp_path):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    graph = built_graph / "tiny.mgraph"
    run = cli("play", graph, *SCRIPT, "--record", tmp_path / "session.json", cwd=cwd)
    assert run.returncode == 0, run.stderr
    run = cli("export", graph, "--recording", tmp_path / "session.json", "--out", tmp_path / "a.glb", cwd=cwd)
    assert run.returncode == 0, run.stderr
    assert "tiny: 61 frames (4 s, hybrid, nodes walk -> jump -> stand -> reach" in run.stdout
    assert "frames identical to the recording's" in run.stdout
    assert "play: 100%" in run.stderr and "write: 100%" in run.stderr
    run = cli("export", graph, *SCRIPT, "--out", tmp_path / "b.glb", "--quiet", cwd=cwd)
    assert run.returncode == 0 and run.stderr == "", run.stderr
    assert (tmp_path / "a.glb").read_bytes() == (tmp_path / "b.glb").read_bytes()
    # the requests in another order, as play takes them (export refused: "requests must be in frame order")
    backwards = SCRIPT[4:8] + SCRIPT[:4] + SCRIPT[8:]
    assert cli("export", graph, *backwards, "--out", tmp_path / "c.glb", "--quiet", cwd=cwd).returncode == 0
    assert (tmp_path / "c.glb").read_bytes() == (tmp_path / "b.glb").read_bytes()
    run = cli("export", graph, *SCRIPT, "--out", tmp_path / "perf.usda", "--quiet", cwd=cwd)
    assert run.returncode == 0, run.stderr
    assert b"timeCodesPerSecond = 15" in (tmp_path / "perf.usda").read_bytes()
    for fmt in ("obj", "vat"):
        run = cli("export", graph, "--recording", tmp_path / "session.json", "--format", fmt, "--out",
                  tmp_path / f"{fmt}.zip", "--quiet", cwd=cwd)
        assert run.returncode == 0, run.stderr
    with zipfile.ZipFile(tmp_path / "obj.zip") as archive:
        record = json.loads(archive.read("clip.json"))
        assert len([n for n in archive.namelist() if n.endswith(".obj")]) == 61
    assert record["space"] == "tiny" and record["nodes"][0] == "walk" and "reach" in record["nodes"]
    assert record["realised"][0][record["parameters"].index("walk.speed")] is not None
    assert record["realised"][0][record["parameters"].index("jump.jump_height")] is None
    assert "vat.json" in zipfile.ZipFile(tmp_path / "vat.zip").namelist()
    assert list(cwd.iterdir()) == []


def _recording(built_graph, tmp_path):
    path = tmp_path / "session.json"
    run = cli("play", built_graph / "tiny.mgraph", "--at", "0.2", "jump", "--seconds", "1", "--record", path,
              cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    return json.loads(path.read_text())


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(graph_checksum="feedface"), "was made with graph 'tiny' (feedface), not this one"),
    (lambda d: d["requests"][0].update(node="fly"), "requests[0]: unknown node 'fly'"),
    (lambda d: d["requests"][0].update(params={"height": 1}), "node 'jump' has no parameter 'height'"),
    (lambda d: d.pop("steps"), "steps a non-negative integer"),
])
def test_bad_recordings_are_one_line_errors(built_graph, tmp_path, change, message):
    document = _recording(built_graph, tmp_path)
    change(document)
    (tmp_path / "bad.json").write_text(json.dumps(document))
    run = cli("export", built_graph / "tiny.mgraph", "--recording", tmp_path / "bad.json", "--out",
              tmp_path / "x.glb", cwd=tmp_path)
    assert run.returncode == 2 and message in run.stderr and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert not (tmp_path / "x.glb").exists()


@pytest.mark.parametrize("args, message", [
    (["--at", "1", "fly"], "no node 'fly' in graph 'tiny'"),
    (["--at", "1", "jump", "height=1"], "node 'jump' has no parameter 'height'; it has jump_height"),
    (["--set", "speed=1", "--start", "stand"], "node 'stand' has no parameter 'speed'; it has no parameters"),
    (["--smoothing", "0.5"], "--smoothing is for motion spaces"),
    (["--recording", "x.json", "--at", "1", "jump"], "--recording replays a recorded performance"),
    # a recording has its own clock and mode: both were ignored without a word (a docs-only trial)
    (["--recording", "x.json", "--fps", "30"], "--fps: --recording replays a recorded performance at its own frame "
                                               "rate and blend mode; leave --fps out"),
    (["--recording", "x.json", "--mode", "linear"], "--mode: --recording replays a recorded performance"),
    (["--recording", "x.json"], "--recording x.json: no such file"),
])
def test_bad_scripts_are_one_line_errors(built_graph, tmp_path, args, message):
    run = cli("export", built_graph / "tiny.mgraph", "--out", tmp_path / "x.glb", *args, cwd=tmp_path)
    assert run.returncode == 2 and message in run.stderr, run.stderr


def test_start_parameters_out_of_reach_are_noted(built_graph, tmp_path):
    """Clamped and said, as a request's are (a docs-only user found them clamped silently)."""
    run = cli("export", built_graph / "tiny.mgraph", "--set", "speed=99", "--seconds", "1", "--out",
              tmp_path / "a.zip", "--format", "obj", "--quiet", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "note: frame 0: " in run.stdout and "speed 99" in run.stdout, run.stdout
    with zipfile.ZipFile(tmp_path / "a.zip") as archive:
        notes = json.loads(archive.read("clip.json"))["notes"]
    assert len(notes) == 1 and notes[0].startswith("frame 0: ")
