"""OBJ and PLY sequence exports: read back with the project's readers, the player's world frames."""

import json
import zipfile

import numpy as np
import pytest

from engine.export import Clip, play_clip, write_export
from engine.export.sequence import write_mesh_sequence
from engine.mesh_io import read_sequence


@pytest.fixture(scope="module")
def walk(export_spaces):
    return play_clip(export_spaces["speed"], Clip(params={"speed": 1.5}, duration=1.0, rate=12))


def world(frames):
    return np.stack([frames.world(k) for k in range(len(frames))]).astype(np.float64)


@pytest.mark.parametrize("fmt, tolerance", [("obj", 5e-7 + 1e-9), ("ply", 0.0)])
def test_sequences_read_back_as_the_players_frames(walk, tmp_path, fmt, tolerance):
    stats = write_export(tmp_path / "seq", walk, fmt)
    assert stats["frames"] == 13 and stats["bytes"] > 0
    sequence = read_sequence(tmp_path / "seq")
    assert sequence.vertices.shape == (13, walk.local.shape[1], 3)
    assert np.array_equal(sequence.faces, walk.faces)
    assert np.abs(sequence.vertices - world(walk)).max() <= tolerance  # OBJ: 6 decimals; PLY: float32
    record = json.loads((tmp_path / "seq" / "clip.json").read_text())
    assert record["frames"] == 13 and record["rate"] == 12 and record["coordinates"] == "world"
    assert np.allclose(record["root_position"], walk.root_position) and record["times"][-1] == pytest.approx(1.0)


def test_a_zip_holds_the_same_files(walk, tmp_path):
    write_export(tmp_path / "seq.zip", walk, "ply")
    write_export(tmp_path / "seq", walk, "ply")
    with zipfile.ZipFile(tmp_path / "seq.zip") as archive:
        names = sorted(archive.namelist())
        assert names == sorted(p.name for p in (tmp_path / "seq").iterdir())
        assert archive.read("frame_0003.ply") == (tmp_path / "seq" / "frame_0003.ply").read_bytes()
    assert np.array_equal(read_sequence(tmp_path / "seq.zip").vertices, read_sequence(tmp_path / "seq").vertices)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq", "seq.zip"]  # no scratch left behind


@pytest.mark.parametrize("format", ["obj", "vat"])
def test_the_same_clip_gives_the_same_zip(walk, tmp_path, format):
    """Byte for byte, whenever it is written: every member is stamped 1980-01-01 (a docs-only user
    found two exports of one recording differing in the members' times of writing)."""
    write_export(tmp_path / "a.zip", walk, format)
    with zipfile.ZipFile(tmp_path / "a.zip") as archive:
        assert {info.date_time for info in archive.infolist()} == {(1980, 1, 1, 0, 0, 0)}
    write_export(tmp_path / "b.zip", walk, format)
    assert (tmp_path / "a.zip").read_bytes() == (tmp_path / "b.zip").read_bytes()


def test_a_directory_with_other_meshes_is_refused(walk, tmp_path):
    (tmp_path / "other.obj").write_text("v 0 0 0\n")
    with pytest.raises(ValueError, match="already holds 1 other mesh files"):
        write_mesh_sequence(tmp_path, walk, "obj")
    with pytest.raises(ValueError, match="sequence format must be one of obj, ply"):
        write_mesh_sequence(tmp_path / "x", walk, "off")


@pytest.mark.parametrize("fmt", ["obj", "vat"])
def test_an_interrupt_at_any_line_of_a_directory_export_leaves_nothing(export_spaces, tmp_path, fmt):
    """Ctrl-C or SIGTERM between any two lines of the writers: the directory the export made is gone,
    or whole when the signal came after the last file (5 SIGTERMs of 60 while frames were written left
    it, holding a frame's hidden temporary; an interrupted VAT export left its first files)."""
    import contextlib

    from interrupting import interrupt_at_every_line

    from engine.export import sequence, vat
    from engine.mesh_io import atomic

    frames = play_clip(export_spaces["speed"], Clip(params={"speed": 1.5}, duration=1 / 12, rate=12))
    out = tmp_path / "out"
    whole = (["clip.json", "frame_0000.obj", "frame_0001.obj"] if fmt == "obj"
             else ["mesh.glb", "positions.png", "vat.json"])
    outcomes = set()

    def export():
        if out.is_dir():  # whole from the run before
            for path in out.iterdir():
                path.unlink()
            out.rmdir()
        write_export(out, frames, fmt)

    def check(at):
        names = sorted(p.name for p in out.iterdir()) if out.is_dir() else None
        assert list(tmp_path.iterdir()) == ([] if names is None else [out]), at
        assert names in (None, whole), (at, names)
        assert at is not None or names == whole
        outcomes.add(names is None)

    files = [module.__file__ for module in (sequence, vat, atomic, contextlib)]
    # (every line: where AtomicFile leaves its temporary, at the start of __exit__, discard_partial finds it)
    lines = interrupt_at_every_line(export, files, check)
    assert lines > 20 and len(frames) == 2 and outcomes == {True, False}
