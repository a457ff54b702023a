"""`morphspace export`: a real subprocess writes each format from a built space; bad input is a
one-line error with exit status 2; nothing is written outside --out."""

import json
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from engine.mesh_io import read_sequence


def export(*args, cwd):
    return subprocess.run([sys.executable, "-m", "server.cli", "export", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def test_export_writes_glb_usd_and_sequences(built_spaces, tmp_path):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    space = built_spaces / "speed.mspace"
    track = tmp_path / "track.json"
    track.write_text(json.dumps({"params": {"speed": 1.0}, "track": [{"time": 1.0, "params": {"speed": 2.4}}]}))
    run = export(space, "--out", tmp_path / "clip.glb", "--track", track, "--seconds", 2, "--fps", 30, cwd=cwd)
    assert run.returncode == 0, run.stderr
    assert "61 frames (2 s at 30 frames/s, hybrid)" in run.stdout and "61 morph targets" in run.stdout
    assert "play: 100%" in run.stderr and "write: 100%" in run.stderr  # the progress bars
    assert (tmp_path / "clip.glb").read_bytes()[:4] == b"glTF"
    run = export(space, "--out", tmp_path / "clip.usda", "--set", "speed=1.5", "--seconds", 1, "--quiet", cwd=cwd)
    assert run.returncode == 0 and run.stderr == "" and b"timeCodesPerSecond = 60" in (tmp_path / "clip.usda").read_bytes()
    run = export(space, "--out", tmp_path / "frames", "--format", "ply", "--set", "speed=1.5", "--at", "0.5",
                 "speed=2", "--seconds", 1, "--fps", 10, cwd=cwd)
    assert run.returncode == 0, run.stderr
    assert read_sequence(tmp_path / "frames").vertices.shape[0] == 11
    run = export(space, "--out", tmp_path / "vat.zip", "--format", "vat", "--seconds", 1, "--fps", 10, cwd=cwd)
    assert run.returncode == 0, run.stderr
    assert sorted(zipfile.ZipFile(tmp_path / "vat.zip").namelist()) == ["mesh.glb", "positions.png", "vat.json"]
    assert list(cwd.iterdir()) == []


@pytest.mark.parametrize("args, message", [
    (["--out", "x.glb", "--set", "speed=7"], "params: speed = 7 m/s is out of range; speed spans"),
    (["--out", "x.glb", "--set", "pace=1"], "unknown parameter 'pace'; this space has speed"),
    (["--out", "x.glb", "--at", "12", "speed=1"], "track: time 12.0 is outside the clip [0, 10] s"),
    (["--out", "x.zip"], "cannot tell the format from the name; give --format"),
    (["--out", "x.glb", "--format", "usd"], "a usd export must be a file ending in .usd, .usdc or .usda"),
    (["--out", "x.glb", "--seconds", "-1"], "--seconds must be a finite positive number of seconds, got -1"),
    (["--out", "x.glb", "--seconds", "0"], "--seconds must be a finite positive number of seconds, got 0"),
    (["--out", "x.glb", "--fps", "nan"], "--fps must be a finite positive number of frames per second, got nan"),
    # (it made a directory frame_0000.obj holding the frames; found by a docs-only user)
    (["--out", "seq/frame_0000.obj", "--format", "obj"],
     "an obj export is a directory or a .zip file, not a .obj file; give the directory"),
    (["--out", "v.png", "--format", "vat"], "a vat export is a directory or a .zip file"),
    # options another format would ignore, and unreadable tracks: said, with the option (a docs-only trial)
    (["--out", "x.usd", "--precision", "float32"], "--precision is for glb exports; a usd export has no such choice"),
    (["--out", "seq", "--format", "vat", "--interpolation", "STEP"], "--interpolation is for glb exports; a vat"),
    (["--out", "x.glb", "--track", "nope.json"], "--track nope.json: no such file"),
    (["--out", "x.glb", "--seconds", "inf"], "--seconds must be a finite positive number of seconds, got inf"),
    (["--out", "x.glb", "--fps", "1000", "--seconds", "0.1"], "--fps 1000: at most 240 frames per second (as the "
                                                              "REST export's 'rate' takes it)"),
    (["--out", "x.glb", "--seconds", "4000", "--fps", "1"], "--seconds 4000: at most 3600 seconds"),
])
def test_bad_input_is_a_one_line_error(built_spaces, tmp_path, args, message):
    run = export(built_spaces / "speed.mspace", *args, cwd=tmp_path)
    assert run.returncode == 2 and message in run.stderr, run.stderr
    assert run.stderr.count("\n") == 1 and run.stderr.startswith("morphspace export: error:")
    assert list(tmp_path.iterdir()) == []


def test_an_output_that_cannot_be_written_is_refused_before_playing(built_spaces, tmp_path):
    """A file export naming a directory failed only after the whole clip was played and written, with
    the temporary file's name; a path under a file gave a raw [Errno 17]; a binary --track a codec error."""
    space = built_spaces / "speed.mspace"
    (tmp_path / "dir.glb").mkdir()
    (tmp_path / "plain").write_text("a file")
    (tmp_path / "track.json").write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    for args, message in (
            (["--out", tmp_path / "dir.glb", "--force"], f"--out {tmp_path / 'dir.glb'} is a directory; a glb export is "
                                                         "a file"),
            (["--out", tmp_path / "plain" / "sub.glb"], f"--out {tmp_path / 'plain' / 'sub.glb'}: {tmp_path / 'plain'} "
                                                        "is a file, not a directory"),
            (["--out", tmp_path / "plain" / "seq", "--format", "obj"], f"{tmp_path / 'plain'} is a file, not a directory"),
            (["--out", tmp_path / "x.glb", "--track", tmp_path / "track.json"],
             f"--track {tmp_path / 'track.json'}: not a JSON text file (it is not UTF-8 text)")):
        run = export(space, *args, "--seconds", 1, cwd=tmp_path)
        assert run.returncode == 2 and message in run.stderr, run.stderr
        assert run.stderr.count("\n") == 1 and "play:" not in run.stderr   # refused before anything was played
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.glb", "plain", "track.json"]
    assert list((tmp_path / "dir.glb").iterdir()) == []


def test_an_existing_output_needs_force(built_spaces, tmp_path):
    (tmp_path / "clip.glb").write_bytes(b"old")
    run = export(built_spaces / "speed.mspace", "--out", tmp_path / "clip.glb", "--seconds", 1, cwd=tmp_path)
    assert run.returncode == 2 and "exists; pass --force" in run.stderr
    run = export(built_spaces / "speed.mspace", "--out", tmp_path / "clip.glb", "--seconds", 1, "--force",
                 cwd=tmp_path)
    assert run.returncode == 0 and (tmp_path / "clip.glb").read_bytes()[:4] == b"glTF"
    assert np.frombuffer((tmp_path / "clip.glb").read_bytes()[8:12], "<u4")[0] == (tmp_path / "clip.glb").stat().st_size


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc refuses new files on Linux only")
@pytest.mark.parametrize("name", ["clip.usd", "clip.usda", "clip.glb"])
def test_an_unwritable_output_is_a_one_line_error_naming_it(built_spaces, tmp_path, name):
    """A docs-only user found USD's own error as a 19-line traceback (exit 1), and the other
    formats naming the hidden temporary file instead of --out (/proc takes no new file, even from root)."""
    run = export(built_spaces / "speed.mspace", "--out", f"/proc/{name}", "--seconds", 1, "--quiet", cwd=tmp_path)
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert run.stderr.startswith(f"morphspace export: error: cannot write /proc/{name}: "), run.stderr
    assert ".tmp" not in run.stderr and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("out", ["frames.zip", "frames"])
def test_sigterm_leaves_nothing_half_written(built_spaces, tmp_path, out):
    """SIGTERM while writing: exit 143 and nothing in the output's directory (a docs-only user found
    a 7.5 MB temporary zip and a scratch directory, and on Ctrl-C a directory of 472 frames without
    clip.json that then blocked a rerun)."""
    import signal
    import time

    where = tmp_path / "out"
    where.mkdir()
    command = [sys.executable, "-m", "server.cli", "export", built_spaces / "speed.mspace", "--out", where / out,
               "--format", "obj", "--seconds", 120, "--quiet"]
    process = subprocess.Popen(list(map(str, command)), cwd=tmp_path, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not any(where.iterdir()) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)  # until it has started writing
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 143 and stderr == "morphspace export: terminated\n", (process.returncode, stderr)
    assert list(where.iterdir()) == []


def test_force_replaces_an_earlier_sequence_export(built_spaces, tmp_path):
    """(a docs-only user found --force refused: the longer earlier export's frames were 'other mesh
    files'); files an export does not write stay, and other mesh files are still refused."""
    space, out = built_spaces / "speed.mspace", tmp_path / "frames"
    assert export(space, "--out", out, "--format", "ply", "--seconds", 1, "--fps", 20, "--quiet", cwd=tmp_path).returncode == 0
    (out / "notes.txt").write_text("mine")
    run = export(space, "--out", out, "--format", "obj", "--seconds", 0.5, "--fps", 20, "--force", "--quiet", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert sorted(p.name for p in out.iterdir()) == ["clip.json"] + [f"frame_{k:04d}.obj" for k in range(11)] + ["notes.txt"]
    (out / "other.ply").write_text("ply\n")
    before = sorted(p.name for p in out.iterdir())
    run = export(space, "--out", out, "--format", "obj", "--seconds", 0.5, "--force", "--quiet", cwd=tmp_path)
    assert run.returncode == 2 and "holds 1 mesh file no export wrote (e.g. other.ply); nothing was removed" in run.stderr, \
        run.stderr
    # the refused --force keeps the earlier export (it removed it first; a docs-only user)
    assert sorted(p.name for p in out.iterdir()) == before
    # and so does a --force refused for its clip, checked before anything is removed
    run = export(space, "--out", out, "--format", "obj", "--seconds", 0, "--force", "--quiet", cwd=tmp_path)
    assert run.returncode == 2 and sorted(p.name for p in out.iterdir()) == before, run.stderr
