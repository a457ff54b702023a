"""The Godot 3 add-on (engine_clients/godot/) run headless against a real server.

A real ``morphspace serve`` streams the test's speed space; Debian's ``godot3-server`` runs the
project in tests/engine_clients/godot_project/ (copied with the add-on into a temporary
directory, HOME and the XDG directories pointed there too). Its script streams frames in both
codecs through a MorphspaceMesh, steers half way, pulls, then pulls on the engine's clock, and
writes every frame it applied (the vertices the mesh holds, the node's transform) and its decode
and mesh update times. Here every frame is checked against the engine's own blend at the
frame's weights and phase (within the codec's bound), pulled frames against the same pulls made
by server/client.py, and the placement against the root transform. On the tiny motion graph
(tests/conftest.py's built_graph) its graph.gd asks for a jump and records the frames' nodes, the
add-on's node_changed signals and properties; the example project's graph scene (Space: jump,
R: reach) runs there too.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import os
import shutil
import subprocess
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from engine.graph.clock import foot_vertices
from engine.graph.legs import LegRig
from engine.motion_space import MotionSpace
from engine.rotations import rot_y
from live_server import LiveServer, data_dir_with_graph, data_dir_with_spaces
from server.client import StreamClient
from server.codecs import decode_vertices, quantisation_error

ROOT = Path(__file__).resolve().parents[2]
ADDON = ROOT / "engine_clients" / "godot" / "addons"
PROJECT = Path(__file__).resolve().parent / "godot_project"
GODOT = Path(os.environ.get("MORPHSPACE_TEST_GODOT", "/usr/bin/godot3-server"))
FRAMES = 60
PULLS = (0.1, 0.37, 0.8, 1.25)
PULL_VALUE = 1.5
VALUES = (1.2, 2.0)
ENGINE_FRAMES = 30
ROUNDING = 2e-6  # metres: float32 rounding of the same blend computed two ways (phase tables, weights)

pytestmark = pytest.mark.skipif(not GODOT.exists(), reason=f"needs Debian's godot3-server at {GODOT} "
                                "(apt-get install -y godot3-server; scripts/test installs it)")


def _tracked_state():
    """git's view of the add-on and the test project (ignored files included)."""
    return subprocess.run(["git", "status", "--porcelain", "--ignored", "--untracked-files=all",
                           "engine_clients", "tests/engine_clients/godot_project"],
                          cwd=ROOT, capture_output=True, text=True, check=True).stdout


def _godot_env(home):
    home.mkdir(parents=True)
    return dict(os.environ, HOME=str(home), XDG_DATA_HOME=str(home / "data"), XDG_CONFIG_HOME=str(home / "config"),
                XDG_CACHE_HOME=str(home / "cache"), LC_ALL="C.UTF-8")


def _project(tmp_path):
    """(the test Godot project with the add-on, copied under tmp_path; an empty output folder)."""
    project = tmp_path / "project"
    shutil.copytree(PROJECT, project)
    shutil.copytree(ADDON, project / "addons")
    out = tmp_path / "out"
    out.mkdir()
    return project, out


def _run_godot(tmp_path, ws_url):
    project, out = _project(tmp_path)
    env = _godot_env(tmp_path / "home")
    args = [str(GODOT), "--path", str(project), "--", f"--out={out}", f"--url={ws_url}", "--space=speed",
            "--param=speed", f"--values={VALUES[0]},{VALUES[1]}", f"--frames={FRAMES}",
            f"--pulls={','.join(map(str, PULLS))}", f"--pull-value={PULL_VALUE}",
            f"--engine-frames={ENGINE_FRAMES}", "--engine-fps=60", "--timeout=90"]
    run = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=150)
    error = out / "error.txt"
    assert run.returncode == 0 and not error.exists(), (
        f"godot exited {run.returncode}: {error.read_text() if error.exists() else ''}\n{run.stdout[-3000:]}\n"
        f"{run.stderr[-3000:]}")
    with open(out / "records.msgpack", "rb") as f:
        records = list(msgpack.Unpacker(f, raw=False))
    summary = msgpack.unpackb((out / "summary.msgpack").read_bytes(), raw=False)
    return records, summary


async def _python_pulls(ws_url, times):
    """The same pulls through server/client.py: {time: frame} in f32."""
    async with StreamClient.connect(ws_url, "speed", codec="f32", rate=0, smoothing=0.0,
                                    params={"speed": VALUES[0]}) as client:
        return {t: await client.pull({"speed": PULL_VALUE}, time=t) for t in times}, client.topology


def test_godot_client_decodes_places_and_pulls_frames(built_spaces, tmp_path):
    before = _tracked_state()
    data = data_dir_with_spaces(tmp_path / "server data", built_spaces, names=("speed",))
    with LiveServer(data) as live:
        records, summary = _run_godot(tmp_path / "godot run", live.ws_url)
        times = sorted({r["time"] for r in records if r["kind"] == "pull"})
        assert times == pytest.approx(PULLS)
        # on a loop of its own in a thread: this worker's main thread may hold Playwright's loop
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            expected_pulls, topology = pool.submit(asyncio.run, _python_pulls(live.ws_url, times)).result(120)
    assert _tracked_state() == before  # nothing written into the repository
    bound = {"f32": 0.0, "q16": quantisation_error((topology.bounds_min, topology.bounds_max))}
    assert 0 < bound["q16"] < 1e-4

    worst = {}
    with MotionSpace.open(built_spaces / "speed.mspace") as space:
        for r in records:
            V = np.frombuffer(r["vertices"], dtype="<f4").reshape(-1, 3)
            assert r["n_vertices"] == space.n_vertices == len(V)
            if r["kind"] == "pull":
                reference = expected_pulls[r["time"]]
                assert r["weights"] == reference.weights.tolist() and r["phase"] == reference.phase
                assert r["root"] == reference.root.tolist() and r["heading"] == reference.heading
                expected = reference.vertices
                if r["codec"] == "f32":
                    assert np.array_equal(V, expected)  # the same float32 bytes, decoded
            else:
                expected = space.blender(r["mode"]).blend(np.asarray(r["weights"]), r["phase"])
            error = float(np.abs(V.astype(np.float64) - expected).max())
            key = f"{r['kind']}-{r['codec']}"
            worst[key] = max(worst.get(key, 0.0), error)
            assert error <= bound[r["codec"]] + ROUNDING, (key, r["seq"], error)
            if "basis" in r:  # placed by the root transform: rotate by heading about +Y, then translate
                assert np.allclose(np.reshape(r["basis"], (3, 3)), rot_y(r["heading"]), atol=1e-6)
                assert np.allclose(r["origin"], r["root"], atol=1e-5)
    kinds = {key: sum(f"{r['kind']}-{r['codec']}" == key for r in records) for key in worst}
    assert kinds["pull-f32"] == kinds["pull-q16"] == len(PULLS) and kinds["engine-f32"] == ENGINE_FRAMES
    assert kinds["stream-f32"] >= FRAMES and kinds["stream-q16"] >= FRAMES  # (and the frame answering the pause)

    for codec in ("f32", "q16"):  # the steer: frames acknowledging it show the new speed at once
        stream = [r for r in records if r["kind"] == "stream" and r["codec"] == codec]
        steer = summary["codecs"][f"stream-{codec}"]["steer_seq"]
        assert steer > 0 and all(r["requested"] == pytest.approx([VALUES[r["ack"] >= steer]]) for r in stream)
        assert any(r["ack"] >= steer for r in stream) and stream[0]["ack"] < steer
        assert [r["seq"] for r in stream] == sorted({r["seq"] for r in stream})
    engine = [r for r in records if r["kind"] == "engine"]
    # each shows the time pulled on the engine's clock, which has moved on by the round trip when it lands: never
    # ahead of it, and behind by the server's answer (up to 0.1 s when idle; a loaded suite run once saw more)
    lags = [r["pull_time"] - r["time"] for r in engine]
    assert min(lags) >= -1e-6 and max(lags) <= 0.5, lags
    assert [r["time"] for r in engine] == sorted(r["time"] for r in engine)

    print("\nGodot 3 add-on, headless (dummy renderer: the mesh update is the CPU side, no GPU upload):")
    for key, figures in sorted(summary["codecs"].items()):
        rows = [r for r in records if f"{r['kind']}-{r['codec']}" == key]
        decode = np.array([r["decode_usec"] for r in rows], dtype=float)
        update = np.array([r["update_usec"] for r in rows], dtype=float)
        total = decode + update
        print(f"  {key}: {figures['frames']} frames applied at {figures['frames_per_second']:.1f} frames/s "
              f"(received {figures['received']}, {figures['superseded']} superseded before the next engine frame, "
              f"{figures['server_dropped']} dropped by the server; engine {figures['engine_fps']} fps); decode median "
              f"{np.median(decode):.0f} us, mesh update median {np.median(update):.0f} us, decode + update "
              f"median {np.median(total):.0f} us, p95 {np.percentile(total, 95):.0f} us, max {total.max():.0f} us; "
              f"largest error {worst[key] * 1e6:.2f} um (bound {bound[key.split('-')[1]] * 1e6:.2f} um)")


def test_godot_client_plays_a_motion_graph_action(built_graph, tmp_path):
    """A MorphspaceMesh on the tiny motion graph (walk, stand, jump, reach) from walk: after 10
    frames a game script calls action("jump", {jump_height: 0.4}, 3.0) (after steering the walk
    from speed 1.2 to 1.5 with set_param at 5 frames); the server plans it (its
    notice answers the action's seq) and the frames go walk -> jump -> stand by themselves. The
    add-on's node_changed signals, current_node / target_node / progress and the parameters
    named by each node follow the frames; frames outside a blend are that node's own blend."""
    data = data_dir_with_graph(tmp_path / "server data", built_graph)
    project, out = _project(tmp_path)
    with LiveServer(data) as live:
        args = [str(GODOT), "--path", str(project), "res://graph.tscn", "--", f"--out={out}", f"--url={live.ws_url}",
                "--graph=tiny", "--node=walk", "--param=speed", "--value=1.2", "--steer=1.5", "--codec=q16", "--before=10",
                "--action=jump", "--action-param=jump_height", "--action-value=0.4", "--budget=3", "--after=5", "--timeout=90"]
        run = subprocess.run(args, cwd=tmp_path, env=_godot_env(tmp_path / "home"), capture_output=True, text=True,
                             timeout=150)
    output = run.stdout + run.stderr
    error = out / "error.txt"
    assert run.returncode == 0 and not error.exists(), (error.read_text() if error.exists() else "") + output[-3000:]
    assert "SCRIPT ERROR" not in output and "Parse Error" not in output, output[-3000:]
    assert "mesh_get_surface_count" not in output and "rid.h" not in output, output[-3000:]  # a clean quit after stop()
    summary = msgpack.unpackb((out / "summary.msgpack").read_bytes(), raw=False)
    with open(out / "records.msgpack", "rb") as f:
        records = list(msgpack.Unpacker(f, raw=False))

    assert summary["topologies"] == 1
    assert [n["name"] for n in summary["nodes"]] == ["walk", "stand", "jump", "reach"]
    cyclic = {n["name"]: n["cyclic"] for n in summary["nodes"]}
    assert cyclic["walk"] and cyclic["stand"] and not cyclic["jump"]
    assert {"from": "walk", "to": "jump"} in summary["edges"] and len(summary["edges"]) == 7
    seq = summary["action_seq"]
    assert seq > 0 and [(n["code"], n["seq"]) for n in summary["notices"]] == [("planned", seq)]
    assert summary["notices"][0]["message"].startswith("walk -> jump:")

    nodes = [r["node"] for r in records]
    visited = [n for i, n in enumerate(nodes) if i == 0 or nodes[i - 1] != n]
    assert visited == ["walk", "jump", "stand"]  # to the action's node, and back to a cyclic node by itself
    assert all(r["node"] == "walk" for r in records if r["ack"] < seq)
    changes = [(c["previous"], c["node"]) for c in summary["changes"]]
    assert changes == [("", "walk"), ("walk", "jump"), ("jump", "stand")]
    starts = [i for i in range(len(nodes)) if i == 0 or nodes[i - 1] != nodes[i]]
    assert [c["frame"] for c in summary["changes"]] == starts  # emitted just before that frame's frame_applied
    assert sum(1 for r in records if r["node"] == "stand") == 5
    blending = [r for r in records if r["progress"] is not None]
    assert blending and all(0.0 <= r["progress"] <= 1.0 and r["target"] is not None for r in blending)
    assert any(r["node"] == "walk" and r["target"] == "jump" for r in records)
    assert all(r["target"] == "stand" for r in records if r["node"] == "jump" and r["progress"] is None)
    for r in records:
        assert (r["current_node"], r["target_node"], r["progress_property"]) == (r["node"], r["target"], r["progress"])
        names = {"walk": ["speed"], "stand": [], "jump": ["jump_height"]}[r["node"]]
        assert list(r["requested_params"]) == names and r["requested_params"] == dict(zip(names, r["requested"]))
        if r["node"] == "walk":  # steered by set_param: from the frame acknowledging it
            speed = 1.5 if r["ack"] >= summary["steer_seq"] else 1.2
            assert r["requested_params"] == {"speed": pytest.approx(speed)}
            assert r["get_param"] == pytest.approx(speed) or r["ack"] < summary["steer_seq"]
    assert 0 < summary["steer_seq"] < seq and any(r["ack"] >= summary["steer_seq"] and r["node"] == "walk"
                                                  for r in records)
    assert any(r["requested_params"] == {"jump_height": pytest.approx(0.4)} for r in records if r["node"] == "jump")

    spaces = {name: MotionSpace.open(built_graph / f"{name}.mspace") for name in ("walk", "stand", "jump")}
    try:
        bound = summary["quantisation_error"]  # the topology's: the box covers every node
        assert 0 < bound < 1e-4
        checked = 0
        rest = np.asarray(spaces["walk"].container["rest"])
        legs = np.zeros(len(rest), dtype=bool)  # below the crotch: where a held foot moves the mesh (engine/graph/legs.py)
        legs[LegRig(rest, foot_vertices(rest)).index] = True
        feet = np.concatenate(foot_vertices(rest))
        for r in records:
            if r["progress"] is None:  # not blending: the node's own blend, decoded within q16's bound, but
                V = np.frombuffer(r["vertices"], dtype="<f4").reshape(-1, 3).astype(np.float64)  # a held foot's leg
                expected = spaces[r["node"]].blend(np.asarray(r["weights"]), r["phase"], "linear")
                error = float(np.abs(V[~legs] - expected[~legs]).max())
                assert error <= bound + 1e-5, (r["seq"], r["node"], error)  # 1e-5: as tests/server's graph test
                assert np.abs(V[feet, 1] - expected[feet, 1]).max() <= bound + 1e-5  # feet moved along the ground only
                assert np.abs(V[legs] - expected[legs]).max() < 0.4
                checked += 1
        assert checked >= 15
    finally:
        for space in spaces.values():
            space.close()
    counts = {n: nodes.count(n) for n in visited}
    print(f"\nGodot 3 add-on on the tiny graph: {summary['notices'][0]['message']}; frames applied per node {counts}, "
          f"{len(blending)} blending, {checked} checked against their node's blend")


def test_example_project_loads_and_runs_a_frame(tmp_path):
    """engine_clients/godot/ opens as a project: its example scene and the add-on's scripts
    parse and run their first frame (no server: the add-on only schedules a reconnect)."""
    project = tmp_path / "example"
    shutil.copytree(ROOT / "engine_clients" / "godot", project)
    run = subprocess.run([str(GODOT), "--path", str(project), "--quit"], cwd=tmp_path, env=_godot_env(tmp_path / "home"),
                         capture_output=True, text=True, timeout=60)
    output = run.stdout + run.stderr
    assert run.returncode == 0 and "SCRIPT ERROR" not in output and "Parse Error" not in output, output[-3000:]


def test_example_graph_demo_jumps_on_space_and_reaches_on_r(built_graph, tmp_path):
    """engine_clients/godot/'s graph scene, headless against a real server on the tiny graph:
    Space (pressed through Godot's input 1 s after the first frame) asks for the jump, R (at 5 s)
    for the reach; the character goes walk, jump, stand, reach, stand and quits cleanly."""
    import json

    data = data_dir_with_graph(tmp_path / "server data", built_graph)
    project = tmp_path / "example"
    shutil.copytree(ROOT / "engine_clients" / "godot", project)
    out = tmp_path / "demo.json"
    with LiveServer(data) as live:
        run = subprocess.run([str(GODOT), "--path", str(project), "res://example/graph_demo.tscn", "--",
                              f"--url={live.ws_url}", "--graph=tiny", "--press=1:space,5:r", "--quit-after=12",
                              f"--out={out}"], cwd=tmp_path, env=_godot_env(tmp_path / "home"), capture_output=True,
                             text=True, timeout=150)
    output = run.stdout + run.stderr
    assert run.returncode == 0 and out.exists(), output[-3000:]
    assert "SCRIPT ERROR" not in output and "Parse Error" not in output and "rid.h" not in output, output[-3000:]
    summary = json.loads(out.read_text())
    assert summary["errors"] == [] and summary["frames"] > 60
    assert summary["visited"][:5] == ["walk", "jump", "stand", "reach", "stand"], summary["visited"]
    assert len(summary["notices"]) >= 2 and {n["code"] for n in summary["notices"]} <= {"planned", "queued"}
    assert summary["root"][2] > 0.5  # it walked before jumping: the root left the origin


def test_example_graph_demo_quits_with_an_error_on_bad_options_an_unknown_graph_or_no_server(built_graph, tmp_path):
    """The graph scene ran until killed, with no --out, on an unknown graph or with no server, and a
    malformed --press stopped its script with a SCRIPT ERROR and hung (a docs-only trial); an unknown
    key pressed R. Now each quits with status 1 and says why in --out."""
    import json
    import socket

    data = data_dir_with_graph(tmp_path / "server data", built_graph)
    project = tmp_path / "example"
    shutil.copytree(ROOT / "engine_clients" / "godot", project)
    with socket.socket() as probe:   # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        silent = f"ws://127.0.0.1:{probe.getsockname()[1]}/v1/stream"

    def scene(name, url, *options):
        out = tmp_path / f"{name}.json"
        run = subprocess.run([str(GODOT), "--path", str(project), "res://example/graph_demo.tscn", "--", f"--url={url}",
                              *options, f"--out={out}"], cwd=tmp_path, env=_godot_env(tmp_path / "home" / name),
                             capture_output=True, text=True, timeout=90)
        output = run.stdout + run.stderr
        assert run.returncode == 1 and out.exists(), output[-3000:]
        assert "SCRIPT ERROR" not in output and "Parse Error" not in output, output[-3000:]
        return json.loads(out.read_text())

    with LiveServer(data) as live:
        unknown = scene("unknown", live.ws_url, "--graph=nope", "--quit-after=3")
        for press in ("abc", "1:x", "one:space"):
            bad = scene(f"press {press}", live.ws_url, "--graph=tiny", f"--press={press}", "--quit-after=3")
            assert [e["code"] for e in bad["errors"]] == ["bad_option"] and bad["visited"] == [], bad
            assert f"--press={press}: each press is T:space or T:r" in bad["errors"][0]["message"]
    assert unknown["frames"] == 0 and unknown["errors"][-1]["code"] == "no_frames", unknown
    assert any("nope" in e["message"] for e in unknown["errors"][:-1]), unknown   # the server's own error first
    nobody = scene("nobody", silent, "--graph=tiny", "--quit-after=2")
    assert [e["code"] for e in nobody["errors"]] == ["no_frames"] and nobody["disconnects"], nobody


def test_godot_client_reconnects_with_its_parameters(built_spaces, tmp_path):
    """The add-on retries (with a doubling delay) until the server is up, and after a server
    restart reconnects on its own, sending hello again with the parameters it last requested."""
    data = data_dir_with_spaces(tmp_path / "server data", built_spaces, names=("speed",))
    live = LiveServer(data)  # its port is chosen; nothing listens there yet
    project, out = _project(tmp_path)
    args = [str(GODOT), "--path", str(project), "res://reconnect.tscn", "--", f"--out={out}", f"--url={live.ws_url}",
            "--space=speed", "--param=speed", f"--value={VALUES[1]}", "--frames=10", "--timeout=90"]
    godot = subprocess.Popen(args, cwd=tmp_path, env=_godot_env(tmp_path / "home"), stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(1.5)  # a few failed attempts
        live.start()
        deadline = time.monotonic() + 60
        while not (out / "first.txt").exists():
            assert godot.poll() is None and time.monotonic() < deadline, "no frames on the first connection"
            time.sleep(0.1)
        live.stop()
        time.sleep(1.0)
        live.start()
        output, _ = godot.communicate(timeout=90)
    finally:
        if godot.poll() is None:
            godot.kill()
            godot.wait()
        live.stop()
    error = out / "error.txt"
    assert godot.returncode == 0 and not error.exists(), (error.read_text() if error.exists() else "") + output[-3000:]
    summary = msgpack.unpackb((out / "summary.msgpack").read_bytes(), raw=False)
    assert summary["topologies"] == 2
    before = [d for d in summary["disconnects"] if d["after_topologies"] == 0]
    after = [d for d in summary["disconnects"] if d["after_topologies"] == 1]
    assert len(before) >= 2 and len(after) >= 1
    delays = [d["retry_in"] for d in before]
    assert delays[:3] == pytest.approx([0.2, 0.4, 0.8][:len(delays[:3])]) and max(delays) <= 1.0
    assert after[0]["retry_in"] == pytest.approx(0.2)  # the topology reset the delay
    first, second = summary["frames"]
    assert all(f["requested"] == pytest.approx([VALUES[1]]) for f in first + second)
    assert second[0]["seq"] < first[-1]["seq"]  # a new connection: frame numbers restarted


def test_godot_client_leaves_a_server_that_went_silent(built_spaces, tmp_path):
    """A server that stops sending without closing the connection (here: the process stopped
    with SIGSTOP; a machine gone from the network looks the same) is left after the add-on's
    silence_timeout, 5 s without a message while frames are due; the add-on then reconnects
    to it once it is back, and streams on."""
    import signal

    data = data_dir_with_spaces(tmp_path / "server data", built_spaces, names=("speed",))
    project, out = _project(tmp_path)
    with LiveServer(data) as live:
        args = [str(GODOT), "--path", str(project), "res://reconnect.tscn", "--", f"--out={out}",
                f"--url={live.ws_url}", "--space=speed", "--param=speed", f"--value={VALUES[1]}", "--frames=10",
                "--timeout=90"]
        godot = subprocess.Popen(args, cwd=tmp_path, env=_godot_env(tmp_path / "home"), stdout=subprocess.PIPE,
                                 stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + 60
            while not (out / "first.txt").exists():
                assert godot.poll() is None and time.monotonic() < deadline, "no frames on the first connection"
                time.sleep(0.1)
            os.killpg(live.process.pid, signal.SIGSTOP)
            try:
                time.sleep(7.0)
            finally:
                os.killpg(live.process.pid, signal.SIGCONT)
            output, _ = godot.communicate(timeout=90)
        finally:
            if godot.poll() is None:
                godot.kill()
                godot.wait()
    error = out / "error.txt"
    assert godot.returncode == 0 and not error.exists(), (error.read_text() if error.exists() else "") + output[-3000:]
    summary = msgpack.unpackb((out / "summary.msgpack").read_bytes(), raw=False)
    after = [d for d in summary["disconnects"] if d["after_topologies"] == 1]
    assert summary["topologies"] == 2 and after, summary["disconnects"]
    assert after[0]["reason"].startswith("no message from the server for 5."), after[0]
    first, second = summary["frames"]
    assert all(f["requested"] == pytest.approx([VALUES[1]]) for f in first + second)


def test_gdscript_msgpack_and_codecs_against_python(tmp_path):
    """msgpack.gd decodes every family the protocol uses (and says what is wrong with broken
    bytes), its encoder gives them back; codecs.gd's q16 decoding (native and the plain loop)
    equals the server's own decoder bit for bit at sizes that fill one Image row, several rows,
    and a padded last row; faces come back with Godot's clockwise winding."""
    rng = np.random.default_rng(7)
    values = {"nil": None, "t": True, "f": False, "fixint": [0, 1, 127, -1, -32], "uint": [128, 255, 256, 65535, 65536,
              2**32 - 1, 2**32, 2**53], "int": [-33, -128, -129, -32768, -32769, -2**31, -2**31 - 1, -2**53],
              "float64": [0.1, -2.5e-300, 1e300, 1 / 3], "str": ["", "a" * 31, "b" * 32, "é" * 200, "x" * 70000],
              "bin": [b"", b"\x00\xff" * 200, bytes(70000)], "nested": [{"k": [1, [2, {"z": None}]]}],
              "map16": {f"key{i}": i for i in range(20)}, 5: "int key"}
    malformed = [b"", b"\xc1", b"\x92\x01", b"\xa5abc", b"\xc4\x05ab", b"\x01\x02", b"\xdd\xff\xff\xff\xff",
                 b"\xcf\xff\xff\xff\xff\xff\xff\xff\xff"]
    bounds = (np.array([-1.1, -0.2, -0.9], dtype=np.float32), np.array([1.3, 2.1, 1.05], dtype=np.float32))
    cases = []
    for n in (1, 1000, 4096, 4097, 10000):
        q = rng.integers(0, 65536, size=(n, 3), dtype=np.uint16)
        q[0] = (0, 65535, 1)
        cases.append({"n": n, "data": q.astype("<u2").tobytes(), "lo": bounds[0].tolist(), "hi": bounds[1].tolist()})
    F = rng.integers(0, 1000, size=(50, 3)).astype("<u4")
    source = tmp_path / "in.msgpack"
    source.write_bytes(msgpack.packb({"values": values, "malformed": malformed, "q16": cases,
                                      "faces": {"n": len(F), "data": F.tobytes()}}, use_bin_type=True))
    project = tmp_path / "project"
    shutil.copytree(PROJECT, project)
    shutil.copytree(ADDON, project / "addons")
    out = tmp_path / "out.msgpack"
    run = subprocess.run([str(GODOT), "--path", str(project), "res://codecs_check.tscn", "--", f"--in={source}",
                          f"--out={out}"], cwd=tmp_path, env=_godot_env(tmp_path / "home"), capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0 and out.exists(), run.stdout[-3000:] + run.stderr[-3000:]
    result = msgpack.unpackb(out.read_bytes(), raw=False, strict_map_key=False)
    assert result["echo"] == values
    assert all(error for error in result["errors"]), result["errors"]  # every broken input named as such
    for case, fast, plain in zip(cases, result["q16"], result["q16_loop"]):
        expected = decode_vertices(case["data"], "q16", case["n"], *bounds)
        assert np.array_equal(np.frombuffer(fast, "<f4").reshape(-1, 3), expected), case["n"]
        assert np.array_equal(np.frombuffer(plain, "<f4").reshape(-1, 3), expected), case["n"]
    assert result["faces"] == F[:, [0, 2, 1]].reshape(-1).tolist()
