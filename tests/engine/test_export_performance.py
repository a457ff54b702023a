"""Exports of motion-graph performances: a recording replayed to the frames ``perform`` makes
(byte for byte), written as glTF and USD that the reference validators pass and that read back
to those frames; bad recordings are errors naming the problem."""

import copy

import numpy as np
import pytest

from engine.export import ClipError, play_performance, scripted_recording, write_export
from engine.graph import GraphPlayer, MotionGraph
from engine.graph.recording import perform
from gltf_reader import Glb, animated_frames
from gltf_validator import assert_clean, validate

REQUESTS = [{"time": 0.5, "node": "jump", "params": {"jump_height": 0.4}, "budget": None},
            {"time": 2.5, "node": "reach", "params": {"reach_height": 1.5}, "budget": 2.0}]


@pytest.fixture(scope="module")
def graph(built_graph):
    with MotionGraph.open(built_graph / "tiny.mgraph") as graph:
        yield graph


@pytest.fixture(scope="module")
def recording(graph):
    """walk -> jump -> stand -> reach, 5 s at 24 frames/s, as morphspace play records it."""
    return scripted_recording(graph, start="walk", params={"speed": 1.2}, requests=REQUESTS, fps=24, seconds=5)


@pytest.fixture(scope="module")
def performance(graph, recording):
    return play_performance(graph, recording)


def world(frames):
    return np.stack([frames.world(k) for k in range(len(frames))]).astype(np.float64)


def test_the_replay_is_the_players_performance_byte_for_byte(graph, recording, performance):
    frames, digest = performance
    placed = []
    r = recording
    _, expected, _ = perform(graph, start=r["start"], params=r["params"], fps=r["fps"], steps=r["steps"],
                             mode=r["mode"], requests=r["requests"],
                             on_frame=lambda k, f: placed.append(f.vertices.copy()))
    assert digest == expected
    assert len(frames) == r["steps"] + 1 == len(placed)
    for k in range(len(frames)):
        assert np.array_equal(frames.world(k), placed[k]), k  # the exporters' placement is the player's
    np.testing.assert_allclose(frames.times, np.arange(len(frames)) / 24, atol=1e-12)
    assert frames.uniform and frames.space == "tiny"
    visited = [n for i, n in enumerate(frames.nodes) if i == 0 or frames.nodes[i - 1] != n]
    assert visited[:2] == ["walk", "jump"] and "reach" in visited
    assert frames.root_position[-1, 2] > 1.0  # it went somewhere: the root moved across nodes
    walk = frames.names.index("walk.speed")
    assert frames.params[0, walk] == pytest.approx(1.2, abs=0.05)
    assert np.isnan(frames.params[frames.nodes.index("jump"), walk])  # not the node shown


@pytest.mark.parametrize("precision", ["int16", "float32"])
def test_glb_passes_the_validator_and_reads_back(performance, tmp_path, precision):
    frames, _ = performance
    path = tmp_path / "perf.glb"
    stats = write_export(path, frames, "glb", precision=precision)
    assert_clean(validate(path))
    times, vertices, faces, shown = animated_frames(path.read_bytes())
    np.testing.assert_allclose(times, frames.times, rtol=0, atol=1e-6)
    assert np.array_equal(faces, frames.faces)
    assert np.abs(vertices - world(frames)).max() <= stats["max_error_m"] + 2e-6
    extras = Glb(path.read_bytes()).json["scenes"][0]["extras"]
    assert extras["graph"] == "tiny" and extras["nodes"] == frames.nodes


def test_the_same_recording_gives_the_same_bytes(graph, recording, tmp_path):
    for name in ("a", "b"):
        frames, _ = play_performance(graph, copy.deepcopy(recording))
        write_export(tmp_path / f"{name}.glb", frames, "glb")
        write_export(tmp_path / f"{name}.usdc", frames, "usd")
    assert (tmp_path / "a.glb").read_bytes() == (tmp_path / "b.glb").read_bytes()
    assert (tmp_path / "a.usdc").read_bytes() == (tmp_path / "b.usdc").read_bytes()


def test_usd_passes_the_validators_and_reads_back(performance, tmp_path):
    Usd = pytest.importorskip("pxr.Usd")
    from pxr import UsdGeom
    from test_export_usd import validation_errors

    frames, _ = performance
    write_export(tmp_path / "perf.usda", frames, "usd")
    stage = Usd.Stage.Open(str(tmp_path / "perf.usda"))
    assert validation_errors(stage) == []
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/tiny/mesh"))
    cache = UsdGeom.XformCache()
    for k in range(0, len(frames), 7):
        time = Usd.TimeCode(k)
        points = np.array(mesh.GetPointsAttr().Get(time), dtype=np.float64)
        cache.SetTime(time)
        M = np.array(cache.GetLocalToWorldTransform(mesh.GetPrim()))
        np.testing.assert_allclose(points @ M[:3, :3] + M[3, :3], frames.world(k), rtol=0, atol=2e-6)


def test_a_streams_times_step_the_player_and_repeated_times_keep_the_last(graph, recording):
    """``times`` (a stream's clock): the player steps by their differences; a step of 0 s (an
    extra frame answering a message) replaces the frame before it in the export."""
    rng = np.random.default_rng(3)
    dts = rng.uniform(0.01, 0.03, size=60)
    dts[[0, 20]] = 0.0
    times = np.concatenate([[0.0], np.cumsum(dts)])
    doc = dict(recording, steps=60, times=times.tolist(), frames_sha256=None,
               requests=[{"frame": 20, "node": "jump", "params": {"jump_height": 0.3}, "budget": None},
                         {"frame": 30, "node": "jump", "params": {"jump_height": 0.45}, "budget": None,
                          "set": True}])
    frames, _ = play_performance(graph, doc)
    assert len(frames) == 59 and np.all(np.diff(frames.times) > 0) and not frames.uniform
    player = GraphPlayer(graph, node="walk", params={"speed": 1.2}, record=False)
    expected = [player.frame().vertices.copy()]
    for k, dt in enumerate(dts, start=1):
        if k == 21:
            player.request("jump", {"jump_height": 0.3})
        if k == 31:
            player.set_params({"jump_height": 0.45})
        expected.append(player.step(dt).vertices.copy())
    kept = [k for k in range(61) if k == 60 or times[k + 1] > times[k]]
    assert kept[:2] == [1, 2] and 20 not in kept
    for i, k in enumerate(kept):
        assert np.array_equal(frames.world(i), expected[k]), k


def _broken(recording, **changes):
    doc = copy.deepcopy(recording)
    doc.update(changes)
    return doc


@pytest.mark.parametrize("changes, message", [
    ({"format": "something-else"}, "not a morphspace-graph-recording"),
    ({"graph_checksum": "0" * 16}, "was made with graph"),
    ({"start": "fly"}, "no node 'fly'"),
    ({"requests": [{"frame": 3, "node": "fly", "params": {}}]}, "requests[0]: unknown node 'fly'"),
    ({"requests": [{"frame": 3, "node": "jump", "params": {"height": 1}}]}, "has no parameter 'height'"),
    ({"requests": [{"frame": 999, "node": "jump", "params": {}}]}, "frame 999 is outside the performance"),
    ({"requests": [{"frame": 3, "node": "jump", "params": {}, "budget": -1}]}, "budget must be a positive"),
    ({"requests": "jump"}, "requests must be a list"),
    ({"params": {"speed": "fast"}}, "walk.speed must be a finite number"),
    ({"steps": 3, "times": [0, 0.1], "requests": []}, "times must be a list of steps + 1 = 4"),
    ({"steps": 2, "times": [0, 0.2, 0.1], "requests": []}, "times must not decrease"),
    ({"steps": 1, "times": [0.5, 0.6], "requests": []}, "times must start at 0"),
])
def test_bad_recordings_name_the_problem(graph, recording, changes, message):
    with pytest.raises(ClipError) as caught:
        play_performance(graph, _broken(recording, **changes))
    assert message in str(caught.value)


def test_glb_of_a_play_recording_gives_back_play_replays_frames(built_graph, tmp_path):
    """``morphspace play --record``, then ``morphspace export --recording``: the GLB read back is
    what ``morphspace play --replay --frames`` writes (OBJ, 6 decimals) within both precisions."""
    import subprocess
    import sys

    from engine.mesh_io import read_mesh

    graph = built_graph / "tiny.mgraph"
    cli = [sys.executable, "-m", "server.cli"]
    run = subprocess.run([*cli, "play", graph, "--at", "0.3", "jump", "jump_height=0.45", "--at", "2", "walk",
                          "speed=1.6", "--seconds", "3.5", "--fps", "20", "--record", tmp_path / "session.json"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    run = subprocess.run([*cli, "export", graph, "--recording", tmp_path / "session.json", "--out",
                          tmp_path / "perf.glb"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "frames identical to the recording's" in run.stdout and "play: 100%" in run.stderr
    run = subprocess.run([*cli, "play", graph, "--replay", tmp_path / "session.json", "--frames", tmp_path / "frames"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    objs = sorted((tmp_path / "frames").glob("frame_*.obj"))
    times, vertices, _, _ = animated_frames((tmp_path / "perf.glb").read_bytes())
    assert len(objs) == len(times) == 71
    error = max(np.abs(vertices[k] - read_mesh(obj).vertices).max() for k, obj in enumerate(objs))
    assert error < 2e-5  # int16: 16 micrometres at most on this body; OBJ: 0.5 micrometres
