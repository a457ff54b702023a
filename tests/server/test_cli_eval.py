"""`morphspace eval` end to end on a small walk/run space: JSON report, figures, ground truth."""

import json

import numpy as np
import pytest
from PIL import Image
from cli_refused import refused

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


def test_eval_bad_input_is_refused_before_anything_is_written(dataset, tmp_path, capsys, monkeypatch):
    space, _ = dataset
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.obj").write_text("v 0 0 0\n")
    (tmp_path / "dir").mkdir()
    renamed = tmp_path / "renamed.mspace"  # built as walk_run.mspace: its name inside is walk_run
    renamed.write_bytes(space.read_bytes())
    before = sorted(p.name for p in tmp_path.iterdir())
    refused(capsys, ["eval", "dir"], "dir: is a directory, not a motion space file")
    refused(capsys, ["eval", space, "--out", "a.obj"], "--out a.obj: exists and is not a directory")
    refused(capsys, ["eval", space, "--out", "ev", "--sweep", "--epsilons-mm", "nan"],
             "--epsilons-mm must be positive numbers of millimetres, got nan")
    refused(capsys, ["eval", space, "--out", "ev", "--weights", "nan", "1"], "--weights must be finite")
    refused(capsys, ["eval", space, "--out", "ev", "--seed", "-1"], "--seed must be a non-negative integer, got -1")
    refused(capsys, ["eval", space, "--out", "ev", "--timing-calls", "1000000000"],
             "--timing-calls must be between 1 and 100000")
    err = refused(capsys, ["eval", "renamed.mspace", "--out", "ev", "--weights", "1", "2", "3"],
                   "--weights: expected 2 weights (walk, run) for renamed.mspace, got 3")
    assert "walk_run" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no ev/


def test_eval_huge_weights_are_normalised_without_overflow(dataset, tmp_path, capsys):
    space, _ = dataset
    result = run_json(capsys, ["eval", str(space), "--json", "--out", str(tmp_path / "ev"), "--timing-calls", "5",
                               "--weights", "1e308", "1e308", "--phase", "0.5"])
    assert result["heatmap"]["weights"] == [0.5, 0.5]
    assert_picture(tmp_path / "ev" / "heatmap.png")


def test_eval_removes_the_out_directory_it_made_when_it_fails(dataset, tmp_path, capsys, monkeypatch):
    from engine import evaluation

    def fail(*args, **kwargs):
        raise ValueError("blend errors failed")

    space, _ = dataset
    monkeypatch.setattr(evaluation, "blend_errors", fail)
    refused(capsys, ["eval", space, "--out", tmp_path / "new" / "ev"], "blend errors failed")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv,message", [
    (["--per-axis", "0"], "--per-axis must be between 2 and 201, got 0"),
    (["--per-axis", "-2"], "--per-axis must be between 2 and 201, got -2"),
    (["--per-axis", "1000"], "--per-axis must be between 2 and 201, got 1000"),
])
def test_eval_params_bad_per_axis_is_refused(built_spaces, capsys, argv, message):
    refused(capsys, ["eval-params", built_spaces / "speed.mspace", *argv], message)


def test_eval_params_names_a_renamed_space_by_its_file(dataset, tmp_path, capsys):
    space, _ = dataset
    renamed = tmp_path / "renamed.mspace"
    renamed.write_bytes(space.read_bytes())
    err = refused(capsys, ["eval-params", renamed], f"{renamed}: the space has no parameter map")
    assert "walk_run" not in err


@pytest.mark.parametrize("argv,message", [
    (["--calls", "1000000000"], "--calls must be between 10 and 1000000, got 1000000000"),
    (["--calls", "5"], "--calls must be between 10 and 1000000, got 5"),
    (["--nonlinear-calls", "1000000000"], "--nonlinear-calls must be between 5 and 100000, got 1000000000"),
    (["--seed", "-1"], "--seed must be a non-negative integer, got -1"),
])
def test_bench_bad_options_are_refused(dataset, capsys, argv, message):
    space, _ = dataset
    refused(capsys, ["bench", space, *argv], message)


def test_bench_requests_are_the_engines_draws_in_little_memory():
    import tracemalloc

    from engine.bench import blend_requests

    # the draws as a list of (weights, phase) tuples made them (before 2026-11-30), from the same generator
    rng = np.random.default_rng(4)
    engine = [(w, float(p)) for w, p in zip(rng.dirichlet(np.ones(3), 200), rng.uniform(0, 1, 200))]
    ours = blend_requests(3, 200, seed=4)
    assert len(ours) == len(engine) == 200
    for (w, p), (v, q) in zip(ours, engine):
        np.testing.assert_array_equal(w, v)
        assert p == q
    tracemalloc.start()
    blend_requests(3, 100_000)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 100_000 * 48  # (3 + 1) float64 a call and the generator's scratch, not ~250 bytes a call


def test_eval_of_a_space_with_a_layout_gives_the_hybrid_error_on_its_sheet(tmp_path, capsys):
    """A chain of three gaits: the grid spans every blend of the sources, the space's hybrid is
    bounded where parameters lead, and eval says so (a docs-only user saw a 20 mm maximum for a 5
    mm epsilon, unexplained)."""
    from engine.motion_space import SourceClip, build_motion_space
    from engine.parameters import Layout
    from engine.synthetic import animate, build_body, gait

    body = build_body(1000)
    clips = [SourceClip(f"gait_{v}", animate(body, gait(body.skeleton, v, cycles=2.0, fps=15.0)), 15.0, True)
             for v in (0.8, 1.6, 2.8)]
    build_motion_space(tmp_path / "gaits.mspace", clips, body.F, name="gaits", epsilon=0.01, rest=body.V, n_phases=8,
                       parameters={"layout": Layout("chain", 3, chain=(0, 1, 2)), "names": ["speed"], "resolution": 5})
    out = tmp_path / "gaits-eval"
    assert main(["eval", str(tmp_path / "gaits.mspace"), "--out", str(out), "--sweep", "--epsilons-mm", "5", "20"]) == 0
    printed = capsys.readouterr().out
    assert "on the layout's sheet, where parameters lead (17 weight vectors), the hybrid is within" in printed
    # the sweep rebuilds the hybrid for the sheet, as build does (on the whole simplex it held 22 GB of
    # blends and ran for more than 15 minutes on the demo's 3-source reach space)
    assert "hybrid rebuilt per epsilon for the layout's sheet, as build builds it, errors over its 17" in printed
    results = json.loads((out / "results.json").read_text())
    for row in results["sweep"]["rows"]:
        assert row["on"] == "sheet" and row["weights"] == 17 and row["max_error_mm"] <= row["epsilon_mm"] + 0.01
    assert results["sweep"]["rows"][0]["corrected_area_percent"] > 0   # measured between sources
    errors = results["errors"]
    assert errors["sheet"]["weights"] == 17
    assert errors["sheet"]["hybrid"]["max_error_mm"] <= 1.01 * errors["epsilon_mm"]
    assert errors["sheet"]["linear"]["max_error_mm"] > errors["sheet"]["hybrid"]["max_error_mm"]
    # a run without --sweep into the same --out leaves no earlier sweep picture beside its results
    # (it stayed; a docs-only user)
    assert (out / "epsilon_sweep.png").is_file()
    assert main(["eval", str(tmp_path / "gaits.mspace"), "--out", str(out), "--timing-calls", "2"]) == 0
    assert "sweep" not in json.loads((out / "results.json").read_text())
    assert sorted(p.name for p in out.iterdir()) == ["heatmap.png", "results.json"]


def test_an_eval_that_fails_leaves_an_earlier_runs_files_in_its_out_as_they_were(dataset, tmp_path, capsys,
                                                                                 monkeypatch):
    """The run's pictures and results.json replace an earlier run's only once all are written (an
    interrupted eval left its heatmap beside the earlier results.json; found by a docs-only user)."""
    from engine import evaluation

    space, _ = dataset
    out = tmp_path / "ev"
    assert main(["eval", str(space), "--out", str(out), "--timing-calls", "5"]) == 0
    capsys.readouterr()
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    (out / "notes.txt").write_text("mine")

    def fail(*args, **kwargs):
        raise KeyboardInterrupt()

    monkeypatch.setattr(evaluation, "epsilon_sweep", fail)
    assert main(["eval", str(space), "--out", str(out), "--timing-calls", "5", "--weights", "0.3", "0.7",
                 "--sweep"]) == 130
    after = {p.name: p.read_bytes() for p in out.iterdir() if p.name != "notes.txt"}
    assert after == before and (out / "notes.txt").read_text() == "mine"
