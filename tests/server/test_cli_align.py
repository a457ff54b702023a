"""`morphspace align` and `morphspace eval-align` on a few frames of a tiny capture dataset."""

import contextlib
import functools
import io
import json
import re
import shutil
import types
import zipfile

import numpy as np
import pytest

from engine.mesh_io import from_metres_y_up, read_frames, read_mesh, read_sequence, write_obj, write_ply
from engine.mesh_io.dataset import (
    load_capture_truth,
    read_capture_manifest,
    write_capture_manifest,
    write_capture_sequence,
    write_capture_template,
)
from engine.synthetic import SequenceSpec, build_body, generate_sequence_data
from server.cli import main
from server.commands.build import load_source


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Two gait sequences of 3 frames each, unstructured frames with colours and ground truth."""
    root = tmp_path_factory.mktemp("captures") / "tiny"
    body = build_body(1000)
    write_capture_template(root, body)
    metas = []
    for i, (name, speed) in enumerate((("walk", 1.0), ("jog", 2.5))):
        data = generate_sequence_data(body, SequenceSpec(name, "gait", {"speed": speed, "cycles": 0.2,
                                                                         "start_phase": 0.3}),
                                      fps=15, seed=i)
        write_capture_sequence(root, name, faces=body.F, vertices=data["vertices"], colors=body.colors,
                               unstructured=data["unstructured"], truth=data["truth"], meta=data["meta"])
        metas.append(data["meta"])
    write_capture_manifest(root, {"preset": "test", "fps": 15, "body": {"model_size": body.size},
                                  "sequences": metas})
    return root


@pytest.fixture(scope="module")
def aligned_run(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("aligned") / "out"
    err, summary = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(summary):
        assert main(["align", str(dataset), "--out", str(out), "--workers", "1", "--levels", "3"]) == 0
    return out, err.getvalue(), summary.getvalue()


@pytest.fixture(scope="module")
def aligned(aligned_run):
    return aligned_run[0]


@pytest.fixture(scope="module")
def dataset_mm_z_up(dataset, tmp_path_factory):
    """The same captures with the walk (files and truth) in millimetres, +Z up (exact coordinates),
    the jog as it was, in metres, +Y up, as a studio may deliver them; nothing says so (the
    manifest's body stays in metres, +Y up, and says so)."""
    root = tmp_path_factory.mktemp("captures") / "tiny_mm"
    shutil.copytree(dataset, root)
    for name in ("walk",):
        base = root / "sequences" / name
        for k, mesh in enumerate(read_frames(base / "unstructured")):
            write_ply(base / "unstructured" / f"frame_{k:04d}.ply", from_metres_y_up(mesh.vertices, "mm", "z"),
                      mesh.faces, colors=mesh.colors, dtype=np.float64)
        truth = load_capture_truth(dataset, name)
        truth["template_positions"] = from_metres_y_up(truth["template_positions"], "mm", "z")
        np.savez(base / "truth.npz", **truth)
    manifest = read_capture_manifest(dataset)
    manifest["body"].update(units="m", up="+Y")
    manifest.pop("format"), manifest.pop("version")
    write_capture_manifest(root, manifest)
    return root


@pytest.fixture(scope="module")
def aligned_mm_run(dataset_mm_z_up, tmp_path_factory):
    out = tmp_path_factory.mktemp("aligned") / "out_mm"
    err, stdout = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(stdout):
        assert main(["align", str(dataset_mm_z_up), "--out", str(out), "--workers", "1", "--levels", "3"]) == 0
    return out, err.getvalue(), stdout.getvalue()


def test_align_shows_progress_bars_up_to_every_frame(aligned_run):
    _, err, _ = aligned_run
    for stage in ("read frames", "shape histograms", "dissimilarity", "align", "write"):
        assert f"{stage}: 100%" in err, f"no finished {stage!r} bar in:\n{err[-2000:]}"
    assert "6/6" in err.split("align: 100%")[1].split("\n")[0]  # counted in frames


def test_morphspace_build_reads_the_aligned_output(aligned, tmp_path):
    # The tiny sequences are a fifth of a gait cycle, too short to find a cycle in: build them as
    # one-shot clips (copies of the aligned output with "cyclic": false in their meta.json).
    sources = []
    for name in ("walk", "jog"):
        copy = tmp_path / "aligned" / "sequences" / name
        shutil.copytree(aligned / "sequences" / name, copy)
        meta = json.loads((copy / "meta.json").read_text())
        meta["cyclic"] = False
        (copy / "meta.json").write_text(json.dumps(meta))
        sources += ["--source", str(copy)]
    shutil.copytree(aligned / "template", tmp_path / "aligned" / "template")
    space = tmp_path / "aligned.mspace"
    assert main(["build", *sources, "--out", str(space), "--phases", "3"]) == 0
    from engine.motion_space import MotionSpace

    template = read_mesh(aligned / "template" / "body.obj")
    with MotionSpace.open(space) as loaded:
        np.testing.assert_array_equal(loaded.faces, template.faces)
        assert list(loaded.source_names) == ["walk", "jog"]
        own = loaded.metadata["heading_turn_deg"]   # no manifest beside the template: the sources' travel
    # With the capture's manifest, heading 0 is the whole capture's travel (align's body.heading_turn_deg),
    # so every space built on its rest shares it, whatever its own sources do; here a value set by hand.
    manifest = json.loads((aligned / "manifest.json").read_text())
    assert abs(manifest["body"]["heading_turn_deg"]) < 30.0
    manifest["body"]["heading_turn_deg"] = own + 7.5
    (tmp_path / "aligned" / "manifest.json").write_text(json.dumps(manifest))
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["build", *sources, "--out", str(space), "--phases", "3", "--force"]) == 0
    assert f"heading 0: the aligned capture's travel, {own + 7.5:+.1f} degrees from the rest's facing" in err.getvalue()
    with MotionSpace.open(space) as loaded:
        assert loaded.metadata["heading_turn_deg"] == pytest.approx(own + 7.5, abs=1e-5)


def test_align_writes_a_dataset_that_build_and_read_sequence_accept(dataset, aligned):
    template = read_mesh(aligned / "template" / "body.obj")
    for name in ("walk", "jog"):
        sequence = read_sequence(aligned / "sequences" / name / "consistent")
        frames = len(list((dataset / "sequences" / name / "unstructured").iterdir()))
        assert sequence.vertices.shape == (frames, len(template.vertices), 3)
        np.testing.assert_array_equal(sequence.faces, template.faces)
        meta = json.loads((aligned / "sequences" / name / "meta.json").read_text())
        assert meta["name"] == name and meta["alignment"]["method"] == "tree"
        clip, faces = load_source(aligned / "sequences" / name, fps=30.0, cyclic=False)  # as `build` reads it
        assert clip.vertices.shape == sequence.vertices.shape
        assert meta["fps"] == 15  # the input's meta.json, not align's default for inputs without one
        # the written frames, whatever the input's meta.json said of its own
        assert (meta["frames"], meta["topology"], meta["vertices"], meta["faces"]) == \
            (frames, "consistent", len(template.vertices), len(template.faces))
        assert meta["duration"] == frames / 15 and "unstructured_vertex_counts" not in meta
    # the dataset's frame rate is the sequences' (the align job writes the same)
    assert json.loads((aligned / "manifest.json").read_text())["fps"] == 15
    with np.load(aligned / "alignment.npz", allow_pickle=False) as record:
        n = int(record["lengths"].sum())
        assert record["dissimilarity"].shape == (n, n)
        assert record["tree_edges"].shape == (n - 1, 2)
        assert record["residual"].shape == (n,) and record["residual"].max() < 0.01
        root = int(record["root"])
        # the colours' disagreement per frame (docs/alignment.md); the root's, on its own surface, is
        # the floor the others are read against
        colour = record["colour"]
        assert colour.shape == (n,) and np.all(colour > 0) and colour[root] <= np.median(colour)
    # the root frame is the template: its aligned copy is the root mesh itself
    names = [str(s) for s in np.load(aligned / "alignment.npz")["sequence_names"]]
    for picture in ("similarity.png", "tree.png", "aligned_pattern.png"):
        assert (aligned / picture).stat().st_size > 0
    assert 0 <= root < n and names == ["walk", "jog"]


def test_aligning_again_gives_the_same_bytes_but_for_the_timings(dataset, aligned, tmp_path):
    """The same frames aligned again (another output directory, another moment): every file the
    same, byte for byte, but ``timings.json``, which holds the stage and per-frame seconds."""
    again = tmp_path / "again"
    with contextlib.redirect_stderr(io.StringIO()):
        assert main(["align", str(dataset), "--out", str(again), "--workers", "1", "--levels", "3"]) == 0
    files = sorted(p.relative_to(aligned) for p in aligned.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    assert {str(f) for f in files} >= {"alignment.npz", "manifest.json", "timings.json", "template/body.obj"}
    differ = [str(f) for f in files if (aligned / f).read_bytes() != (again / f).read_bytes()]
    assert differ == ["timings.json"], differ
    timings = json.loads((aligned / "timings.json").read_text())
    assert len(timings["seconds"]) == len(timings["cpu_seconds"]) == 6 and timings["stages_s"]["align"] > 0
    with np.load(aligned / "alignment.npz") as record:
        assert "seconds" not in record.files and "cpu_seconds" not in record.files
    names = json.loads((aligned / "sequences" / "walk" / "meta.json").read_text())["alignment"]["source_files"]
    assert names == sorted(p.name for p in (dataset / "sequences" / "walk" / "unstructured").iterdir())


def test_a_frame_in_a_format_not_read_is_named_and_left_out(dataset, tmp_path):
    """A directory of frames with one ``.stl`` among them, the last frame of another name and no
    meta.json: the ``.stl`` is left out with a warning naming it, the mixed names and the order they
    are taken in are warned of, the assumed frame rate is noted, and meta.json lists the files read."""
    frames = tmp_path / "take"
    shutil.copytree(dataset / "sequences" / "walk" / "unstructured", frames)
    (frames / "frame_0001b.stl").write_bytes(b"solid x\nendsolid x\n")
    (frames / "frame_0002.ply").rename(frames / "take_0002.ply")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["align", str(frames), "--out", str(tmp_path / "out"), "--workers", "1", "--levels", "2"]) == 0
    err = err.getvalue()
    assert "take: 1 file(s) in a mesh format that is not read" in err and "frame_0001b.stl" in err
    assert ("warning: take: the frame files mix names 'frame_' and 'take_', taken in natural order: frame_0000.ply "
            "to frame_0001.ply as frames 0-1, then take_0002.ply as frame 2\n") in err
    assert "take: no meta.json gives the frame rate; written as 30 frames/s (say --fps)" in err
    # frames named each by a word: one short line, not a list of every name (a docs-only trial's ten names)
    from server.commands.align_inputs import mixed_names_text

    words = [f"{word}.obj" for word in ("alpha", "bravo", "charlie", "delta", "echo", "juliet")]
    assert mixed_names_text(words) == ("the frame files have 6 different names, taken in natural order: alpha.obj as "
                                       "frame 0, bravo.obj as frame 1, ..., juliet.obj as frame 5")
    assert mixed_names_text(["a_1.obj", "b_1.obj", "c_1.obj", "d_1.obj", "e_1.obj", "e_2.obj"]).startswith(
        "the frame files mix 5 names ('a_', 'b_', ..., 'e_'), taken in natural order: a_1.obj as frame 0, then ")
    meta = json.loads((tmp_path / "out" / "sequences" / "take" / "meta.json").read_text())
    assert meta["alignment"]["source_files"] == sorted(p.name for p in frames.iterdir() if p.suffix != ".stl")
    assert meta["fps"] == 30


def test_frames_from_a_zip_are_named_by_their_member_paths(dataset, tmp_path):
    """One zip holding two folders' frames: meta.json names each frame's member path, so frames of
    the same file name in the two folders stay apart (a docs-only trial found bare names)."""
    frames = sorted((dataset / "sequences" / "walk" / "unstructured").iterdir())[:2]
    archive = tmp_path / "two.zip"
    with zipfile.ZipFile(archive, "w") as bundle:
        for folder in ("a", "b"):
            for path in frames:
                bundle.write(path, f"{folder}/{path.name}")
    assert main(["align", str(archive), "--fps", "25", "--out", str(tmp_path / "out"), "--workers", "1",
                 "--levels", "2"]) == 0
    meta = json.loads((tmp_path / "out" / "sequences" / "two" / "meta.json").read_text())
    assert meta["alignment"]["source_files"] == [f"{folder}/{path.name}" for folder in ("a", "b") for path in frames]


def test_eval_align_scores_tree_and_sequential(dataset, tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["eval-align", str(dataset), "--max-frames", "3", "--out", str(out), "--json",
                 "--workers", "1"]) == 0
    report = json.loads(capsys.readouterr().out)
    for method in ("tree", "sequential"):
        assert report[method]["frames"] == 6
        assert {"mean_pct", "p95_pct", "max_pct", "residual_mean_mm", "seconds_per_frame"} <= set(report[method])
    assert report["tree"]["mean_pct"] < 1.5
    stages = report["stage_seconds"]   # every stage's wall time, the alignment and the repair among them
    assert {"similarity", "tree", "tetrahedralize", "align", "repair"} <= set(stages)
    assert all(t >= 0 for t in stages.values()) and stages["align"] > 0
    for method in ("tree", "sequential"):  # where the error lies, and whether the flag finds the bad frames
        breakdown = report[method]["breakdown"]
        assert {row["depths"] for row in breakdown["per_depth"]} <= {"1", "2-4", "5-16", "17-64", "65+"}
        assert sum(row["frames"] for row in breakdown["per_depth"]) == 5  # every frame but the root
        assert set(breakdown["confidence"]) == {"over_2pct", "over_3pct"}
        assert len(breakdown["worst_frames"]) == 5 and breakdown["worst_frames"][0]["frame"] != report["root"]
    assert (out / "aligned_pattern.png").is_file() and (out / "results.json").is_file()
    # every frame of both methods, in DIR/frames.csv, agreeing with the summary
    import csv
    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert [r["method"] for r in rows] == ["tree"] * 6 + ["sequential"] * 6
    for method in ("tree", "sequential"):
        mine = [r for r in rows if r["method"] == method]
        assert [(r["sequence"], int(r["frame"])) for r in mine] == [(s, f) for s in ("walk", "jog") for f in range(3)]
        worst = max(mine, key=lambda r: float(r["mean_pct"]))
        assert abs(float(worst["mean_pct"]) - report[method]["worst_frame_mean_pct"]) < 1e-3
        for entry in report[method]["breakdown"]["worst_frames"]:  # the global index and the files' SEQUENCE:FRAME
            row = mine[entry["frame"]]
            assert entry["label"] == f"{row['sequence']}:{row['frame']}"
            assert abs(float(row["mean_pct"]) - entry["mean_pct"]) < 1e-3
        roots = [r for r in mine if r["parent"] == ""]
        assert len(roots) == 1 and roots[0]["depth"] == "0" and float(roots[0]["mean_pct"]) < 0.05
        assert all(r["parent"].split(":")[0] in ("walk", "jog") for r in mine if r["parent"])
        assert sum(r["flagged"] == "1" for r in mine) == report[method]["flagged_frames"]
    assert main(["eval-align", str(dataset), "--max-frames", "3", "--out", str(tmp_path / "printed"), "--no-sequential",
                 "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    printed_report = json.loads((tmp_path / 'printed' / 'results.json').read_text())
    root, label = printed_report["root"], printed_report["root_frame"]
    assert label == ["walk:0", "walk:1", "walk:2", "jog:0", "jog:1", "jog:2"][root]
    # why no trial or race ran, as align says it (found by a docs-only user)
    assert f"root frame {root}, {label} (the spread's choice, `apart`: no trial or race on fewer than 24 frames)\n" \
        in printed
    printed_dir = tmp_path / "printed"
    assert printed.rstrip().endswith(f", {printed_dir / 'aligned_pattern.png'}, {printed_dir / 'similarity.png'} "
                                     f"and {printed_dir / 'tree.png'}")
    row = next(line for line in printed.splitlines() if line.startswith("tree "))
    assert all(float(x) != 0 or x == "0" for x in row.split()[1:8]), row  # none reads 0.00 unless it is 0
    # the figures leave out the root, which is not aligned, per sequence too (found by a docs-only user)
    for name, figures in printed_report["tree"]["per_sequence"].items():
        frame_means = [float(r["mean_pct"]) for r in csv.DictReader((tmp_path / "printed" / "frames.csv").open())
                       if r["sequence"] == name and r["parent"] != ""]
        assert figures["mean_pct"] == pytest.approx(np.mean(frame_means), abs=2e-3), (name, frame_means)
    # the sequential alignment's picture is among those written when it was made
    assert main(["eval-align", str(dataset), "--max-frames", "3", "--out", str(out), "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    assert printed.rstrip().endswith(f", {out / 'aligned_pattern_sequential.png'}, {out / 'similarity.png'} and "
                                     f"{out / 'tree.png'}")


def test_eval_align_every_kth_frame_scores_those_frames(dataset, tmp_path, capsys):
    """``--every 2``: frames 0 and 2 of each sequence, aligned and scored against their own truth."""
    from server.commands.eval_align_data import picked_frames, read_truth

    picks = picked_frames([3, 3], 2, None)
    assert [p.tolist() for p in picks] == [[0, 2], [0, 2]]
    assert [p.tolist() for p in picked_frames([7], 2, 3)] == [[0, 2, 4]]
    parts, _ = read_truth(dataset, [{"name": "walk"}, {"name": "jog"}], picks, [3, 3])
    for part, name in zip(parts, ("walk", "jog")):
        np.testing.assert_array_equal(part, load_capture_truth(dataset, name)["template_positions"][[0, 2]])
    assert main(["eval-align", str(dataset), "--every", "2", "--no-sequential", "--out", str(tmp_path / "eval"),
                 "--json", "--workers", "1", "--repair-budget", "0"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["every"] == 2 and report["frames"] == 4 and report["tree"]["frames"] == 4
    kept = ["walk:0", "walk:2", "jog:0", "jog:2"]  # worst frames: named by the files' numbers, not the kept ones'
    assert all(entry["label"] == kept[entry["frame"]] for entry in report["tree"]["breakdown"]["worst_frames"])
    assert report["root_trial"] is None and "root_trial_seconds" not in report  # 4 frames: no trial
    assert report["tree"]["mean_pct"] < 2.0
    assert report["tree"]["repair_budget"] == 0 and report["tree"]["repaired_frames"] == 0
    assert report["tree"]["swing_limbs"] is False
    assert main(["eval-align", str(dataset), "--every", "2", "--no-sequential", "--out", str(tmp_path / "swing"),
                 "--json", "--workers", "1", "--repair-budget", "0", "--swing-limbs"]) == 0
    swung = json.loads(capsys.readouterr().out)["tree"]
    assert swung["swing_limbs"] is True and swung["frames"] == 4 and swung["mean_pct"] < 2.0
    assert report["tree"]["reach_limbs"] is True and swung["reach_limbs"] is True  # on by default
    assert main(["eval-align", str(dataset), "--every", "2", "--no-sequential", "--out", str(tmp_path / "reach"),
                 "--json", "--workers", "1", "--repair-budget", "0", "--no-reach-limbs"]) == 0
    unpulled = json.loads(capsys.readouterr().out)["tree"]
    assert unpulled["reach_limbs"] is False and unpulled["frames"] == 4 and unpulled["mean_pct"] < 2.0
    assert unpulled["pulled_frames"] == 0 and 0 <= report["tree"]["pulled_frames"] <= 4
    assert report["tree"]["graft_limbs"] is False and unpulled["graft_limbs"] is False  # off by default
    assert main(["eval-align", str(dataset), "--every", "2", "--no-sequential", "--out", str(tmp_path / "grafted"),
                 "--json", "--workers", "1", "--repair-budget", "0", "--graft-limbs"]) == 0
    grafted = json.loads(capsys.readouterr().out)["tree"]
    # with no repair budget nothing is grafted: the same alignment
    assert grafted["graft_limbs"] is True and grafted["mean_pct"] == report["tree"]["mean_pct"]
    # align's --levels and --patches reach the aligner: a coarser run scores differently
    assert main(["eval-align", str(dataset), "--every", "2", "--no-sequential", "--out", str(tmp_path / "coarse"),
                 "--json", "--workers", "1", "--repair-budget", "0", "--levels", "2", "--patches", "10"]) == 0
    coarse = json.loads(capsys.readouterr().out)
    assert coarse["tree"]["frames"] == 4 and coarse["tree"]["mean_pct"] != report["tree"]["mean_pct"]
    # --root SEQUENCE:FRAME names a frame of the capture's own numbering (frames.csv's), which must be kept
    assert main(["eval-align", str(dataset), "--every", "2", "--no-sequential", "--out", str(tmp_path / "rooted"),
                 "--json", "--workers", "1", "--repair-budget", "0", "--root", "jog:2"]) == 0
    rooted = json.loads(capsys.readouterr().out)
    assert rooted["root"] == 3 and rooted["root_frame"] == "jog:2"   # kept: walk 0, 2, jog 0, 2
    assert main(["eval-align", str(dataset), "--every", "2", "--out", str(tmp_path / "r"), "--root", "jog:1"]) == 2
    assert "--root jog:1: frame 1 of jog is not among the frames kept (0, 2; --every and --max-frames pick them)" \
        in capsys.readouterr().err
    assert main(["eval-align", str(dataset), "--levels", "0"]) == 2
    assert main(["eval-align", str(dataset), "--every", "0"]) == 2
    assert main(["eval-align", str(dataset), "--retries", "-1"]) == 2
    assert "--retries must be from 0 to 10, got -1" in capsys.readouterr().err
    assert main(["eval-align", str(dataset), "--repair-budget", "-1"]) == 2
    assert "--repair-budget must be from 0 to 10, got -1" in capsys.readouterr().err
    assert main(["eval-align", str(dataset), "--levels", "9"]) == 2
    assert "--levels must be from 1 to 8, got 9" in capsys.readouterr().err


def test_eval_align_passes_retries_to_the_tree(dataset, tmp_path, capsys, monkeypatch):
    """``--retries`` is align's: it reaches the tree's alignment (not the sequential baseline) and the report."""
    import server.commands.eval_align as eval_align

    seen = []
    real = eval_align.align_captures

    def recording(*args, **kwargs):
        seen.append((kwargs.get("method"), kwargs.get("retries")))
        return real(*args, **kwargs)

    monkeypatch.setattr(eval_align, "align_captures", recording)
    assert main(["eval-align", str(dataset), "--every", "2", "--out", str(tmp_path / "eval"), "--json",
                 "--workers", "1", "--repair-budget", "0", "--retries", "0"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert seen == [("tree", 0), ("sequential", None)]  # the baseline is never retried (align_captures)
    assert report["tree"]["retries"] == 0 and report["tree"]["retried_frames"] == 0


def test_eval_align_scores_an_existing_alignment(dataset, aligned, tmp_path, capsys):
    stale = ("similarity.png", "tree.png", "aligned_pattern_sequential.png")
    for name in stale:   # an earlier run's pictures in the same --out (a docs-only trial found them left there)
        (tmp_path / name).write_bytes(b"an earlier run's picture")
    assert main(["eval-align", str(dataset), "--aligned", str(aligned), "--out", str(tmp_path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [name for name in stale if (tmp_path / name).exists()] == []
    assert (tmp_path / "aligned_pattern.png").stat().st_size > 1000
    assert report["aligned"]["mean_pct"] < 1.5
    assert report["root"] == int(np.load(aligned / "alignment.npz")["root"]) and "every" not in report
    assert report["root_frame"] == ["walk:0", "walk:1", "walk:2", "jog:0", "jog:1", "jog:2"][report["root"]]
    recorded = json.loads((aligned / "manifest.json").read_text())["alignment"]["root_reason"]
    assert recorded and report["root_reason"] == recorded  # why no trial ran, as the align output records it
    # options that steer an alignment do nothing here: refused, not accepted and ignored (a docs-only trial found
    # --root printed as "given" while the alignment's own root was scored)
    for options, named in ((["--root", "walk:1"], "--root"), (["--max-frames", "2", "--levels", "2"],
                                                                  "--max-frames, --levels"),
                           (["--every", "2"], "--every"), (["--no-reach-limbs"], "--no-reach-limbs"),
                           (["--only", "walk"], "--only")):  # it was ignored: every sequence was scored
        assert main(["eval-align", str(dataset), "--aligned", str(aligned), "--out", str(tmp_path), *options]) == 2
        assert f"error: {named}: with --aligned the output of `morphspace align` is scored as it is" in \
            capsys.readouterr().err
    # units or an up axis other than the input the alignment recorded: refused (the truth read in cm against
    # frames converted from m gave 75% errors and a warning only); what it recorded is accepted
    said = json.loads((aligned / "sequences" / "walk" / "meta.json").read_text())["alignment"]
    other = {"m": "cm", "cm": "mm", "mm": "m"}[said["source_units"]]
    assert main(["eval-align", str(dataset), "--aligned", str(aligned), "--out", str(tmp_path), "--units", other]) == 2
    assert (f"error: --units {other}: {aligned} aligned walk from input in {said['source_units']} (source_units in its "
            "meta.json)") in capsys.readouterr().err
    flipped = "z" if said["source_up"].lower().lstrip("+") == "y" else "y"
    assert main(["eval-align", str(dataset), "--aligned", str(aligned), "--out", str(tmp_path), "--up", flipped]) == 2
    assert f"error: --up {flipped}: " in capsys.readouterr().err
    assert main(["eval-align", str(dataset), "--aligned", str(aligned), "--out", str(tmp_path / "same"), "--json",
                 "--units", said["source_units"], "--up", said["source_up"].lstrip("+").lower()]) == 0
    assert json.loads(capsys.readouterr().out)["aligned"]["mean_pct"] == report["aligned"]["mean_pct"]
    # the confidence the alignment recorded, and the tree depths it aligned along (alignment.npz)
    record = np.load(aligned / "alignment.npz")
    assert report["aligned"]["flagged_frames"] == int(np.sum(record["confidence"] < 0.5))
    assert report["aligned"]["repaired_frames"] == int(np.sum(record["repaired"]))
    # the pulls kept per frame (engine.align.reach): counted, never negative, none for the root
    assert record["pulled"].dtype.kind == "i" and record["pulled"].min() >= 0
    assert record["pulled"][int(record["root"])] == 0
    assert report["aligned"]["pulled_frames"] == int(np.sum(record["pulled"] > 0))
    breakdown = report["aligned"]["breakdown"]
    assert set(breakdown["confidence"]) == {"over_2pct", "over_3pct"}
    assert sum(row["frames"] for row in breakdown["per_depth"]) == report["frames"] - 1
    assert all({"depth", "confidence", "label"} <= set(row) for row in breakdown["worst_frames"])
    import csv
    rows = list(csv.DictReader((tmp_path / "frames.csv").open()))
    assert all(row["label"] == f"{rows[row['frame']]['sequence']}:{rows[row['frame']]['frame']}"
               for row in breakdown["worst_frames"])
    assert len(rows) == report["frames"] and {r["method"] for r in rows} == {"aligned"}
    assert [float(r["confidence"]) for r in rows] == pytest.approx(record["confidence"].tolist(), abs=1e-4)
    assert sum(r["repaired"] == "1" for r in rows) == report["aligned"]["repaired_frames"]
    assert sum(r["parent"] == "" for r in rows) == 1 and all(r["depth"] != "" for r in rows)


def test_bad_input_gives_a_clear_error(tmp_path, capsys, dataset):
    assert main(["align", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "missing: no such file or directory" in capsys.readouterr().err
    assert main(["align", str(dataset), "--out", str(tmp_path / "o"), "--root", "nope:3"]) == 2
    assert "no sequence 'nope'" in capsys.readouterr().err
    # a frame past a sequence's end is refused from the files listed, before any frame is read
    assert main(["align", str(dataset), "--out", str(tmp_path / "o"), "--root", "walk:999"]) == 2
    err = capsys.readouterr().err
    assert "--root walk:999: sequence walk has frames 0.." in err and "read frames" not in err, err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["align", str(empty), "--out", str(tmp_path / "o2")]) == 2
    assert "empty" in capsys.readouterr().err


def test_captures_in_millimetres_z_up_align_as_in_metres_y_up(aligned, aligned_mm_run):
    out, err, stdout = aligned_mm_run
    assert "input walk: units mm (detected" in err and "up +Z (detected" in err and "converted to metres" in err
    assert "input jog: units m (detected" in err
    for name, units, up in (("walk", "mm", "+Z"), ("jog", "m", "+Y")):
        # written in metres, +Y up: the same numbers as from the metre files (which differ only
        # by rounding: x mm = x / 1000 m to the last bit here)
        np.testing.assert_allclose(read_sequence(out / "sequences" / name / "consistent").vertices,
                                   read_sequence(aligned / "sequences" / name / "consistent").vertices, atol=1e-9)
        meta = json.loads((out / "sequences" / name / "meta.json").read_text())
        assert (meta["units"], meta["up"]) == ("m", "+Y")
        assert (meta["alignment"]["source_units"], meta["alignment"]["source_up"]) == (units, up)
        assert meta["alignment"]["input"]["units_from"] == "detected"
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["body"]["source_units"], manifest["body"]["source_up"]) == ("mixed", "mixed")
    assert manifest["alignment"]["input"]["walk"]["units"] == "mm"
    with np.load(out / "alignment.npz", allow_pickle=False) as record:
        assert record["source_units"].tolist() == ["mm", "m"] and record["source_up"].tolist() == ["+Z", "+Y"]
    # residuals in the data's units and in % of the model size
    assert "fit residual mean" in stdout and " mm (" in stdout and "% of model size" in stdout


def test_given_units_and_up_override_detection(dataset_mm_z_up, tmp_path, capsys):
    out = tmp_path / "cm"
    assert main(["align", str(dataset_mm_z_up), "--out", str(out), "--only", "walk", "--units", "cm", "--up", "z",
                 "--levels", "1", "--retries", "0", "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "units cm (given" in captured.err and "up +Z (given" in captured.err
    assert "not human-sized; it looks like mm" in captured.err
    assert " cm (" in captured.out  # residuals shown in centimetres for data in centimetres
    template = read_mesh(out / "template" / "body.obj")
    size = np.ptp(template.vertices, axis=0)
    assert size.argmax() == 1 and 10 < size.max() < 25  # mm read as cm: ten times too big, but +Y up


def test_eval_align_of_an_existing_alignment_prints_the_root_trial_and_race_it_recorded(dataset, aligned, tmp_path,
                                                                                         capsys):
    """The printed second line names the root as the alignment's and repeats what its manifest records:
    why no trial ran, or the trial and the race (a docs-only trial found only the bare root there)."""
    root = int(np.load(aligned / "alignment.npz")["root"])
    label = ["walk:0", "walk:1", "walk:2", "jog:0", "jog:1", "jog:2"][root]
    reason = json.loads((aligned / "manifest.json").read_text())["alignment"]["root_reason"]
    assert main(["eval-align", str(dataset), "--aligned", str(aligned), "--out", str(tmp_path / "e")]) == 0
    assert capsys.readouterr().out.splitlines()[1] == (
        f"root frame {root}, {label} (align's root, as {aligned / 'manifest.json'} records: {reason})")
    raced = tmp_path / "raced"
    shutil.copytree(aligned, raced)
    manifest = json.loads((raced / "manifest.json").read_text())
    other = (root + 1) % 6
    manifest["alignment"].update(root_reason=None, root_trial={
        "candidates": [root, other], "probes": [2, 5], "mean": [0.1234, 0.2345], "spread_choice": other,
        "race": {"finalists": [root, other], "frames": 6, "confidence": [0.61, 0.55], "winner": root}})
    (raced / "manifest.json").write_text(json.dumps(manifest))
    assert main(["eval-align", str(dataset), "--aligned", str(raced), "--out", str(tmp_path / "r")]) == 0
    assert capsys.readouterr().out.splitlines()[1] == (
        f"root frame {root}, {label} (align's root, as {raced / 'manifest.json'} records: tried: candidates "
        f"[{root}, {other}], mean badness [0.1234, 0.2345]; raced: [{root}, {other}], mean confidence [0.61, 0.55])")


def test_metres_given_as_centimetres_show_residuals_to_3_significant_figures(dataset, tmp_path, capsys):
    """Frames in metres aligned with ``--units cm``: a model 1.7 cm across (warned of), whose fit
    residuals, thousandths of a centimetre, were printed as 0.00 cm."""
    assert main(["align", str(dataset), "--out", str(tmp_path / "out"), "--only", "walk", "--units", "cm",
                 "--levels", "1", "--retries", "0", "--workers", "1"]) == 0
    captured = capsys.readouterr()
    assert "units cm (given" in captured.err and "not human-sized" in captured.err
    mean, largest = re.search(r"fit residual mean (\S+) cm \(.*\), max (\S+) cm \(", captured.out).groups()
    assert float(mean) < 1 and float(largest) < 1, captured.out
    for shown in (mean, largest):  # 3 significant figures, never 0.00
        assert re.fullmatch(r"0\.0*[1-9]\d\d", shown), captured.out
    # how many alignments the repair tried, kept or not, beside what it kept (found by a docs-only user)
    assert re.search(r"  confidence: \d+ frames? repaired \(aligned again from the root or trusted frames; \d+ "
                     r"alignments? tried\), \d+ of \d+ still below 0.5", captured.out), captured.out


def test_eval_align_in_millimetres_z_up_scores_as_in_metres(dataset, dataset_mm_z_up, aligned, tmp_path, capsys):
    reports = []
    for data in (dataset, dataset_mm_z_up):  # one alignment; the walk's ground truth in m +Y up, then mm +Z up
        assert main(["eval-align", str(data), "--aligned", str(aligned), "--out", str(tmp_path / data.name),
                     "--json"]) == 0
        reports.append(json.loads(capsys.readouterr().out))
    metres, millimetres = reports
    for key in ("mean_mm", "p95_mm", "max_mm", "mean_pct", "p95_pct", "max_pct"):
        assert millimetres["aligned"][key] == pytest.approx(metres["aligned"][key], rel=1e-6, abs=1e-6)
    assert millimetres["model_size_m"] == pytest.approx(metres["model_size_m"])
    walk = millimetres["input"]["walk"]
    assert (walk["units"], walk["up"], millimetres["input"]["jog"]["units"]) == ("mm", "+Z", "m")
    assert (metres["input"]["walk"]["units"], metres["input"]["walk"]["up"]) == ("m", "+Y")
    assert millimetres["display_unit"] == metres["display_unit"] == "mm"
    # the printed report says which sequences are in which units (found by a docs-only user)
    assert main(["eval-align", str(dataset_mm_z_up), "--aligned", str(aligned), "--out", str(tmp_path / "printed")]) == 0
    assert "; input in m, +Y up (jog) / mm, +Z up (walk); lengths in mm\n" in capsys.readouterr().out


def test_printed_figures_under_1_keep_3_significant_figures():
    """eval-align's table printed 0.0 cm and 0.00% for errors of thousandths (found by a docs-only
    user); its figures, like align's lengths, keep 3 significant figures under 1."""
    from server.units import figure_text

    assert [figure_text(v) for v in (0.00173, 0.0456, 0.5, 1.5, 12.345, 0.0)] == \
        ["0.00173", "0.0456", "0.500", "1.50", "12.35", "0.00"]
    assert [figure_text(v, 0) for v in (0.00173, 3.6, 250.4)] == ["0.00173", "4", "250"]
    assert figure_text(-0.0123, 1) == "-0.0123" and figure_text(float("nan")) == "nan"


def test_build_converts_sources_in_millimetres_z_up(aligned, tmp_path, capsys):
    spaces = {}
    for units, up in (("m", "y"), ("mm", "z")):
        sources = []
        for name in ("walk", "jog"):
            copy = tmp_path / units / "sequences" / name
            sequence = read_sequence(aligned / "sequences" / name / "consistent")
            for k, V in enumerate(sequence.vertices):
                write_obj(copy / "consistent" / f"frame_{k:04d}.obj", from_metres_y_up(V, units, up), sequence.faces)
            meta = json.loads((aligned / "sequences" / name / "meta.json").read_text())
            meta.update(cyclic=False, units=units, up=f"+{up.upper()}")
            (copy / "meta.json").write_text(json.dumps(meta))
            sources += ["--source", str(copy)]
        spaces[units] = tmp_path / f"{units}.mspace"
        assert main(["build", *sources, "--out", str(spaces[units]), "--phases", "3"]) == 0
    err = capsys.readouterr().err
    # (no template next to these copies: the rest shape is the first frame, in the sources' units)
    assert "source walk, jog, the rest shape: units mm (detected" in err and "up +Z (detected" in err
    assert "converted to metres" in err and "morphspace build: rest shape: resting on the first frame" in err
    from engine.motion_space import MotionSpace

    with MotionSpace.open(spaces["m"]) as metres, MotionSpace.open(spaces["mm"]) as millimetres:
        # the space records what its sources were in (its own coordinates are metres, +Y up)
        assert (metres.metadata["source_units"], metres.metadata["source_up"]) == ("m", "+Y")
        assert (millimetres.metadata["source_units"], millimetres.metadata["source_up"]) == ("mm", "+Z")
        assert millimetres.metadata["input"]["walk"] == {"units": "mm", "up": "+Z", "units_from": "detected",
                                                         "up_from": "detected"}
        assert millimetres.metadata["input"]["rest"]["units"] == "mm"
        assert (millimetres.metadata["units"], millimetres.metadata["up"]) == ("m", "+Y")
        for key in ("sources", "rest", "tet_vertices"):
            np.testing.assert_allclose(np.asarray(millimetres.container[key]), np.asarray(metres.container[key]),
                                       atol=1e-6)


def test_an_unwelded_root_frame_is_welded_before_its_tetrahedra(dataset, tmp_path, capsys):
    """A frame exported unwelded (each face its own three vertices) as the root: its twins become
    one vertex, so it fills with tetrahedra and every frame is aligned onto it."""
    copy = tmp_path / "soup"
    shutil.copytree(dataset, copy)
    path = sorted((copy / "sequences" / "walk" / "unstructured").iterdir())[1]
    mesh = read_mesh(path)
    V = mesh.vertices[mesh.faces].reshape(-1, 3)
    write_ply(path, V, np.arange(len(V)).reshape(-1, 3), colors=mesh.colors[mesh.faces].reshape(-1, 3),
              dtype=np.float64)
    out = tmp_path / "out"
    assert main(["align", str(copy), "--out", str(out), "--workers", "1", "--levels", "2", "--root", "walk:1"]) == 0
    template = read_mesh(out / "template" / "body.obj")
    assert len(template.vertices) <= len(np.unique(V, axis=0)) < len(V)
    printed = capsys.readouterr().out
    assert "root walk:1" in printed and "  root: the root given: no trial or race\n" in printed
    assert json.loads((out / "manifest.json").read_text())["alignment"]["root_reason"] == "the root given: no trial or race"
    for name in ("walk", "jog"):
        assert read_sequence(out / "sequences" / name / "consistent").vertices.shape[1] == len(template.vertices)


def test_metadata_units_that_are_not_units_are_named_and_not_used(dataset):
    from server.units import declared_convention, meshes_to_metres

    declared = declared_convention([{"units": "furlongs", "up": "+X"}, {"units": "m"}])
    assert (declared.units, declared.up) == ("m", None)  # the next record's claim
    assert declared.ignored == ("the metadata's units 'furlongs' are none of m, cm, mm: ignored",
                                "the metadata's up axis '+X' is neither +Y nor +Z: ignored")
    meshes = read_frames(dataset / "sequences" / "walk" / "unstructured")
    _, convention = meshes_to_metres(meshes, declared=declared)
    assert (convention.units, convention.up) == ("m", "y")
    assert set(declared.ignored) <= set(convention.warnings)


def test_eval_align_refuses_frames_that_do_not_match_their_ground_truth(dataset, tmp_path, capsys):
    """A frame missing in the middle of a sequence would pair every later frame with the wrong truth:
    eval-align names the truth file and both counts instead of scoring (found by a docs-only trial)."""
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    frames = sorted((copy / "sequences" / "walk" / "unstructured").iterdir())
    frames[1].unlink()
    assert main(["eval-align", str(copy), "--no-sequential", "--workers", "1", "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err
    assert "sequences/walk/truth.npz: ground truth for 3 frames, the sequence has 2" in err
    assert not (tmp_path / "e").exists()


def test_aligned_metadata_drops_what_describes_the_input_frames():
    """The aligned frames are neither the studio's reconstructions nor noisy: their statistics and
    noise stay with the input (docs/file-formats.md, aligned datasets)."""
    from server.commands.align_output import aligned_meta

    meta = {"name": "walk", "cyclic": True, "frames_per_cycle": 24, "fps": 25.0, "units": "mm", "up": "+Z",
            "noise_mm": 2.5, "studio": {"holes_per_frame": 6.1}, "unstructured_vertex_counts": [10000]}
    out = aligned_meta(meta, "walk", 24, 25.0, 9000, 18000)
    assert out["cyclic"] is True and out["frames_per_cycle"] == 24 and out["frames"] == 24
    assert not {"studio", "noise_mm", "unstructured_vertex_counts"} & set(out)


def test_the_summary_says_whether_colours_were_cues_and_why(aligned_run):
    from server.commands.align_output import colour_cues_text

    # the 1,000-vertex body is too coarse for its colours to carry a texture
    assert "colour cues off (--colors auto: the root's median edge is not under 1.6% of" in aligned_run[2]
    # 6 frames: too few to try roots, and the summary says so; the manifest records no trial
    assert "root: the spread's choice, `apart`: no trial or race on fewer than 24 frames" in aligned_run[2]
    assert json.loads((aligned_run[0] / "manifest.json").read_text())["alignment"]["root_trial"] is None
    # the pieces the pruned graph fell into, as alignment.npz records them ("1 component reconnected"
    # when nothing was; a docs-only user)
    pieces = int(np.load(aligned_run[0] / "alignment.npz")["tree_components"])
    assert (", the pruned graph in one piece), " if pieces == 1 else
            f", {pieces} pieces of the pruned graph reconnected), ") in aligned_run[2]
    frames = [types.SimpleNamespace(colors=None)]
    assert colour_cues_text("auto", False, frames) == "off (--colors auto: not every frame has vertex colours)"
    assert colour_cues_text("on", True, frames) == "on (--colors on)"


def test_a_frame_wound_inward_is_turned_outward_and_aligns_as_the_others(dataset, aligned, tmp_path, capsys):
    """A frame written with every face reversed (an exporter of the other handedness) faces into
    the body; it is wound outward again first, so the alignment is the same, bit for bit, and the
    summary names it."""
    copy = tmp_path / "inward"
    shutil.copytree(dataset, copy)
    path = sorted((copy / "sequences" / "jog" / "unstructured").iterdir())[2]
    mesh = read_mesh(path)
    write_ply(path, mesh.vertices, mesh.faces[:, ::-1], colors=mesh.colors, dtype=np.float64)
    out = tmp_path / "out"
    assert main(["align", str(copy), "--out", str(out), "--workers", "1", "--levels", "3"]) == 0
    assert "turned outward in 1 frame: jog:2" in capsys.readouterr().out
    for name in ("walk", "jog"):
        ours = read_sequence(out / "sequences" / name / "consistent")
        theirs = read_sequence(aligned / "sequences" / name / "consistent")
        np.testing.assert_array_equal(ours.vertices, theirs.vertices)
        np.testing.assert_array_equal(ours.faces, theirs.faces)


@pytest.fixture(scope="module")
def longer_dataset(tmp_path_factory):
    """One gait sequence of 24 frames: just long enough for the root to be tried."""
    root = tmp_path_factory.mktemp("captures") / "longer"
    body = build_body(1000)
    write_capture_template(root, body)
    data = generate_sequence_data(body, SequenceSpec("walk", "gait", {"speed": 1.2, "cycles": 1.5}), fps=15, seed=3)
    assert len(data["unstructured"]) == 24
    write_capture_sequence(root, "walk", faces=body.F, vertices=data["vertices"], colors=body.colors,
                           unstructured=data["unstructured"], truth=data["truth"], meta=data["meta"])
    write_capture_manifest(root, {"preset": "test", "fps": 15, "body": {"model_size": body.size},
                                  "sequences": [data["meta"]]})
    return root


def test_the_root_is_tried_and_raced_on_a_capture_of_24_frames_or_more(longer_dataset, tmp_path, capsys, monkeypatch):
    from engine.align import captures, root_trial
    from engine.align.root_race import finalists

    # three probes a candidate instead of six, in all four runs (the summary reports the count)
    monkeypatch.setattr(captures, "trial_probes", functools.partial(root_trial.trial_probes, count=3))
    out = tmp_path / "tried"
    assert main(["align", str(longer_dataset), "--out", str(out), "--workers", "2", "--levels", "1",
                 "--root-choice", "race"]) == 0
    captured = capsys.readouterr()
    assert "try roots: 100%" in captured.err and "race roots: 100%" in captured.err
    assert ", root trial " in captured.out and ", root race " in captured.out
    line = next(x for x in captured.out.splitlines() if "root tried:" in x)
    assert "candidates aligned 3 probe frames each (mean badness, lower is better: walk:" in line, line
    tried, raced = line.split("better: ")[1], line.split("higher is better: ")[1]
    means = {label: float(value) for label, value in re.findall(r"(walk:\d+) ([0-9.]+)", tried.split(")")[0])}
    confidence = {label: float(value) for label, value in re.findall(r"(walk:\d+) ([0-9.]+)", raced.split(")")[0])}
    frames = len(np.load(out / "alignment.npz")["parent"])
    # the manifest keeps the whole report, unrounded
    record = json.loads((out / "manifest.json").read_text())["alignment"]["root_trial"]
    # the trial's two least bad candidates (by the unrounded means: two may print alike) each aligned
    # the whole capture; the more confident is the root
    assert f"; the best 2 each aligned {frames} frames (mean confidence" in line, line
    least_bad = [f"walk:{c}" for c in finalists(record)]
    assert sorted(confidence) == sorted(least_bad), (means, confidence)
    best = f"walk:{record['race']['winner']}"
    assert confidence[best] == max(confidence.values())
    assert f"; {best} " in line and np.load(out / "alignment.npz")["root"] == int(best.split(":")[1])
    assert ("kept (the spread's choice too)" in line) != ("taken instead of the spread's choice, walk:" in line), line
    assert record["race"]["winner"] == np.load(out / "alignment.npz")["root"] and record["race"]["frames"] == frames
    assert [round(m, 2) for m in record["mean"]] == [means[f"walk:{c}"] for c in record["candidates"]]
    # the trial alone: no race
    assert main(["align", str(longer_dataset), "--out", str(tmp_path / "trial"), "--workers", "1", "--levels", "1",
                 "--root-choice", "trial"]) == 0
    captured = capsys.readouterr()
    assert "root tried:" in captured.out and "race roots" not in captured.err and "root race" not in captured.out
    # the spread's choice alone: no trial
    assert main(["align", str(longer_dataset), "--out", str(tmp_path / "apart"), "--workers", "1", "--levels", "1",
                 "--root-choice", "apart"]) == 0
    captured = capsys.readouterr()
    assert "root tried" not in captured.out and "try roots" not in captured.err
    # the default on a tracked take: the trial's choice, no race, and the summary says why (this walk's tree is not a
    # chain: a stride's frames look alike, so 52% of its steps join neighbours; the share asked for is lowered)
    from engine.align import root_race

    monkeypatch.setattr(root_race, "TRACKED_SHARE", 0.3)
    assert main(["align", str(longer_dataset), "--out", str(tmp_path / "auto"), "--workers", "1", "--levels", "1"]) == 0
    captured = capsys.readouterr()
    assert "root tried:" in captured.out and "try roots: 100%" in captured.err and "race roots" not in captured.err
    assert "  root: the trial's choice: no race on a densely tracked take (" in captured.out
    record = json.loads((tmp_path / "auto" / "manifest.json").read_text())["alignment"]
    assert "race" not in record["root_trial"] and "densely tracked take" in record["root_reason"]
    assert record["options"]["root_choice"] == "auto"


def test_an_output_that_would_destroy_the_input_is_refused_before_any_work(dataset, tmp_path, capsys):
    """--out the input itself (or a directory holding it) with --force replaced the frames being
    aligned by the result; a file as --out failed only after the whole alignment, leaving its
    staging directory behind (found by a bad-input trial)."""
    copy = tmp_path / "copy"
    shutil.copytree(dataset / "sequences" / "walk", copy)
    before = sorted(p.name for p in copy.rglob("*"))
    for out in (copy, tmp_path, copy / "inside"):
        assert main(["align", str(copy), "--out", str(out), "--force"]) == 2
        err = capsys.readouterr().err
        assert "--out" in err and str(copy) in err and "Traceback" not in err
    assert sorted(p.name for p in copy.rglob("*")) == before
    afile = tmp_path / "afile"
    afile.write_text("not a directory")
    assert main(["align", str(copy), "--out", str(afile), "--force"]) == 2
    assert "afile is a file, not a directory" in capsys.readouterr().err
    assert afile.read_text() == "not a directory" and not list(tmp_path.glob(".afile*"))


def test_a_given_root_with_a_root_choice_is_refused(dataset, tmp_path, capsys):
    """--root with --root-choice race ran with the root given and recorded root_choice "race" beside
    root_reason "the root given" (a docs-only trial); refused before any frame is read, in align and
    eval-align; --root-choice auto (the default) with --root stays accepted."""
    for command in (["align", str(dataset), "--out", str(tmp_path / "a")],
                    ["eval-align", str(dataset), "--out", str(tmp_path / "e")]):
        assert main([*command, "--root", "walk:0", "--root-choice", "race"]) == 2
        err = capsys.readouterr().err
        assert "error: --root-choice race: the root is given (--root walk:0), so no root is chosen" in err, err
        assert not (tmp_path / "a").exists() and not (tmp_path / "e").exists()


def test_bad_frame_rates_and_metadata_are_named(dataset, tmp_path, capsys):
    copy = tmp_path / "walk"
    shutil.copytree(dataset / "sequences" / "walk", copy)
    for fps in ("nan", "-3", "0", "inf"):
        assert main(["align", str(copy), "--out", str(tmp_path / "o"), "--fps", fps]) == 2
        assert "--fps must be above 0 and at most 1000" in capsys.readouterr().err
    assert main(["align", str(copy), "--out", str(tmp_path / "o"), "--repair-budget", "nan"]) == 2
    assert "--repair-budget must be from 0 to 10, got nan" in capsys.readouterr().err
    for meta, words in (("[1, 2]", "meta.json: not a JSON object"), ('{"fps": "fast"}', "meta.json: fps must be"),
                        ('{"fps": NaN}', "meta.json: fps must be")):
        (copy / "meta.json").write_text(meta)
        assert main(["align", str(copy), "--out", str(tmp_path / "o")]) == 2
        assert words in capsys.readouterr().err
    broken = tmp_path / "broken"
    shutil.copytree(dataset, broken)
    manifest = json.loads((broken / "manifest.json").read_text())
    (broken / "manifest.json").write_text(json.dumps({**manifest, "sequences": 5}))
    assert main(["align", str(broken), "--out", str(tmp_path / "o")]) == 2
    assert "manifest.json: 'sequences' must be a list of objects with a 'name'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_eval_align_names_a_broken_ground_truth_or_alignment(dataset, aligned, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    truth = copy / "sequences" / "walk" / "truth.npz"
    with np.load(truth) as data:
        arrays = {k: data[k] for k in data.files}
    cases = {"no positions": {k: v for k, v in arrays.items() if k != "template_positions"},
             "half the vertices": {**arrays, "template_positions": arrays["template_positions"][:, :500]}}
    words = {"no positions": "truth.npz: no template_positions", "half the vertices": "has shape (3, 500, 3)"}
    for case, content in cases.items():
        np.savez(truth, **content)
        assert main(["eval-align", str(copy), "--aligned", str(aligned), "--out", str(tmp_path / "e")]) == 2
        assert words[case] in capsys.readouterr().err, case
    truth.write_bytes(b"PK\x03\x04 not really a zip")
    assert main(["eval-align", str(copy), "--aligned", str(aligned), "--out", str(tmp_path / "e")]) == 2
    assert "truth.npz: unreadable ground truth" in capsys.readouterr().err
    broken = tmp_path / "aligned"
    shutil.copytree(aligned, broken)
    (broken / "alignment.npz").write_bytes((aligned / "alignment.npz").read_bytes()[:300])
    assert main(["eval-align", str(dataset), "--aligned", str(broken), "--out", str(tmp_path / "e")]) == 2
    assert "alignment.npz: unreadable alignment record" in capsys.readouterr().err
    assert main(["eval-align", str(tmp_path / "nope"), "--out", str(tmp_path / "e")]) == 2
    assert "nope: no such directory" in capsys.readouterr().err
    assert main(["eval-align", str(dataset), "--workers", "0", "--out", str(tmp_path / "e")]) == 2
    assert "--workers must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "e").exists()


def test_a_sequence_with_consistent_frames_only_is_read_from_them(tmp_path):
    """An aligned output aligned again (or an upload's sequence): its frames are in consistent/, and
    `align` said "no mesh files among the 2 entries of the directory" (a docs-only user)."""
    from engine.mesh_io import write_obj
    from server.commands.align_inputs import resolve_inputs

    sequence = tmp_path / "walk"
    (sequence / "consistent").mkdir(parents=True)
    (sequence / "meta.json").write_text(json.dumps({"name": "walk", "fps": 10.0}))
    V, F = np.eye(3).tolist() + [[0.0, 0.0, 0.0]], [[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]]
    write_obj(sequence / "consistent" / "frame_0000.obj", np.array(V), np.array(F))
    (entry,) = resolve_inputs([sequence])
    assert entry["frames"] == sequence / "consistent"
    (sequence / "unstructured").mkdir()  # re-meshed frames, where there are any, come first
    assert resolve_inputs([sequence])[0]["frames"] == sequence / "unstructured"


def test_the_summary_says_what_the_root_mesh_left_out_of_its_frame(dataset, tmp_path, capsys):
    """The root mesh leaves out its frame's floating pieces (and welded twins, unused vertices): the
    summary gives both counts, so a template smaller than the frame named as root is explained."""
    frames = tmp_path / "walk"
    frames.mkdir()
    for path in sorted((dataset / "sequences" / "walk" / "unstructured").iterdir()):
        mesh = read_mesh(path)
        blob = np.array([[0, 0, 0], [0.02, 0, 0], [0, 0.02, 0], [0, 0, 0.02]]) + [0.6, 1.0, 0.0]   # beside the body
        V = np.concatenate([mesh.vertices, blob])
        n = len(mesh.vertices)
        F = np.concatenate([mesh.faces, n + np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])])
        write_obj(frames / f"{path.stem}.obj", V, F)
    out = tmp_path / "out"
    assert main(["align", str(frames), "--out", str(out), "--workers", "1", "--levels", "3", "--root", "1",
                 "--colors", "off"]) == 0
    captured = len(read_mesh(frames / "frame_0001.obj").vertices)
    kept = len(read_mesh(out / "template" / "body.obj").vertices)
    assert kept <= captured - 4
    assert (f"root walk:1 = frame 1, {kept} of its frame's {captured} vertices: {captured - kept} left out (floating "
            f"pieces, vertices welded to a twin at the same place, vertices no face uses)") in capsys.readouterr().out


def test_a_single_frame_is_its_own_root_and_the_summary_says_nothing_was_aligned(dataset, tmp_path, capsys):
    """One frame is accepted: it is the root, written as it is; the summary gave a time per frame aligned
    (0.28 s/frame wall) for no frame aligned (a docs-only trial)."""
    frames = tmp_path / "single"
    frames.mkdir()
    first = sorted((dataset / "sequences" / "walk" / "unstructured").iterdir())[0]
    shutil.copy(first, frames / first.name)
    assert main(["align", str(frames), "--out", str(tmp_path / "out"), "--workers", "1", "--levels", "2"]) == 0
    out = capsys.readouterr().out
    assert "no alignment (the root is the only frame), repair 0.0 s" in out and "s/frame" not in out, out
    assert read_sequence(tmp_path / "out" / "sequences" / "single" / "consistent").vertices.shape[0] == 1


def test_a_frame_in_other_units_than_its_sequence_is_refused_by_name(dataset, tmp_path, capsys):
    """One frame of the walk saved in millimetres among frames in metres: aligned, it was a body a
    thousand times too big (residuals of kilometres, exit 0) and dragged the frames aligned from it.
    Units are decided per sequence, so a frame off its sequence's scale is named and nothing written;
    stray unreferenced points do not count towards a frame's size."""
    root = tmp_path / "mixed"
    shutil.copytree(dataset, root)
    frames = root / "sequences" / "walk" / "unstructured"
    mesh = read_frames(frames)[1]
    path = sorted(frames.iterdir())[1]
    stray = np.vstack([mesh.vertices, [[40.0, 0.0, 0.0]]])  # a far point no face uses: not the frame's size
    write_ply(path, stray, mesh.faces, colors=np.vstack([mesh.colors, [[0.5, 0.5, 0.5]]]), dtype=np.float64)
    out = tmp_path / "out"
    assert main(["align", str(root), "--out", str(out), "--only", "walk", "--levels", "1", "--retries", "0",
                 "--workers", "1"]) == 0
    capsys.readouterr()
    write_ply(path, mesh.vertices * 1000.0, mesh.faces, colors=mesh.colors, dtype=np.float64)
    assert main(["align", str(root), "--out", str(tmp_path / "refused"), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    said = re.search(rf"sequence 'walk': {path.name} \(frame 1\) is ([\d,]+) times the size of the sequence's "
                     "median frame: one sequence's frames must be in the same units", err)
    assert said and 900 < int(said.group(1).replace(",", "")) < 1100, err[-500:]
    assert not (tmp_path / "refused").exists()
