"""Motion graphs from the command line (build-graph, play GRAPH.mgraph) and as a REST job.

The graph joins the test spaces: the speed chain (cyclic) and the jump distance chain (one-shot)."""

from __future__ import annotations

import json
import time

import httpx
import pytest
from cli_refused import refused
from live_server import LiveServer

from engine.graph import MotionGraph
from server.cli import main

TOKEN = "test-token-graph"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
SPEC = """
name = "gaits"
spaces = "{spaces}"
edges = [["run", "leap"], ["leap", "run"]]

[window]
phases = 12
per_axis = 3

[[nodes]]
name = "run"
space = "speed.mspace"

[[nodes]]
name = "leap"
space = "jump.mspace"
"""


@pytest.fixture(scope="module")
def graph_file(built_spaces, tmp_path_factory):
    directory = tmp_path_factory.mktemp("graph-cli")
    (directory / "graph.toml").write_text(SPEC.format(spaces=built_spaces))
    out = directory / "gaits.mgraph"
    assert main(["build-graph", str(directory / "graph.toml"), "--out", str(out)]) == 0
    return out


def test_build_graph_writes_a_graph_file(graph_file, capsys):
    with MotionGraph.open(graph_file) as graph:
        assert [n.name for n in graph.nodes] == ["run", "leap"] and graph.node("leap").meta["return_to"] == "run"
        assert graph.edges[("run", "leap")].shape == (3, 12, 3, 12)
    assert main(["build-graph", str(graph_file.parent / "graph.toml"), "--out", str(graph_file)]) == 2
    assert "already exists" in capsys.readouterr().err


def test_spaces_facing_heading_0_apart_are_warned_of(built_spaces):
    """Spaces built from a captured rest take heading 0 from where their sources travel
    (``heading_turn_deg``); one that travels and one that does not then differ, and a transition
    turns the body by it. The generator's spaces (0 each) and differences of 1 degree pass."""
    from server.commands.build_graph import _heading_turn, heading_turn_note

    assert _heading_turn(built_spaces / "speed.mspace") == _heading_turn(built_spaces / "jump.mspace") == 0.0
    assert heading_turn_note({"run": 0.0, "leap": 0.0}) is None and heading_turn_note({"a": 5.2, "b": 4.4}) is None
    note = heading_turn_note({"walk": 5.65, "reach": 0.0})
    assert note == ("the nodes' spaces face heading 0 up to 5.7 degrees apart (heading_turn_deg: walk +5.7, "
                    "reach +0.0); a transition between two of them turns the body by their difference"), note


@pytest.mark.parametrize("change,message", [
    (lambda s: s.replace('space = "jump.mspace"', 'space = "nope.mspace"'), "nope.mspace does not exist"),
    (lambda s: s.replace('["leap", "run"]', '["leap", "walk"]'), "both ends must be nodes"),
    (lambda s: s.replace("per_axis = 3", "per_axis = 0"), "window"),
    (lambda s: s.replace("[[nodes]]", "[[nodes]]\ncolour = 1", 1), "unknown key"),
    # found by a docs-only user: each failed only later, or named neither the spec nor the node
    (lambda s: s.replace('name = "leap"', 'name = "le ap/x"').replace('"leap"', '"le ap/x"'),
     "node name 'le ap/x': use letters, digits"),
    (lambda s: s + '\n[[nodes]]\nname = "idle"\nspace = "speed.mspace"\n',
     "node 'idle' cannot be reached from 'run' along the edges; every node must be reachable from every other"),
    (lambda s: s.replace('space = "jump.mspace"', 'space = "{spec}"'), "node 'leap': its space cannot be opened: "),
])
def test_bad_specs_name_the_problem(built_spaces, tmp_path, capsys, change, message):
    (tmp_path / "g.toml").write_text(change(SPEC.format(spaces=built_spaces)).replace("{spec}", str(tmp_path / "g.toml")))
    assert main(["build-graph", str(tmp_path / "g.toml"), "--out", str(tmp_path / "g.mgraph")]) == 2
    err = capsys.readouterr().err
    assert message in err and f"{tmp_path / 'g.toml'}: " in err, err
    assert not (tmp_path / "g.mgraph").exists()


def _wait(client, job_id, timeout=120.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["status"] in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not finish in {timeout} s: {job}")


def test_graph_job_over_rest(built_spaces, tmp_path_factory):
    from live_server import data_dir_with_spaces

    data = data_dir_with_spaces(tmp_path_factory.mktemp("graph-data"), built_spaces)
    request = {"kind": "graph", "graph": "gaits", "nodes": [{"name": "run", "space": "speed"},
                                                            {"name": "leap", "space": "jump", "return_to": "run"}],
               "edges": [["run", "leap"], ["leap", "run"]], "window": {"phases": 12, "per_axis": 3}}
    with LiveServer(data, env={"MORPHSPACE_TOKEN": TOKEN}) as live, httpx.Client(base_url=live.url, timeout=30) as client:
        bad = client.post("/v1/jobs", headers=AUTH, json={**request, "edges": [["run", "fly"]]})
        assert bad.status_code == 422 and "both ends must be nodes" in bad.text
        missing = client.post("/v1/jobs", headers=AUTH, json={**request, "nodes": [
            {"name": "run", "space": "speed"}, {"name": "leap", "space": "hop"}]})
        assert missing.status_code == 404 and "hop" in missing.json()["detail"]
        r = client.post("/v1/jobs", headers=AUTH, json=request)
        assert r.status_code == 202, r.text
        job = _wait(client, r.json()["id"])
        assert job["status"] == "succeeded", job
        assert job["kind"] == "graph" and job["result"]["nodes"] == ["run", "leap"]
        assert job["result"]["url"] == "/v1/graphs/gaits"
        described = client.get("/v1/graphs/gaits").json()  # served at once, beside its spaces
        assert [n["name"] for n in described["nodes"]] == ["run", "leap"] and described["start"] == "run"
        assert described["edges"] == [{"from": "run", "to": "leap"}, {"from": "leap", "to": "run"}]
        assert [e["from"] for e in job["result"]["edges"]] == ["run", "leap"]
        assert client.get("/v1/jobs", params={"kind": "graph"}).json()["jobs"][0]["id"] == job["id"]
        again = client.post("/v1/jobs", headers=AUTH, json=request)
        assert again.status_code == 409 and "already exists" in again.json()["detail"]
    with MotionGraph.open(data / "spaces" / "gaits.mgraph") as graph:  # its spaces found beside it
        assert graph.node("run").meta["space"] == "speed.mspace"


def test_play_a_graph_record_and_replay_byte_for_byte(graph_file, tmp_path, capsys):
    record = tmp_path / "session.json"
    status = main(["play", str(graph_file), "--set", "speed=1.2", "--at", "1", "leap", "jump_distance=0.8",
                   "budget=0.5", "--seconds", "5", "--fps", "20", "--frames", str(tmp_path / "frames"),
                   "--record", str(record), "--json", "--mode", "linear"])
    assert status == 0
    report = json.loads(capsys.readouterr().out)
    events = [e["event"] for e in report["events"]]
    assert events == ["leave run -> leap", "enter leap", "leave leap -> run", "enter run"]
    assert report["requests"][0]["status"] == "planned" and report["requests"][0]["latency"] <= 0.5 + 1e-9
    assert len(list((tmp_path / "frames").glob("frame_*.obj"))) == report["frames"] == 101
    saved = json.loads(record.read_text())
    assert saved["requests"] == [{"frame": 20, "node": "leap", "params": {"jump_distance": 0.8}, "budget": 0.5}]
    assert saved["frames_sha256"] == report["frames_sha256"] and saved["mode"] == "linear"
    assert main(["play", str(graph_file), "--replay", str(record)]) == 0  # a new player, the same frames
    assert "identical frames" in capsys.readouterr().out
    saved["requests"][0]["frame"] = 21  # a different performance is told apart
    record.write_text(json.dumps(saved))
    assert main(["play", str(graph_file), "--replay", str(record)]) == 1
    assert "DIFFERENT frames" in capsys.readouterr().out


def test_play_replays_a_browser_recording_on_its_own_clock(graph_file, tmp_path, capsys):
    """A browser recording (the stream's frame times, a parameter change, no digest): --replay steps
    by its times, as the exports do, and says there is no digest to compare instead of failing."""
    from engine.export.performance import play_performance

    record = tmp_path / "session.json"
    assert main(["play", str(graph_file), "--set", "speed=1.2", "--at", "1", "leap", "jump_distance=0.8",
                 "--seconds", "3", "--fps", "20", "--record", str(record)]) == 0
    capsys.readouterr()
    document = json.loads(record.read_text())
    steps = document["steps"]
    document["times"] = [round(k * 0.05 + (0.004 if k % 3 == 1 else 0.0), 4) for k in range(steps + 1)]
    document["requests"].insert(0, {"frame": 5, "node": "run", "params": {"speed": 1.5}, "set": True})
    document.update(frames_sha256=None, source="browser")
    record.write_text(json.dumps(document))
    assert main(["play", str(graph_file), "--replay", str(record), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["identical"] is None and report["frames"] == steps + 1
    with MotionGraph.open(graph_file) as graph:
        _, exported = play_performance(graph, document)  # what morphspace export makes of it
        _, evenly = play_performance(graph, dict(document, times=None))
    assert report["frames_sha256"] == exported != evenly
    assert main(["play", str(graph_file), "--replay", str(record)]) == 0
    assert "no frames digest recorded (a browser recording, or one written without it), nothing to compare" in capsys.readouterr().out
    document["times"][5] = document["times"][4] - 0.01
    record.write_text(json.dumps(document))
    assert main(["play", str(graph_file), "--replay", str(record)]) == 2
    assert "times must not decrease (frame 5" in capsys.readouterr().err


@pytest.mark.parametrize("argv,message", [
    (["--at", "1", "fly"], "no node 'fly'"),
    (["--at", "1", "leap", "height=2"], "has no parameter 'height'"),
    (["--at", "soon", "leap"], "needs a time first"),
    (["--at", "1"], "needs a time and a node"),
])
def test_play_graph_errors_name_the_problem(graph_file, capsys, argv, message):
    assert main(["play", str(graph_file), *argv]) == 2
    assert message in capsys.readouterr().err


def test_graph_options_are_refused_for_a_space(built_spaces, tmp_path, capsys):
    assert main(["play", str(built_spaces / "speed.mspace"), "--record", str(tmp_path / "r.json")]) == 2
    assert "for motion graphs" in capsys.readouterr().err
    assert not (tmp_path / "r.json").exists()


def test_eval_graph_measures_the_search_and_the_baselines_on_the_same_requests(graph_file, capsys):
    assert main(["eval-graph", str(graph_file), "--requests", "4", "--seeds", "0,1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["graph"] == "gaits" and report["seeds"] == [0, 1] and report["requests_per_seed"] == 4
    assert set(report["strategies"]) == {"search", "cut", "crossfade"}
    for name, figures in report["strategies"].items():
        assert figures["transitions"] >= 2, name
        assert figures["root_ratio_max"] <= 1.0 + 1e-6, name  # the root moves as the blend says
        assert 0.0 <= figures["frames_held"] <= 1.0 and figures["leg_offset_max_cm"] >= figures["leg_offset_p95_cm"]
        assert 0.0 < figures["pop_p50"] <= figures["pop_p95"], name
        if figures["frames_held"] > 0:  # the legs carry a held foot keeping their lengths (3% stretch at most)
            assert figures["leg_segment_change_max_pct"] < 5.0, name
            assert figures["leg_edge_change_p95_pct"] <= figures["leg_edge_change_max_pct"], name
    # feet on the ground are held (this graph blends its walk straight into its stand, so a foot
    # may slide by what is beyond the leg's reach: the bound)
    assert report["strategies"]["search"]["foot_slide_p95_cm"] < 2.0
    assert report["strategies"]["search"]["searches"] >= 2 and report["strategies"]["cut"]["smoothness_p95"] > 0
    assert main(["eval-graph", str(graph_file), "--requests", "3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert main(["eval-graph", str(graph_file), "--requests", "3"]) == 0
    out = capsys.readouterr().out
    assert "search latency weight 0.5, candidates 5\n" in out
    header, *rows = out.splitlines()[1:5]
    assert header.split() == ["strategy", "n", "smooth", "p50", "p95", "pop", "p50", "p95", "latency", "p50", "p95",
                              "slide", "p50/p95", "cm", "root", "max", "seam", "p50", "mm", "held", "%", "leg",
                              "p95/max", "cm", "leg", "length", "p95/max", "%", "leg", "edge", "p95/max", "%"]
    for row, (name, s) in zip(rows, report["strategies"].items()):  # every figure of --json's record but the search's
        two = lambda a, b, spec=".1f": [format(s[a], spec), "/", format(s[b], spec)]  # noqa: E731
        assert row.split() == [name, str(s["transitions"])] + [format(s[key], ".2f") for key in (
            "smoothness_p50", "smoothness_p95", "pop_p50", "pop_p95", "latency_p50_s", "latency_p95_s")] + two(
            "foot_slide_p50_cm", "foot_slide_p95_cm", ".2f") + [
            format(s["root_ratio_max"], ".2f"), format(s["seam_p50_mm"], ".1f"), format(100 * s["frames_held"], ".0f")
        ] + two("leg_offset_p95_cm", "leg_offset_max_cm") + two("leg_segment_change_p95_pct",
                                                                "leg_segment_change_max_pct") + two(
            "leg_edge_change_p95_pct", "leg_edge_change_max_pct"), row
    assert "search time median" in out
    assert main(["eval-graph", str(graph_file), "--requests", "3", "--candidates", "-1"]) == 2
    assert "--candidates" in capsys.readouterr().err


@pytest.mark.parametrize("argv,message", [
    (["--seeds", "a,b"], "--seeds: expected integers"),
    (["--requests", "0"], "--requests must be at least 1, got 0"),
    (["--fps", "0"], "--fps must be a finite positive number of frames per second, got 0"),
    (["--seeds", "-1"], "--seeds: seeds are integers from 0, got '-1'"),
    (["--seeds", "0,0"], "--seeds: seed 0 is given twice"),
    (["--latency-weight", "-1"], "--latency-weight must be a number from 0 (cost per second of latency), got -1"),
    (["--candidates", "-1"], "--candidates must be an integer from 0 to 1000, got -1"),
])
def test_eval_graph_errors_name_the_problem(graph_file, capsys, argv, message):
    assert main(["eval-graph", str(graph_file), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "SearchOptions(" not in err, err


def test_eval_graph_refuses_a_file_that_is_not_a_graph(built_spaces, capsys):
    assert main(["eval-graph", str(built_spaces / "speed.mspace")]) == 2
    assert "not a" in capsys.readouterr().err


TINY_SPEC = """
name = "g"
spaces = "."
edges = [["a", "b"], ["b", "a"]]

[[nodes]]
name = "a"
space = "a.mspace"

[[nodes]]
name = "b"
space = "b.mspace"
"""


@pytest.fixture
def tiny_spec(tmp_path):
    """A graph spec over two stand-in space files: every check here runs before a space is opened."""
    for name in ("a", "b"):
        (tmp_path / f"{name}.mspace").write_bytes(b"not opened")
    (tmp_path / "g.toml").write_text(TINY_SPEC)
    return tmp_path / "g.toml"


def _graph_refused(capsys, argv, *expected):
    return refused(capsys, ["build-graph", *argv], *expected)


@pytest.mark.parametrize("change,message", [
    (lambda s: s.replace('spaces = "."', "spaces = 4"), "spaces must be a directory (a non-empty string), got 4"),
    (lambda s: s.replace('name = "g"', "name = 3"), "name must be a non-empty string"),
    (lambda s: s.replace('name = "g"', 'name = "g"\ncolour = 1'), "unknown key(s) colour; known: name, spaces"),
    (lambda s: s.replace("[[nodes]]", "[window]\nper_axis = 0\n\n[[nodes]]", 1),
     "[window] per_axis must be an integer from 1 to 21, got 0"),
    (lambda s: s.replace("[[nodes]]", '[window]\nwindow_step = "x"\n\n[[nodes]]', 1),
     "[window] window_step must be a number above 0 and at most 0.5, got 'x'"),
    (lambda s: s.replace("[[nodes]]", "[window]\nphases = 1000\n\n[[nodes]]", 1),
     "[window] phases must be an integer from 4 to 256, got 1000"),
    (lambda s: s.replace("[[nodes]]", "[window]\nvelocity_weight = nan\n\n[[nodes]]", 1),
     "[window] velocity_weight must be a number from 0 to 10, got nan"),
    (lambda s: s.replace('edges = [["a", "b"], ["b", "a"]]', 'edges = [["a", "b"], ["b", "a"]]\nwindow = 5'),
     "window must be a table ([window]), got 5"),
    (lambda s: s + "return_to = 5\n", "node 'b': return_to must be a node name, got 5"),
])
def test_bad_graph_spec_keys_are_named_with_their_range(tiny_spec, capsys, change, message):
    tiny_spec.write_text(change(TINY_SPEC))
    err = _graph_refused(capsys, [tiny_spec, "--out", tiny_spec.with_name("o.mgraph")], message)
    assert f"{tiny_spec}: " in err
    assert not tiny_spec.with_name("o.mgraph").exists()


def test_directories_as_the_graph_spec_or_output_and_an_input_as_output_are_refused(tiny_spec, capsys):
    directory = tiny_spec.parent
    _graph_refused(capsys, [directory], f"{directory} is a directory, not a graph spec file")
    (directory / "out").mkdir()
    _graph_refused(capsys, [tiny_spec, "--out", directory / "out", "--force"],
                   f"--out {directory / 'out'} is a directory, not a file")
    (directory / "g.mgraph").mkdir()  # the spec's default output
    _graph_refused(capsys, [tiny_spec, "--force"], f"{directory / 'g.mgraph'} is a directory, not a file")
    _graph_refused(capsys, [tiny_spec, "--out", directory / "a.mspace", "--force"],
                   f"--out {directory / 'a.mspace'} is the input")
    assert (directory / "a.mspace").read_bytes() == b"not opened" and list((directory / "out").iterdir()) == []
    assert not list(directory.glob(".*.tmp"))
