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
