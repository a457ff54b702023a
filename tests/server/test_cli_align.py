"""`morphspace align` and `morphspace eval-align` on a few frames of a tiny capture dataset."""

import contextlib
import io
import json
import shutil

import numpy as np
import pytest

from engine.mesh_io import read_mesh, read_sequence
from engine.mesh_io.dataset import write_capture_manifest, write_capture_sequence, write_capture_template
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
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["align", str(dataset), "--out", str(out), "--workers", "1", "--levels", "3"]) == 0
    return out, err.getvalue()


@pytest.fixture(scope="module")
def aligned(aligned_run):
    return aligned_run[0]


def test_align_shows_progress_bars_up_to_every_frame(aligned_run):
    _, err = aligned_run
    for stage in ("shape histograms", "dissimilarity", "align", "write"):
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
    with np.load(aligned / "alignment.npz", allow_pickle=False) as record:
        n = int(record["lengths"].sum())
        assert record["dissimilarity"].shape == (n, n)
        assert record["tree_edges"].shape == (n - 1, 2)
        assert record["residual"].shape == (n,) and record["residual"].max() < 0.01
        root = int(record["root"])
    # the root frame is the template: its aligned copy is the root mesh itself
    names = [str(s) for s in np.load(aligned / "alignment.npz")["sequence_names"]]
    for picture in ("similarity.png", "tree.png", "aligned_pattern.png"):
        assert (aligned / picture).stat().st_size > 0
    assert 0 <= root < n and names == ["walk", "jog"]


def test_eval_align_scores_tree_and_sequential(dataset, tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["eval-align", str(dataset), "--max-frames", "3", "--out", str(out), "--json",
                 "--workers", "1"]) == 0
    report = json.loads(capsys.readouterr().out)
    for method in ("tree", "sequential"):
        assert report[method]["frames"] == 6
        assert {"mean_pct", "p95_pct", "max_pct", "residual_mean_mm", "seconds_per_frame"} <= set(report[method])
    assert report["tree"]["mean_pct"] < 1.5
    assert (out / "aligned_pattern.png").is_file() and (out / "results.json").is_file()


def test_eval_align_scores_an_existing_alignment(dataset, aligned, tmp_path, capsys):
    assert main(["eval-align", str(dataset), "--aligned", str(aligned), "--out", str(tmp_path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["aligned"]["mean_pct"] < 1.5


def test_bad_input_gives_a_clear_error(tmp_path, capsys, dataset):
    assert main(["align", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "missing: no such file or directory" in capsys.readouterr().err
    assert main(["align", str(dataset), "--out", str(tmp_path / "o"), "--root", "nope:3"]) == 2
    assert "no sequence 'nope'" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["align", str(empty), "--out", str(tmp_path / "o2")]) == 2
    assert "empty" in capsys.readouterr().err
