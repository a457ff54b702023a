"""The client SDK's example script, run against a real server."""

import subprocess
import sys

from engine.mesh_io import read_mesh


def test_the_drive_example_streams_steers_pulls_and_writes_a_frame(server, tmp_path):
    out = tmp_path / "last.obj"
    result = subprocess.run([sys.executable, "-m", "server.examples.drive", "--url", server.ws_url, "--space",
                             "speed", "--seconds", "2.5", "--rate", "30", "--obj", str(out)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert "speed: " in result.stdout and "update->frame" in result.stdout
    assert "pulled the frame" in result.stdout
    mesh = read_mesh(out)
    assert len(mesh.vertices) > 500


def test_the_drive_example_walks_jumps_walks_and_reaches_on_a_graph(built_graph, tmp_path):
    from live_server import LiveServer, data_dir_with_graph

    out = tmp_path / "last.obj"
    with LiveServer(data_dir_with_graph(tmp_path / "data", built_graph)) as live:
        result = subprocess.run([sys.executable, "-m", "server.examples.drive", "--url", live.ws_url, "--graph", "tiny",
                                 "--rate", "30", "--set", "jump.jump_height=0.45", "--obj", str(out)],
                                capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith("graph tiny: 4 nodes (walk, stand, jump, reach)")
    actions = [line for line in lines if line.startswith("action ")]
    assert [a.split()[1] for a in actions] == ["jump", "walk", "reach"] and "{'jump_height': 0.45}" in actions[0]
    plans = [line.strip() for line in lines if "server: planned:" in line]
    assert [p.split(":")[2].strip().split(" ")[0] for p in plans] == ["walk", "stand", "walk"]  # where each left from
    assert "walk -> stand -> reach" in plans[2]  # no edge walk -> reach: through the stand
    entered = [line.split()[1] for line in lines if line.startswith("entered ")]
    assert entered == ["jump", "walk", "reach"]
    fastest = next(line for line in lines if line.startswith("fastest root motion"))
    assert float(fastest.split(":")[1].split()[0]) < 2.5  # the root never leaps
    assert "ended at node stand" in fastest  # the reach returned to the stand by itself
    mesh = read_mesh(out)
    assert len(mesh.vertices) == 1000 and mesh.vertices[:, 2].mean() > 1.0  # where it walked to, not the origin
