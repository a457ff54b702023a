"""`morphspace synth --preset studio-tiny`: the studio dataset on disk, in the units it declares."""

import contextlib
import io
import json
import re

import numpy as np
import pytest

from engine.mesh_io import read_frames, read_mesh, read_sequence
from engine.mesh_io.dataset import load_capture_truth, read_capture_manifest
from engine.surface import SurfaceQuery
from engine.synthetic.studio.reconstruct import frame_statistics
from server.cli import main


@pytest.fixture(scope="module")
def studio_run(tmp_path_factory):
    """The studio-tiny dataset written by `morphspace synth`, and what it wrote to stderr."""
    out = tmp_path_factory.mktemp("captures") / "studio-tiny"
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["synth", "--preset", "studio-tiny", "--out", str(out), "--workers", "2"]) == 0
    return out, err.getvalue()


@pytest.fixture(scope="module")
def studio(studio_run):
    return studio_run[0]


def test_the_animate_bar_counts_sequences_and_its_length_never_changes(studio_run):
    """The bar counted frames and grew as each sequence's count came in (11, 22, 33 ...)."""
    shown = re.findall(r"animate:\s+\d+%\|[^|]*\|\s*(\d+)/(\d+)", studio_run[1])
    assert shown, studio_run[1][-2000:]
    assert {total for _, total in shown} == {"3"} and shown[-1] == ("3", "3"), shown


def test_the_reconstruct_bar_names_the_frames_and_the_previews_bar_counts_previews(studio_run):
    """The reconstruct bar's note named each chunk by its first frame ("walk 0" all along on a
    short take); the previews bar counted "frames" (a docs-only trial found both)."""
    err = studio_run[1].replace("\r", "\n")
    notes = set(re.findall(r"reconstruct:[^\n]*\b(\w+ frames \d+-\d+)\]", err))
    assert notes and all(int(n.split()[-1].split("-")[0]) <= int(n.split("-")[-1]) for n in notes), err[-2000:]
    previews = re.findall(r"previews:[^\n]*\s(\d+)/(\d+) \[[^\n]*(?:s/preview|preview/s)", err)
    assert previews and previews[-1] == ("3", "3"), err[-2000:]


def test_layout_manifest_and_declared_units(studio):
    manifest = read_capture_manifest(studio)
    assert manifest["preset"] == "studio-tiny" and manifest["consistent_format"] == "ply"
    assert manifest["body"]["units"] == "m" and manifest["body"]["up"] == "+Y"
    assert manifest["body"]["model_size"] == pytest.approx(1.666, abs=0.01)  # its height
    assert set(manifest["body"]["parts"]) == {"body", "skirt", "sleeve_l", "sleeve_r"}
    # each sequence's truth is in that sequence's units and axes (strikes: mm, +Z): no global claim
    assert not {"truth_units", "truth_up"} & set(manifest["studio"])
    template = read_mesh(studio / "template" / "body.obj")
    assert len(template.vertices) == manifest["body"]["vertices"]
    declared = {s["name"]: (s["units"], s["up"]) for s in manifest["sequences"]}
    assert declared == {"walk": ("m", "+Y"), "strikes": ("mm", "+Z"), "contacts": ("m", "+Y")}
    for name in declared:
        base = studio / "sequences" / name
        meta = json.loads((base / "meta.json").read_text())
        assert len(list((base / "consistent").glob("frame_*.ply"))) == meta["frames"]
        assert len(list((base / "unstructured").glob("frame_*.ply"))) == meta["frames"]
        assert len(meta["unstructured_vertex_counts"]) == meta["frames"]
        assert meta["studio"]["frames_with_holes"] == meta["frames"]
        assert (studio / "previews" / f"{name}.png").stat().st_size > 50_000
    assert not (studio / ".work").exists() and not list(studio.parent.glob(".studio-tiny.partial-*"))


@pytest.mark.parametrize("name, scale, up", [("walk", 1.0, 1), ("strikes", 1000.0, 2)])
def test_files_and_truth_share_the_declared_frame(studio, name, scale, up):
    base = studio / "sequences" / name
    truth = load_capture_truth(studio, name)
    consistent = read_sequence(base / "consistent")
    np.testing.assert_allclose(consistent.vertices, truth["template_positions"], atol=1e-6 * scale)
    positions = truth["template_positions"]
    assert positions[..., up].max() == pytest.approx(1.67 * scale, rel=0.06)  # the head is up that axis
    frames = read_frames(base / "unstructured")
    for k in (0, len(frames) - 1):
        V, F = frames[k].vertices, frames[k].faces
        distance = SurfaceQuery(positions[k], consistent.faces).closest(V)[3]
        assert 0.001 * scale < np.median(distance) < 0.004 * scale  # 2.5 mm noise, in the file's units
        stats = frame_statistics(F, len(V))
        assert stats["boundary_edges"] > 0 and stats["components"] >= 1


def test_height_is_refused_for_the_studio(tmp_path, capsys):
    assert main(["synth", "--preset", "studio-tiny", "--out", str(tmp_path / "x"), "--height", "1.8"]) == 2
    assert "--height applies to the procedural presets" in capsys.readouterr().err


def test_textured_frames_carry_the_same_colours_in_an_atlas(studio, tmp_path):
    out = tmp_path / "textured"
    assert main(["synth", "--preset", "studio-tiny", "--only", "walk", "--out", str(out), "--workers", "1",
                 "--textured", "--unstructured-format", "obj", "--no-previews"]) == 0
    assert read_capture_manifest(out)["unstructured_textured"] is True
    folder = out / "sequences" / "walk" / "unstructured"
    assert {p.suffix for p in folder.iterdir()} == {".obj", ".mtl", ".png"}
    textured = read_frames(folder)
    plain = read_frames(studio / "sequences" / "walk" / "unstructured")
    assert len(textured) == len(plain)
    for k in (0, len(plain) - 1):   # the same reconstruction (walk is first: the same seed), its colours through the texture
        np.testing.assert_allclose(textured[k].vertices, plain[k].vertices, atol=1e-6)   # metres, 6 decimals
        assert np.array_equal(textured[k].faces, plain[k].faces)
        difference = np.abs(textured[k].colors - plain[k].colors).max(axis=1)
        assert np.median(difference) < 0.05 and difference.mean() < 0.06
