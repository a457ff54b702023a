"""Recording a motion-graph session in the browser (issue 14 item 6, issue 16): Record restarts the
stream at its start node (at the start node's sliders) and keeps the requests (Space's jump action, an action to walk at a new
speed, a speed change on the walk) with the stream's frame clock; Stop downloads the recording
(JSON) and its glTF. The glTF passes the Khronos validator and is the engine's replay of the
recording, and that replay is the frames the page was shown (the same nodes; roots and vertices to
the float32 rounding of the stream's phase tables)."""

from __future__ import annotations

import importlib.util
import json
import time
from pathlib import Path

import numpy as np
import pytest
from live_server import LiveServer, data_dir_with_graph

from engine.export import play_performance
from engine.graph import MotionGraph

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = 120  # root-local vertices kept per streamed frame

COLLECT = """(sample) => {
  const c = window.morphspace.connection;
  const frame = c.handlers.frame;
  window.__frames = [];
  c.handlers.frame = (m) => {
    const v = m.vertices;
    const local = new Float32Array(v.buffer.slice(v.byteOffset, v.byteOffset + 12 * sample));
    window.__frames.push({seq: m.seq, ack: m.ack, time: m.time, node: m.node, root: m.root, heading: m.heading,
                          local: Array.from(local)});
    frame(m);
  };
}"""


def _load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


gltf_reader = _load("morphspace_gltf_reader", ROOT / "tests" / "engine" / "gltf_reader.py")
gltf_validator = _load("morphspace_gltf_validator", ROOT / "tests" / "engine" / "gltf_validator.py")


@pytest.fixture(scope="module")
def recording_server(built_graph, tmp_path_factory):
    data = data_dir_with_graph(tmp_path_factory.mktemp("browser-graph-recording"), built_graph)
    with LiveServer(data) as live:
        yield live


def set_slider(page, name, value):
    page.page.evaluate("""([name, value]) => {
      const input = document.getElementById(`param-${name}`);
      input.value = String(value);
      input.dispatchEvent(new Event("input"));
    }""", [name, value])


def test_a_recorded_graph_session_downloads_and_replays_to_the_frames_shown(recording_server, built_graph, open_page,
                                                                            tmp_path):
    page = open_page(recording_server.url + "/app/?graph=tiny&p.speed=1.2&codec=f32")
    page.wait_status(lambda s: s["topologySpace"] == "graph:tiny" and s["framesDrawn"] > 2
                     and s["frame"]["node"] == "walk", what="the graph streaming")
    page.wait_status(lambda s: s["frame"]["time"] > 1.0, what="a second of walking")
    set_slider(page, "jump_height", 0.45)
    set_slider(page, "speed", 1.4)  # after the hello: Record sends it again after its reset
    page.wait_status(lambda s: s["requested"] == {"speed": pytest.approx(1.4, abs=0.01)}, what="the walk at 1.4")
    page.page.evaluate(COLLECT, SAMPLE)
    downloads = []
    page.page.on("download", lambda download: downloads.append(download))
    page.page.click("#record")
    assert page.page.locator("#record").get_attribute("aria-pressed") == "true"
    # the first frame after Record's reset (it shows time 0 for a moment only: the recorder keeps its seq)
    restarted = page.wait_status(lambda s: s["recording"] and s["recording"]["firstSeq"] is not None,
                                 what="the stream restarted")
    assert restarted["recording"]["kind"] == "graph" and restarted["recording"]["resetSeq"] is not None
    first_frame = page.page.evaluate("(seq) => window.__frames.find((f) => f.seq === seq)",
                                     restarted["recording"]["firstSeq"])
    assert first_frame["time"] == 0 and first_frame["node"] == "walk", first_frame
    page.page.locator("#view").focus()
    page.page.keyboard.press("Space")
    page.wait_status(lambda s: s["frame"]["node"] == "jump", what="Space to jump")
    page.wait_status(lambda s: s["frame"]["node"] == "stand" and s["frame"]["progress"] is None, timeout=20,
                     what="landing back on the stand")
    set_slider(page, "speed", 1.5)  # the stand has no speed: kept for the walk's action
    page.page.keyboard.press("1")
    page.wait_status(lambda s: s["frame"]["node"] == "walk" and s["frame"]["progress"] is None, timeout=20,
                     what="1 to walk again")
    set_slider(page, "speed", 1.0)  # a params message on the walk
    page.wait_status(lambda s: s["requested"] == {"speed": pytest.approx(1.0, abs=0.01)}, what="the new speed")
    time.sleep(0.3)
    page.page.click("#record")  # Stop
    deadline = time.monotonic() + 60
    while len(downloads) < 2:
        assert time.monotonic() < deadline, [d.suggested_filename for d in downloads]
        page.page.wait_for_timeout(100)
    saved = {}
    for download in downloads:
        saved[download.suggested_filename] = tmp_path / download.suggested_filename
        download.save_as(saved[download.suggested_filename])
    assert sorted(saved) == ["tiny-performance.glb", "tiny-recording.json"]
    assert page.page.locator("#record").get_attribute("aria-pressed") == "false"

    recording = json.loads(saved["tiny-recording.json"].read_text())
    with MotionGraph.open(built_graph / "tiny.mgraph") as graph:
        assert recording["graph"] == "tiny" and recording["graph_checksum"] == graph.checksum
        frames, _ = play_performance(graph, recording)
    assert recording["start"] == "walk" and recording["params"] == {"speed": pytest.approx(1.2)}
    assert recording["missed_frames"] == 0 and recording["times"][:2] == [0, 0]
    assert len(recording["times"]) == recording["steps"] + 1
    requests = recording["requests"]
    assert requests[0]["set"] and requests[0]["node"] == "walk" and requests[0]["frame"] <= 3
    assert requests[0]["params"] == {"speed": pytest.approx(1.4, abs=0.01)}  # the slider, not the hello's 1.2
    actions = [(r["node"], r["params"]) for r in requests if not r.get("set")]
    assert actions[0] == ("jump", {"jump_height": pytest.approx(0.45, abs=0.002)})
    assert ("walk", {"speed": pytest.approx(1.5, abs=0.01)}) in actions
    assert any(r.get("set") and r["node"] == "walk" and r["params"] == {"speed": pytest.approx(1.0, abs=0.01)}
               for r in requests)

    # the glTF: validator-clean, and the engine's replay of the recording
    issues = gltf_validator.validate(saved["tiny-performance.glb"])["issues"]
    assert issues["numErrors"] == 0, issues["messages"][:5]
    times, vertices, _, _ = gltf_reader.animated_frames(saved["tiny-performance.glb"].read_bytes())
    world = np.stack([frames.world(k) for k in range(len(frames))]).astype(np.float64)
    np.testing.assert_allclose(times, frames.times, rtol=0, atol=1e-6)
    assert np.abs(vertices - world).max() < 2e-5
    assert {"walk", "jump", "stand"} <= set(frames.nodes)

    # the replay is what the page was shown: frame k of the recording is the k-th streamed frame after Record
    shown = page.page.evaluate("window.__frames")
    first = next(i for i, f in enumerate(shown) if f["time"] == 0)
    shown = shown[first:first + recording["steps"]]
    assert len(shown) == recording["steps"] and [f["seq"] for f in shown] == list(range(shown[0]["seq"],
                                                                                          shown[-1]["seq"] + 1))
    at_time = {t: k for k, t in enumerate(frames.times.tolist())}
    kept = [(i, at_time[f["time"]]) for i, f in enumerate(shown)  # at a repeated time the export keeps the last
            if i + 1 == len(shown) or shown[i + 1]["time"] != f["time"]]
    assert len(kept) >= len(frames) - 1
    assert [frames.nodes[k] for _, k in kept] == [shown[i]["node"] for i, _ in kept]
    root = max(np.abs(frames.root_position[k] - shown[i]["root"]).max() for i, k in kept)
    heading = max(abs(frames.heading[k] - shown[i]["heading"]) for i, k in kept)
    local = max(np.abs(frames.local[k][:SAMPLE].reshape(-1) - shown[i]["local"]).max() for i, k in kept)
    # the stream blends through phase tables (exact up to float32 rounding), the replay blends each frame
    assert root < 1e-5 and heading < 1e-6 and local < 2e-5, (root, heading, local)
    print(f"replay vs shown: root {root:.3g} m, heading {heading:.3g} rad, root-local vertices {local:.3g} m")
    assert page.errors() == []
