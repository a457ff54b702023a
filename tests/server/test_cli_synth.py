"""`morphspace synth` end to end: files on disk, read back by mesh_io and independent readers."""

import json

import numpy as np
import pytest
import trimesh
from cli_refused import refused

from engine.mesh_io import read_frames, read_sequence
from engine.mesh_io.dataset import load_capture_truth, read_capture_manifest
from engine.surface import SurfaceQuery
from server.cli import main


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("captures") / "tiny"
    status = main(["synth", "--preset", "tiny", "--out", str(out), "--only", "walk", "jump", "--workers", "2"])
    assert status == 0
    return out


def test_dataset_layout_and_manifest(tiny):
    manifest = read_capture_manifest(tiny)
    assert [s["name"] for s in manifest["sequences"]] == ["walk", "jump"]
    assert manifest["body"]["model_size"] == pytest.approx(1.75, abs=0.02)
    assert manifest["body"]["height"] == 1.75  # the height the body was built at (no --height given)
    for name in ("walk", "jump"):
        base = tiny / "sequences" / name
        meta = json.loads((base / "meta.json").read_text())
        assert len(list((base / "consistent").glob("frame_*.obj"))) == meta["frames"]
        assert len(list((base / "unstructured").glob("frame_*.ply"))) == meta["frames"]
        assert (tiny / "previews" / f"{name}.png").stat().st_size > 10_000
    assert not list(tiny.parent.glob(".tiny.partial-*"))  # staging directory renamed away


def test_consistent_frames_read_back_match_the_ground_truth(tiny):
    seq = read_sequence(tiny / "sequences" / "walk" / "consistent")
    truth = load_capture_truth(tiny, "walk")
    assert seq.vertices.shape == truth["template_positions"].shape
    np.testing.assert_allclose(seq.vertices, truth["template_positions"], atol=2e-6)
    # An independent OBJ reader sees the same mesh.
    other = trimesh.load(tiny / "sequences" / "walk" / "consistent" / "frame_0003.obj", process=False)
    np.testing.assert_allclose(other.vertices, seq.vertices[3], atol=2e-6)
    np.testing.assert_array_equal(other.faces, seq.faces)


def test_unstructured_frames_read_back_and_lie_on_the_true_surface(tiny):
    frames = read_frames(tiny / "sequences" / "jump" / "unstructured")
    truth = load_capture_truth(tiny, "jump")
    template = read_sequence(tiny / "sequences" / "jump" / "consistent")
    manifest = read_capture_manifest(tiny)
    noise = manifest["noise_mm"] / 1000.0
    assert len(frames) == len(truth["template_positions"])
    assert len({len(f.vertices) for f in frames}) > 1  # every frame has its own mesh
    for k in (0, len(frames) // 2):
        other = trimesh.load(tiny / "sequences" / "jump" / "unstructured" / f"frame_{k:04d}.ply", process=False)
        np.testing.assert_allclose(other.vertices, frames[k].vertices, atol=1e-6)
        assert other.is_watertight
        distance = SurfaceQuery(truth["template_positions"][k], template.faces).closest(frames[k].vertices)[3]
        assert distance.max() < 5 * noise + 1e-5


def test_existing_output_is_not_overwritten_without_force(tiny, capsys):
    before = sorted(p.name for p in tiny.iterdir())
    assert main(["synth", "--preset", "tiny", "--out", str(tiny), "--only", "walk"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert sorted(p.name for p in tiny.iterdir()) == before


def test_unknown_sequence_is_a_clear_error(tmp_path, capsys):
    assert main(["synth", "--preset", "tiny", "--out", str(tmp_path / "x"), "--only", "moonwalk"]) == 2
    assert "unknown sequence(s) moonwalk" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


QUICK = ["--preset", "tiny", "--only", "walk", "--no-previews", "--no-unstructured", "--workers", "1"]


def _refused(capsys, argv, *expected):
    return refused(capsys, ["synth", *argv], *expected)


@pytest.mark.parametrize("argv,message", [
    (["--fps", "inf"], "--fps must be between 1 and 240 frames per second, got inf"),
    (["--fps", "nan"], "--fps must be between 1 and 240 frames per second, got nan"),
    (["--fps", "0"], "--fps must be between 1 and 240 frames per second, got 0"),
    (["--noise-mm", "nan"], "--noise-mm must be between 0 and 100, got nan"),
    (["--noise-mm", "-1"], "--noise-mm must be between 0 and 100, got -1"),
    (["--workers", "0"], "--workers must be between 1 and"),
    (["--workers", "-2"], "--workers must be between 1 and"),
    (["--seed", "-1"], "--seed must be a non-negative integer, got -1"),
    (["--vertices", "10"], "--vertices must be between 1000 and 50000, got 10"),
    (["--height", "0"], "--height must be between 1.0 and 2.5 m, got 0"),
    (["--height", "nan"], "--height must be between 1.0 and 2.5 m, got nan"),
])
def test_bad_options_are_refused_before_anything_is_written(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    _refused(capsys, [*QUICK, "--out", "x", *argv], message)
    assert list(tmp_path.iterdir()) == []  # no x, no .x.partial-<pid>


def test_an_out_that_is_a_file_or_holds_the_current_directory_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.obj").write_text("v 0 0 0\n")
    _refused(capsys, [*QUICK, "--out", "a.obj", "--force"], "--out a.obj: exists and is not a directory")
    _refused(capsys, [*QUICK, "--out", "a.obj/x"], "--out a.obj/x: a.obj is not a directory")
    _refused(capsys, [*QUICK, "--out", ".", "--force"], "--out .: is the current directory or holds it")
    assert [p.name for p in tmp_path.iterdir()] == ["a.obj"] and (tmp_path / "a.obj").read_text() == "v 0 0 0\n"


def test_a_failure_while_writing_leaves_no_staging_directory(tmp_path, capsys, monkeypatch):
    from server.commands import synth

    def fail(vertices, height):
        raise OSError("disk full")

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(synth, "_body", fail)
    _refused(capsys, [*QUICK, "--out", "new/deeper/x"], "disk full")
    assert list(tmp_path.iterdir()) == []  # neither .x.partial-<pid> nor the parents made for it


def test_the_summary_counts_in_the_singular_and_reads_no_negative_zero(tmp_path, capsys):
    """("wrote 1 studio sequences", "turn_rate -0.000"; a docs-only user.)"""
    from server.commands.synth import _fixed

    assert main(["synth", "--preset", "tiny", "--out", str(tmp_path / "one"), "--only", "walk", "--no-unstructured",
                 "--no-previews", "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("wrote 1 sequence, ") and "-0.000" not in printed, printed
    assert (_fixed(-1e-9), _fixed(-0.0004), _fixed(-0.0006), _fixed(2.25)) == ("0.000", "0.000", "-0.001", "2.250")


def test_an_interrupt_at_any_line_of_the_staging_leaves_nothing(tmp_path):
    """Ctrl-C or SIGTERM between any two lines of ``staged`` (synth's and align's ``--out``): the staging directory and the parents
    made for it are gone, or the output is complete (the staging directory was made before the
    clean-up's ``try``: a signal taken just after its mkdir left it)."""
    import contextlib

    from interrupting import interrupt_at_every_line

    from server.commands import staging as module

    out = tmp_path / "new" / "x"

    def write():
        with module.staged(out) as staging:
            (staging / "frame.obj").write_text("v 0 0 0\n")

    def check(at):
        made = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
        assert made in ([], ["new", "new/x", "new/x/frame.obj"]), (at, made)
        assert at is not None or made
        if made:
            for path in (out / "frame.obj", out, out.parent):
                path.unlink() if path.is_file() else path.rmdir()

    assert interrupt_at_every_line(write, [module.__file__, contextlib.__file__], check) > 10
