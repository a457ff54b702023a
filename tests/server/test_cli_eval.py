"""`morphspace eval` end to end on a small walk/run space: JSON report, figures, ground truth."""

import json

import numpy as np
import pytest
from PIL import Image

from engine.mesh_io.dataset import DATASET_FORMAT, DATASET_VERSION
from engine.motion_space import SourceClip, build_motion_space
from engine.synthetic import animate, build_body, gait
from server.cli import main

SPEEDS = {"walk": 0.8, "run": 3.0}
BODY_VERTICES = 1000


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A motion space and the capture-dataset metadata its sources came from (no frames needed)."""
    root = tmp_path_factory.mktemp("eval")
    body = build_body(BODY_VERTICES)
    captures = root / "captures"
    (captures / "sequences").mkdir(parents=True)
    (captures / "manifest.json").write_text(json.dumps({
        "format": DATASET_FORMAT, "version": DATASET_VERSION,
        "body": {"vertices": BODY_VERTICES, "height": 1.75}}))
    clips = []
    for name, speed in SPEEDS.items():
        motion = gait(body.skeleton, speed, cycles=2.0, start_phase=0.0)
        n = len(motion.times)
        clips.append(SourceClip(name=name, vertices=animate(body, motion), fps=motion.fps, cyclic=True))
        (captures / "sequences" / name).mkdir()
        (captures / "sequences" / name / "meta.json").write_text(json.dumps({
            "name": name, "kind": "gait", "fps": motion.fps, "frames": n, "cyclic": True,
            "frames_per_cycle": n, "requested": {"speed": speed, "turn_rate": 0.0},
            "motion_params": motion.params, "events": {"left_heel_strikes": []}}))
    space = root / "walk_run.mspace"
    build_motion_space(space, clips, body.F, name="walk_run", n_phases=8, epsilon=0.005, rest=body.V)
    return space, captures


def run_json(capsys, argv):
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def assert_picture(path):
    image = np.asarray(Image.open(path).convert("RGB"), dtype=float)
    assert image.shape[0] > 200 and image.shape[1] > 600
    assert image.std() > 10  # not blank


def test_eval_json_report_and_heatmap(dataset, tmp_path, capsys):
    space, _ = dataset
    out = tmp_path / "report"
    result = run_json(capsys, ["eval", str(space), "--json", "--out", str(out), "--timing-calls", "10"])
    assert {"space", "errors", "heatmap", "results"} <= set(result)
    assert "sweep" not in result and "ground_truth" not in result
    methods = result["errors"]["methods"]
    assert list(methods) == ["linear", "hybrid_1", "hybrid_3", "hybrid", "nonlinear"]
    for row in methods.values():
        assert {"max_error_mm", "max_error_percent", "mean_error_mm", "time_per_frame_ms",
                "frames_per_second", "references"} <= set(row)
    assert methods["nonlinear"]["max_error_mm"] == 0.0
    assert methods["hybrid"]["max_error_mm"] <= 5.01
    assert result["heatmap"]["path"] == str(out / "heatmap.png")
    assert_picture(out / "heatmap.png")
    assert json.loads((out / "results.json").read_text())["errors"]["methods"].keys() == methods.keys()


def test_eval_sweep_and_ground_truth(dataset, capsys):
    space, captures = dataset
    result = run_json(capsys, ["eval", str(space), "--json", "--sweep", "--epsilons-mm", "3", "10",
                               "--captures", str(captures), "--timing-calls", "5"])
    out = space.with_name("walk_run-eval")  # the default output directory
    assert result["heatmap"]["path"] == str(out / "heatmap.png")
    assert [r["epsilon_mm"] for r in result["sweep"]["rows"]] == [3, 10]
    assert_picture(out / "epsilon_sweep.png")
    gt = result["ground_truth"]
    assert [s["name"] for s in gt["sources"]] == ["walk", "run"]
    assert all(s["max_mm"] < 1.0 for s in gt["sources"])  # the truth reproduces each source (re-warped)
    assert gt["summary"]["nonlinear"]["mean_mm"] < gt["summary"]["linear"]["mean_mm"]


def test_eval_ground_truth_of_a_dataset_without_a_recorded_height(dataset, tmp_path, capsys):
    """Datasets synthesised before 2026-11-30 record ``"height": null`` for the default body (1.75 m)."""
    import shutil

    space, captures = dataset
    old = tmp_path / "old-captures"
    shutil.copytree(captures, old)
    manifest = json.loads((old / "manifest.json").read_text())
    manifest["body"]["height"] = None
    (old / "manifest.json").write_text(json.dumps(manifest))
    result = run_json(capsys, ["eval", str(space), "--json", "--out", str(tmp_path / "out"), "--captures", str(old),
                               "--timing-calls", "5"])
    assert all(s["max_mm"] < 1.0 for s in result["ground_truth"]["sources"])


def test_eval_prints_tables(dataset, tmp_path, capsys):
    space, _ = dataset
    assert main(["eval", str(space), "--out", str(tmp_path), "--timing-calls", "5",
                 "--weights", "0.5", "0.5", "--phase", "0.25"]) == 0
    text = capsys.readouterr().out
    for label in ("Linear", "Hybrid, 1 reference", "Hybrid, 3 references", "Hybrid, epsilon 5 mm", "Non-linear",
                  "frames/s"):
        assert label in text
    assert json.loads((tmp_path / "results.json").read_text())["heatmap"]["phase"] == 0.25


def test_eval_errors_are_one_line(dataset, tmp_path, capsys):
    space, _ = dataset
    assert main(["eval", str(tmp_path / "missing.mspace")]) == 2
    assert "no such motion space" in capsys.readouterr().err
    assert main(["eval", str(space), "--out", str(tmp_path), "--weights", "1", "2", "3"]) == 2
    assert "expected 2 weights" in capsys.readouterr().err
