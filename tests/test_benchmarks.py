"""Every script under benchmarks/ runs in its ``--tiny`` mode and reports sane figures.

Each script is run as a real subprocess (``python benchmarks/X.py --tiny --out TMP/result.json``)
from an empty working directory. The scripts are found by globbing, so a new benchmark fails here
until it has a tiny mode and an entry in ``CHECKS`` saying which figures it must report
(``benchmarks/_*.py`` are modules the scripts share, not benchmarks). A few seconds each; the
stream benchmark starts a real server on 127.0.0.1 and stops it itself.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py") if not p.name.startswith("_"))


def positive(x):
    return isinstance(x, (int, float)) and math.isfinite(x) and x > 0


def non_negative(x):
    return isinstance(x, (int, float)) and math.isfinite(x) and x >= 0


def check_blend_scaling(rows, stdout):
    (row,) = rows
    assert row["vertices"] == 1000 and row["tets"] > 0 and row["phases"] > 0
    assert positive(row["build_s"]["total_s"])
    assert row["threads"] == 1 and non_negative(row["load_average"])
    for mode, calls in (("linear", 200), ("hybrid", 200), ("nonlinear", 10)):
        figures = row["modes"][mode]
        assert figures["calls"] == calls
        assert all(positive(figures[k]) for k in ("frames_per_second", "cpu_frames_per_second", "median_us",
                                                  "p95_us")), (mode, figures)
        player = row["player"][mode]
        assert player["settled"]["steps"] == (100 if mode != "nonlinear" else 30) and player["steered"]["steps"] >= 30
        assert positive(player["settled"]["frames_per_second"]) and positive(player["steered"]["frames_per_second"])
    hybrid = row["hybrid"]
    assert hybrid["references"] >= 1 and non_negative(hybrid["max_test_error_mm"])
    assert hybrid["dense_weights"] == 9 and 0 < hybrid["dense_max_error_mm"] <= 5.1  # the bound, between tests too
    assert non_negative(hybrid["correction_share_of_sources"]) and hybrid["correction_share_of_sources"] < 1
    assert positive(hybrid["source_mb"])
    assert "1000 vertices" in stdout and "nonlinear" in stdout and "corrections" in stdout and "one core" in stdout and "dense sampling" in stdout


def check_graph_search(result, stdout):
    assert result["graph"] == "tiny" and result["vertices"] == 1000 and result["search_ms"]["count"] == 500
    assert positive(result["search_ms"]["median"]) and result["search_ms"]["p99"] >= result["search_ms"]["median"]
    assert positive(result["search_cpu_ms"]["p99"]) and result["search_cpu_ms"]["max"] >= result["search_cpu_ms"]["p99"]
    assert set(result["strategies"]) == {"search", "cut", "crossfade"}
    for figures in result["strategies"].values():
        assert figures["transitions"] >= 3 and positive(figures["smoothness_p95"])
        assert non_negative(figures["foot_slide_p95_cm"]) and non_negative(figures["latency_p50_s"])
    assert "search median" in stdout and "CPU time median" in stdout and "crossfade" in stdout
    performance = result["performance"]  # against the true continuous performance generated for the tiny body
    assert set(performance["strategies"]) == {"search", "cut", "crossfade"} and performance["true_frames"] > 200
    for figures in performance["strategies"].values():
        assert figures["frames"] == performance["true_frames"] and non_negative(figures["end_offset_m"])
        for key in ("aligned", "slack", "pose_aligned", "pose_slack"):
            assert positive(figures[key]["p50_mm"]) and figures[key]["p95_mm"] >= figures[key]["p50_mm"]
        assert figures["slack"]["p50_mm"] <= figures["aligned"]["p50_mm"]
    assert "against the true performance" in stdout


def check_similarity_scaling(records, stdout):
    (record,) = records
    assert record["frames"] == 60 and record["vertices_mean"] == 1000 and record["workers"] == 1
    assert positive(record["histograms_s"]) and positive(record["similarity_total_s"])
    assert all(non_negative(record[k]) for k in ("matrix_s", "filter_s", "tree_s"))
    assert record["tree_depth"] >= 1 and record["components"] >= 1
    assert json.loads(stdout.strip().splitlines()[-1]) == record  # the printed line is the record


def check_speed_ground_truth(rows, stdout):
    (row,) = rows
    assert row["speed"] == 1.8
    assert len(row["weights"]) == 2 and sum(row["weights"]) == pytest.approx(1.0, abs=1e-3)
    for method in ("linear", "hybrid", "nonlinear"):
        errors = row[method]
        assert all(positive(errors[k]) for k in ("mean_mm", "max_mm", "edge_error_percent", "volume_error_percent"))
        assert errors["max_mm"] >= errors["mean_mm"]
    assert all(positive(row[k]) for k in ("ratio_mean", "ratio_edge", "ratio_volume"))
    assert "speed 1.80 m/s" in stdout and "linear/non-linear" in stdout


def check_stream_load(result, stdout):
    assert result["clients"] == 4 and result["connected"] == 4 and result["failures"] == []
    assert 0.25 < result["delivered_mean"] < 1.5  # a 1.5 s window: a frame more or less is a few percent
    assert positive(result["frames_per_second_total"])
    assert result["latency_ms"]["count"] > 0 and positive(result["latency_ms"]["median"])
    assert non_negative(result["server_cpu_cores"]) and positive(result["server_rss_mb"]["start"])
    assert non_negative(result["server_cpu_us_per_frame"]) and "server CPU per delivered frame" in stdout
    assert 0 <= result["server_system_us_per_frame"] <= result["server_cpu_us_per_frame"] and "in the kernel" in stdout
    assert result["heatmap_clients"] == 1 and result["delivered_heatmap_min"] > 0.25 and "heatmap on" in stdout
    assert result["server_counters"]["frames"] > 0
    assert "frames delivered: mean" in stdout and "params -> first frame" in stdout
    assert result["workers"] == 1 and non_negative(result["clients_cpu_cores"])
    comparison = result["workers_comparison"]  # 1 and 2 workers side by side, 4 clients each
    assert comparison["workers"] == [1, 2] and comparison["levels"] == [4]
    assert {row["workers"] for row in comparison["table"]} == {1, 2}
    for row in comparison["table"]:
        assert row["clients"] == 4 and positive(row["delivered_mean"]) and non_negative(row["clients_cpu_cores"])
    for workers in ("1", "2"):
        assert comparison["capacity"][workers] in (0, 4)
        (record, *_) = comparison["rounds"][workers]
        assert record["connected"] == 4 and record["failures"] == [] and record["server_counters"]["frames"] > 0
        assert 0 < record["server_memory_mb"]["pss_sum"] <= record["server_memory_mb"]["rss_sum"]
    assert "workers side by side" in stdout
    assert "TARGET server CPU per delivered frame <= 40 us at 200 clients" in stdout  # issue 13's targets, explicit
    assert "TARGET 50 of 200 clients with the heatmap on" in stdout and "not the target load" in stdout
    offline = result["offline"]  # the scheduler's work alone, sockets replaced by a counter
    (record,) = offline["rounds"]["this tree"]
    assert record["clients"] == 4 and record["steering"] == 4 and record["frames"] == 4 * 240
    assert record["batched_frames"] > 0 and positive(offline["us_per_frame_median"]["this tree"])
    assert "offline CPU per frame" in stdout
    (record,) = result["offline_grid"]["rounds"]["this tree"]  # the online ticks: hellos spread over a period
    assert record["clients"] == 4 and record["frames"] >= 4 * 235 and record["ticks"] > 0
    assert record["frames"] / record["ticks"] > 3  # one grid: the four served in the same ticks


def check_stream_stall(result, stdout):
    assert result["stalls"] == [0.5, 1.0] and len(result["records"]) == 8
    for stall in ("0.5", "1.0"):
        summary = result["by_stall"][stall]
        assert summary["clients"] == 4 and summary["recovered"] == 4 and summary["closed"] == 0
        assert positive(summary["first_fresh_ms_median"]) and summary["first_fresh_ms_max"] >= summary["first_fresh_ms_median"]
    assert 0 < result["transport_bytes_max"] <= 256 * 1024
    assert non_negative(result["kernel_send_queue_max"])
    assert "first fresh frame after reading resumes" in stdout and "bytes held for one connection" in stdout


def check_tetrahedra(rows, stdout):
    (row,) = rows
    assert row["surface_vertices"] >= 900 and row["runs"] == 2 and row["identical"] is True
    assert positive(row["median_s"]) and row["tets"] >= 6 and row["tet_vertices"] >= 8
    assert "identical bytes" in stdout


def check_open_blends(result, stdout):
    (pair,) = result["pairs"]
    assert pair["sequence"] == "walk" and pair["holes"] >= 1 and pair["faces_dropped"] > 0
    assert all(positive(v) for v in pair["input_volumes_l"])
    assert abs(pair["nonlinear_change_percent"]) <= result["target_percent"]          # the target
    assert abs(pair["linear_change_percent"]) > abs(pair["nonlinear_change_percent"])  # what it is for
    assert result["summary"]["nonlinear"]["pairs"] == 1
    assert "non-linear: |capped volume change| median" in stdout


def check_export(record, stdout):
    assert record["vertices"] == 1000 and record["frames"] == 61 and record["fps"] == 30
    assert positive(record["play_s"]) and non_negative(record["load_average"])
    formats = record["formats"]
    assert set(formats) == {"glb int16", "glb float32", "usd", "ply sequence", "vat"}
    for row in formats.values():
        assert positive(row["write_s"]) and row["total_s"] >= row["write_s"] and row["bytes"] > 0
    assert formats["glb int16"]["bytes"] < formats["glb float32"]["bytes"]  # 8 instead of 12 bytes a vertex
    assert 0 < formats["glb int16"]["max_error_mm"] < 0.05 and formats["glb float32"]["max_error_mm"] == 0
    assert set(record["met"]) == {"glb_seconds", "glb_megabytes", "usd_seconds"}
    assert "glb int16" in stdout and "targets: glTF <= 5 s" in stdout


def check_align_speed(record, stdout):
    assert record["dataset"] == "tiny" and record["frames"] == 6 and 900 < record["vertices_mean"] < 1100
    assert record["every"] == 1
    assert positive(record["cpu_seconds_per_frame"]) and positive(record["aligner_cpu_seconds_per_frame"])
    assert record["aligner_cpu_seconds_per_frame"] <= record["cpu_seconds_per_frame"]
    assert {"similarity", "tree", "align", "repair"} <= set(record["stages_wall_s"])
    assert 0 < record["mean_pct"] <= record["p95_pct"] < 100 and 0 < record["worst_frame_pct"] < 100
    assert record["target_met"] is None and non_negative(record["load_average_before"][0])
    assert "CPU s per frame all in" in stdout
    assert "TARGET alignment <= 3 CPU s/frame at 10k: not judged (1,0" in stdout


def check_align_breakdown(record, stdout):
    assert record["dataset"] == "tiny" and record["frames"] == 6 and record["every"] == 2 and record["method"] == "tree"
    assert record["options"]["patches"] == 8 and positive(record["cpu_seconds_per_frame"])
    assert 0 < record["mean_pct"] <= record["p95_pct"] < 100
    (part,) = record["per_part"].values()  # no studio parts: one, all of the vertices and all of the tail
    assert part["share_of_vertices"] == 1.0 and part["share_of_tail"] == 1.0 and part["p95_without_pct"] is None
    assert sum(row["frames"] for row in record["per_depth"]) == 5 and len(record["worst_frames"]) == 5
    for calibration in record["confidence"].values():
        assert calibration["flagged_bad"] <= min(calibration["flagged"], calibration["bad"])
    assert "of the tail" in stdout and "flag vs frames over 3pct" in stdout and non_negative(record["load_average_before"][0])


def check_repair_variants(record, stdout):
    assert record["dataset"] == "tiny" and record["frames"] == 8 and record["workers"] == 1
    rows = {row["variant"]: row for row in record["variants"]}
    assert list(rows) == ["none", "together@0.5", "root_first@0.25", "root_first@0.25:0", "root_first@0"]
    assert record["sequences"] == ["run"]
    assert rows["root_first@0.25:0"]["min_yield"] == 0 and rows["root_first@0.25"]["min_yield"] > 0
    for row in rows.values():
        assert set(row["stopped"]) <= {"root", "others"}
        assert 0 < row["mean_pct"] <= row["p95_pct"] < 100 and non_negative(row["seconds"])
        assert row["frames_over_3pct_flagged"] <= row["frames_over_3pct"] and row["repaired"] <= row["flagged"] + row["repaired"]
        assert row["alignments"] <= int(row["budget"] * record["frames"])  # the budget holds
    # no budget, no repair: the same alignment as without the repair, scored alike
    for label in ("none", "root_first@0"):
        assert rows[label]["repaired"] == 0 and rows[label]["alignments"] == 0
    assert rows["root_first@0"]["mean_pct"] == rows["none"]["mean_pct"]
    assert "aligned once" in stdout and "root_first@0.25" in stdout


def check_root_trial(record, stdout):
    assert record["dataset"] == "tiny" and record["frames"] == 8 and record["candidates"] == [0, 4]
    assert len(record["probes"]) == 2 and not set(record["probes"]) & {0, 4}
    assert record["trial_choice"] in (0, 4) and 0 <= record["spread_choice"] < 8 and positive(record["trial_cpu_seconds"])
    badness = [row["badness_mean"] for row in record["rows"]]
    assert all(non_negative(b) for b in badness)
    assert record["rows"][badness.index(min(badness))]["frame"] == record["trial_choice"]
    for row in record["rows"]:
        assert 0 < row["true_mean_pct"] <= row["true_p95_pct"] < 100
    assert record["rank_correlation"] in (-1.0, 1.0) and record["truth_choice"] in (0, 4)
    assert "candidates x 2 probes" in stdout and "rank correlation of badness and true error" in stdout
    # the race: the trial's two best, the more confident whole alignment
    assert sorted(record["finalists"]) == [0, 4] and record["finalists"][0] == record["trial_choice"]
    confidence = {row["frame"]: row["confidence_mean"] for row in record["rows"]}
    assert all(0 <= c <= 1 for c in confidence.values())
    assert record["race_choice"] == max(record["finalists"], key=confidence.get)
    assert record["confidence_rank_correlation"] in (-1.0, 1.0)
    assert "the race between [" in stdout and "confidence and true error" in stdout


def check_align_momentum(record, stdout):
    assert record["dataset"] == "tiny" and record["root"] == 2 and record["frames"] == 4
    assert [run["momentum"] for run in record["runs"]] == [0.0, 0.5, 1.0]
    for run in record["runs"]:
        assert len(run["errors_pct"]) == 4 and all(0 < e < 100 for e in run["errors_pct"])
        assert run["mean_pct"] == pytest.approx(sum(run["errors_pct"]) / 4, abs=2e-3)
        assert positive(run["cpu_seconds_per_frame"])
    # the first frame has no last step to follow: every momentum starts it the same way
    assert len({run["errors_pct"][0] for run in record["runs"]}) == 1
    assert "momentum 0.5: mean" in stdout and non_negative(record["load_average"])


def check_align_steps(record, stdout):
    assert record["dataset"] == "tiny" and [row["pair"] for row in record["pairs"]] == [[0, 1], [3, 2]]
    for row in record["pairs"]:
        assert 0 < row["mean_pct"] < 100 and set(row["parts_pct"]) == {"all"}
        assert row["parts_pct"]["all"] == pytest.approx(row["mean_pct"], abs=2e-3)
        # aligning moves the true rigid placement closer to the truth, not further; the true pose
        # (the solid pulled onto the truth) is closer still, and the fit from it stays near it
        assert 0 < row["oracle_rigid_pct"] < row["placement_alone_pct"]
        assert 0 <= row["true_pose_pct"] < row["placement_alone_pct"] and 0 < row["oracle_pose_pct"] < 100
        # the 3 worst skeleton segments, worst first; each segment's mean bounds the pair's from above
        # at least once (the worst is no better than the mean over all vertices)
        worst = list(row["worst_segments_pct"].values())
        assert len(worst) == 3 and worst == sorted(worst, reverse=True) and worst[0] >= row["mean_pct"] - 2e-3
        assert all(name in stdout for name in row["worst_segments_pct"])
        # the elbows and wrists pulled onto their true places are closer to them than aligned, and
        # the fit from there is scored like every other figure
        pull = row["oracle_pull"]
        assert row["oracle_pull_vertices"] > 0 and 0 <= pull["pulled_parts_pct"] < pull["as_aligned_parts_pct"]
        assert 0 < pull["pulled_fit_pct"] < 100 and 0 < pull["as_aligned_pct"] < 100
    assert "worst segments" in stdout and record["oracle_pull_parts"] == ["elbow", "wrist"]
    assert "elbow/wrist pulled onto the truth, then the fit" in stdout
    assert record["mean_pct"] == pytest.approx(sum(r["mean_pct"] for r in record["pairs"]) / 2, abs=2e-3)
    assert positive(record["cpu_seconds"]) and "2 single steps: mean" in stdout and "true rigid placement" in stdout
    assert 0 < record["oracle_pose_mean_pct"] < 100 and "from the true pose" in stdout


def check_dask_align(records, stdout):
    (record,) = records
    assert record["frames"] == 4 and record["equal"] is True and record["local_equal"] is True
    assert [row["workers"] for row in record["clusters"]] == [1, 2]
    for row in record["clusters"]:
        assert positive(row["median_s"]) and row["tasks"] >= 3 and row["repeats_equal"]
        assert {"similarity", "align", "repair", "pieces", "critical_path_frames"} <= set(row["stages_s"])
    assert positive(record["speedup"]) and non_negative(record["load_average"])
    assert "speedup 2 vs 1 workers" in stdout and "target run: " in stdout and "results equal" in stdout
    assert "TARGET the demo's 973 frames >= 1.7x faster on 2 workers" in stdout and "not the target run" in stdout


def check_graph_load(result, stdout):
    assert result["graph"] == "tiny" and result["clients"] == 8 and result["seconds"] == 3.0
    (record,) = result["rounds"]["this tree"]
    assert record["frames"] == 8 * 180 and record["acting"] == 2 and record["errors"] == 0
    assert record["actions"] >= 2 and positive(record["us_per_frame"]) and non_negative(record["action_us_per_frame"])
    assert positive(result["us_per_frame_median"]["this tree"]) and result["same_frames"]
    assert len(result["digests"]["this tree"]) == 32 and "us per frame" in stdout


def check_godot_client(result, stdout):
    assert result["vertices"] == 1000 and result["seconds"] == 2.0 and result["engine_fps_target"] == 60
    assert set(result["runs"]) == {"stream-f32", "stream-q16", "engine-f32"}
    for key, row in result["runs"].items():
        assert row["frames"] == 120 and positive(row["frames_per_second"]) and positive(row["engine_fps"]), key
        assert non_negative(row["received_per_second"]) and row["superseded"] >= 0 and row["server_dropped"] >= 0
        for figure in ("decode_us", "update_us", "decode_update_us"):
            assert 0 < row[figure]["median"] <= row[figure]["p95"] <= row[figure]["max"], (key, figure)
        assert f"{key}: 1000 vertices, decode median" in stdout


def check_stream_socket(result, stdout):
    assert result["clients"] == 8 and result["bytes"] == 18000 and result["frames"] + result["skipped"] > 0
    assert result["frames"] > 0 and positive(result["cpu_us_per_frame"])
    assert non_negative(result["user_us_per_frame"]) and non_negative(result["system_us_per_frame"])
    assert "us of the writer's CPU a frame" in stdout


def check_hybrid_sheet(rows, stdout):
    (row,) = rows
    assert row["layout"] == "grid" and row["sources"] == 4 and row["vertices"] == 1000 and row["phases"] == 8
    assert row["per_axis"] == 17 and row["weights"] == 17 * 17
    build = row["build"]
    assert build["check_points"] == 9 * 9 - 5 * 5 and non_negative(build["max_check_error_mm"])
    assert build["max_check_error_mm"] <= row["epsilon_mm"] and build["max_test_error_mm"] <= 0.9 * row["epsilon_mm"] + 1e-3
    # the sampled weights the build tested and those it checked agree with what it recorded
    assert abs(row["max_error_test_weights_mm"] - build["max_test_error_mm"]) < 0.05
    assert 0 < row["max_error_between_mm"] and row["max_error_mm"] == max(row["max_error_test_weights_mm"],
                                                                        row["max_error_between_mm"])
    assert row["weights_over_epsilon"] == 0 and positive(row["seconds"]) and positive(row["cpu_seconds"])
    assert '"max_error_between_mm"' in stdout  # the figures are printed as well as written


CHECKS = {
    "align_breakdown.py": check_align_breakdown,
    "align_momentum.py": check_align_momentum,
    "align_steps.py": check_align_steps,
    "align_speed.py": check_align_speed,
    "blend_scaling.py": check_blend_scaling,
    "dask_align.py": check_dask_align,
    "export.py": check_export,
    "godot_client.py": check_godot_client,
    "graph_load.py": check_graph_load,
    "graph_search.py": check_graph_search,
    "hybrid_sheet.py": check_hybrid_sheet,
    "open_blends.py": check_open_blends,
    "repair_variants.py": check_repair_variants,
    "root_trial.py": check_root_trial,
    "similarity_scaling.py": check_similarity_scaling,
    "speed_ground_truth.py": check_speed_ground_truth,
    "stream_load.py": check_stream_load,
    "stream_socket.py": check_stream_socket,
    "stream_stall.py": check_stream_stall,
    "tetrahedra.py": check_tetrahedra,
}


def recorded_results():
    """(name, size, mtime) of every file in benchmarks/results/: a tiny run must leave them alone."""
    return sorted((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in (BENCHMARKS / "results").glob("*"))


def test_scripts_are_found():
    assert {"blend_scaling.py", "stream_load.py"} <= set(SCRIPTS)


@pytest.mark.parametrize("script", SCRIPTS)
def test_benchmark_tiny_mode(script, tmp_path):
    assert script in CHECKS, (f"benchmarks/{script} is not checked: give it a --tiny mode (smallest sizes, a few "
                              f"seconds, JSON to --out) and add the figures it must report to CHECKS")
    out, cwd = tmp_path / "result.json", tmp_path / "cwd"
    cwd.mkdir()
    before = recorded_results()
    run = subprocess.run([sys.executable, str(BENCHMARKS / script), "--tiny", "--out", str(out)], cwd=cwd,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, f"benchmarks/{script} --tiny failed:\n{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
    CHECKS[script](json.loads(out.read_text()), run.stdout)
    assert recorded_results() == before
    assert not list(cwd.iterdir()), "a tiny run wrote into its working directory"


@pytest.mark.parametrize("script", [s for s in SCRIPTS if s in CHECKS])
def test_tiny_mode_needs_out(script, tmp_path):
    run = subprocess.run([sys.executable, str(BENCHMARKS / script), "--tiny"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "--tiny needs --out" in run.stderr
    assert list(tmp_path.iterdir()) == []


def test_stream_load_streams_a_motion_graph_with_acting_clients(tmp_path):
    """``stream_load.py --tiny --graph tiny``: the tiny graph (walk, stand, jump, reach) built for the
    run; 2 of 4 clients send actions every 0.5-1.5 s; frames delivered for the acting and the passive
    clients apart, the actions' notices and the transitions the frames show."""
    out, cwd = tmp_path / "result.json", tmp_path / "cwd"
    cwd.mkdir()
    before = recorded_results()
    run = subprocess.run([sys.executable, str(BENCHMARKS / "stream_load.py"), "--tiny", "--graph", "tiny", "--out",
                          str(out)], cwd=cwd, capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, f"stream_load.py --graph failed:\n{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
    result = json.loads(out.read_text())
    assert result["graph"] == "tiny" and result["clients"] == 4 and result["acting_clients"] == 2
    assert result["connected"] == 4 and result["failures"] == [] and "workers_comparison" not in result
    figures = result["graph_round"]
    assert figures["acting"]["clients"] == 2 and figures["passive"]["clients"] == 2
    for group in ("acting", "passive"):
        assert 0.25 < figures[group]["delivered_min"] <= figures[group]["delivered_mean"] < 1.5
    assert figures["actions"] >= 4 and figures["error_count"] == 0 and figures["errors"] == []
    assert set(figures["notices"]) <= {"planned", "queued", "superseded"}
    answered = figures["notices"].get("planned", 0) + figures["notices"].get("queued", 0)
    assert 0 < answered <= 2 * figures["actions"]  # each planned or queued, a queued one planned later
    assert figures["notices"].get("superseded", 0) < figures["actions"]
    assert figures["transitions"] >= 1 and 1 <= figures["actions_entered"] <= figures["actions"]
    assert positive(figures["action_to_entered_s"]["median"])
    assert 0 < result["latency_ms"]["count"] <= figures["actions"] and positive(result["latency_ms"]["median"])
    assert "acting clients (2)" in run.stdout and "transitions carried out" in run.stdout
    assert recorded_results() == before and not list(cwd.iterdir())


def test_stream_load_compares_a_baseline_tree_side_by_side(tmp_path):
    """``stream_load.py --baseline DIR``: a server from DIR (here this same tree) and this tree's take
    alternating rounds under the same load; the record has both, their medians and the ratio."""
    out, cwd = tmp_path / "result.json", tmp_path / "cwd"
    cwd.mkdir()
    run = subprocess.run([sys.executable, str(BENCHMARKS / "stream_load.py"), "--tiny", "--out", str(out),
                          "--baseline", str(BENCHMARKS.parent), "--repeat", "2", "--heatmap-clients", "0"],
                         cwd=cwd, capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, f"stream_load.py --baseline failed:\n{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
    comparison = json.loads(out.read_text())["baseline_comparison"]
    assert set(comparison["summary"]) == {"baseline", "this tree"} and comparison["repeat"] == 2
    for label, summary in comparison["summary"].items():
        assert len(comparison["rounds"][label]) == 2 and all(r["connected"] == 4 for r in comparison["rounds"][label])
        assert positive(summary["server_cpu_us_per_frame_median"]) and positive(summary["delivered_mean_median"])
        assert 0 <= summary["server_system_us_per_frame_median"] <= summary["server_cpu_us_per_frame_median"]
    assert positive(comparison["ratio_cpu_per_frame"]) and "this tree / baseline" in run.stdout
    assert not list(cwd.iterdir())


def test_export_measures_a_graph_performance(tmp_path):
    """``export.py --tiny --graph tiny``: the tiny graph built for the run, a scripted performance
    (walk, then a jump) replayed and written as glTF and USD, timed and sized."""
    out, cwd = tmp_path / "result.json", tmp_path / "cwd"
    cwd.mkdir()
    before = recorded_results()
    run = subprocess.run([sys.executable, str(BENCHMARKS / "export.py"), "--tiny", "--graph", "tiny", "--out", str(out)],
                         cwd=cwd, capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, f"export.py --graph failed:\n{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
    record = json.loads(out.read_text())
    assert record["graph"] == "tiny" and record["vertices"] == 1000 and record["frames"] == 61
    assert record["visited"][:2] == ["walk", "jump"] and record["requests"][0]["node"] == "jump"
    assert set(record["formats"]) == {"glb int16", "glb float32", "usd"} and positive(record["play_s"])
    for row in record["formats"].values():
        assert positive(row["write_s"]) and row["total_s"] >= row["write_s"] and row["bytes"] > 0
    assert set(record["met"]) == {"glb_seconds", "glb_megabytes", "usd_seconds"}
    assert "graph tiny: 61 frames" in run.stdout
    assert recorded_results() == before and not list(cwd.iterdir())


def test_align_speed_measures_a_denser_capture(tmp_path):
    """``align_speed.py --tiny --subdivide 1 --every 2``: every other frame of the tiny run, every
    triangle split in four (about 4,000 vertices), aligned and scored against the same truth."""
    out = tmp_path / "align_speed.json"
    run = subprocess.run([sys.executable, str(BENCHMARKS / "align_speed.py"), "--tiny", "--subdivide", "1",
                          "--every", "2", "--out", str(out)], cwd=tmp_path, capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr[-4000:]
    record = json.loads(out.read_text())
    assert record["subdivide"] == 1 and 3600 < record["vertices_mean"] < 4400
    assert record["every"] == 2 and record["frames"] == 6 and "every 2" in run.stdout
    assert 0 < record["mean_pct"] <= record["p95_pct"] < 100 and record["target_met"] is None
    assert "not judged (4," in run.stdout
