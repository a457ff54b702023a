"""A motion graph in the browser, against a real server and a real built graph (walk, stand, jump,
reach): the diagram shows the nodes and edges, the node playing and the transition's target;
Space jumps at the jump slider, R reaches, a click goes to a node; the character keeps its place
in the world across every transition; no console errors."""

from __future__ import annotations

import numpy as np
import pytest
from live_server import LiveServer, data_dir_with_graph

COLLECT = """() => {
  const c = window.morphspace.connection;
  const frame = c.handlers.frame;
  window.__frames = [];
  c.handlers.frame = (m) => {
    window.__frames.push({node: m.node, target: m.target, progress: m.progress, root: m.root, heading: m.heading,
                          time: m.time, requested: m.requested});
    frame(m);
  };
}"""


@pytest.fixture(scope="module")
def graph_web_server(built_graph, tmp_path_factory):
    data = data_dir_with_graph(tmp_path_factory.mktemp("browser-graph"), built_graph)
    with LiveServer(data) as live:
        yield live


def classes(page, node):
    return page.page.locator(f'#graph-view [data-node="{node}"]').get_attribute("class").split()


def set_slider(page, name, value):
    page.page.evaluate("""([name, value]) => {
      const input = document.getElementById(`param-${name}`);
      input.value = String(value);
      input.dispatchEvent(new Event("input"));
    }""", [name, value])


def test_walk_jump_walk_reach_from_the_keyboard_and_the_diagram(graph_web_server, open_page):
    page = open_page(graph_web_server.url + "/app/?graph=tiny&p.speed=1.2")
    status = page.wait_status(lambda s: s["topologySpace"] == "graph:tiny" and s["framesDrawn"] > 2
                              and s["frame"]["node"] == "walk", what="the graph streaming")
    assert status["graph"] == "tiny" and status["requested"] == {"speed": pytest.approx(1.2)}
    assert page.page.locator("#graph-section").is_visible()
    assert page.page.locator("#graph-view [data-node]").count() == 4
    assert page.page.locator("#graph-view [data-edge]").count() == 7
    assert "active" in classes(page, "walk") and "active" not in classes(page, "jump")
    assert page.page.locator("#heatmap").is_disabled() and page.page.locator("#compare").is_disabled()
    # every node's parameters have a slider; the jump's is set for the next jump (the walk has none)
    for name in ("speed", "jump_height", "reach_height"):
        assert page.page.locator(f"#param-{name}").count() == 1
    set_slider(page, "jump_height", 0.45)
    page.page.evaluate(COLLECT)
    page.page.locator("#view").focus()
    page.page.keyboard.press("Space")
    status = page.wait_status(lambda s: s["frame"]["node"] == "jump", what="Space to jump")
    assert status["action"]["node"] == "jump" and not status["paused"]
    assert status["requested"] == {"jump_height": pytest.approx(0.45, abs=0.002)}  # the slider's (step-rounded)
    page.wait_status(lambda s: s["frame"]["target"] == "stand", what="the jump's return planned")
    assert "active" in classes(page, "jump") and "target" in classes(page, "stand")
    page.screenshot("graph-jump")
    page.wait_status(lambda s: s["frame"]["node"] == "stand" and s["frame"]["progress"] is None, timeout=20,
                     what="landing back on the stand")
    page.page.keyboard.press("1")  # the first node: walk
    page.wait_status(lambda s: s["frame"]["node"] == "walk" and s["frame"]["progress"] is None, timeout=20,
                     what="1 to walk again")
    page.page.keyboard.press("r")  # walk -> stand -> reach
    page.wait_status(lambda s: s["frame"]["node"] == "reach", timeout=20, what="R to reach")
    page.wait_status(lambda s: s["frame"]["node"] == "stand" and s["frame"]["progress"] is None, timeout=20,
                     what="the reach returning to the stand")
    page.page.locator('#graph-view [data-node="walk"]').click()  # a click on the diagram
    status = page.wait_status(lambda s: s["frame"]["node"] == "walk" and s["frame"]["progress"] is None,
                              timeout=20, what="a click on walk")
    assert status["action"]["entered"] is not None and status["action"]["entered"] < 5
    assert "entered" in page.page.locator("#graph-state").text_content()
    frames = page.page.evaluate("window.__frames")
    nodes = [f["node"] for f in frames]
    visited = [n for i, n in enumerate(nodes) if i == 0 or nodes[i - 1] != n]
    assert visited == ["walk", "jump", "stand", "walk", "stand", "reach", "stand", "walk"]
    assert any(f["progress"] is not None and 0 <= f["progress"] <= 1 for f in frames)
    # the character keeps its place: no step faster than the motion, never back to the origin
    root = np.array([f["root"] for f in frames])
    times = np.array([f["time"] for f in frames])
    speed = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1) / np.maximum(np.diff(times), 1e-3)
    assert speed.max() < 2.5 and root[-1, 2] > root[0, 2] + 0.5
    pixels = page.canvas_pixels("graph-walk")
    assert np.ptp(pixels) > 0
    assert page.errors() == []


def test_the_picker_lists_graphs_beside_spaces(graph_web_server, open_page):
    page = open_page(graph_web_server.url + "/app/?space=walk")
    page.wait_status(lambda s: s["topologySpace"] == "walk" and s["framesDrawn"] > 2, what="the walk space")
    assert page.status()["graphs"] == ["tiny"]
    assert not page.page.locator("#graph-section").is_visible()
    page.page.locator("#space").select_option("graph:tiny")
    page.wait_status(lambda s: s["topologySpace"] == "graph:tiny" and s["frame"] and s["frame"]["node"] == "walk",
                     what="the graph from the picker")
    page.page.wait_for_function("location.search.includes('graph=tiny')", polling=50, timeout=5000)  # the URL (throttled)
    assert "space=" not in page.page.url.split("?")[1]
    page.page.locator("#space").select_option("walk")  # and back to a space: Space pauses there
    page.wait_status(lambda s: s["topologySpace"] == "walk" and s["frame"] and s["frame"]["node"] is None,
                     what="the walk space again")
    assert not page.page.locator("#graph-section").is_visible()
    page.page.locator("#view").focus()
    page.page.keyboard.press("Space")
    page.wait_status(lambda s: s["paused"], what="Space to pause a space")
    assert page.errors() == []


def test_the_frame_on_screen_of_a_graph_downloads_from_its_node_space(graph_web_server, open_page, tmp_path):
    """The OBJ link of a graph's frame asks the space of the node shown (the walk's) for the same pose."""
    page = open_page(graph_web_server.url + "/app/?graph=tiny&p.speed=1.2")
    page.wait_status(lambda s: s["topologySpace"] == "graph:tiny" and s["framesDrawn"] > 2
                     and s["frame"]["node"] == "walk", what="the graph streaming")
    page.page.click("#pause")
    page.wait_status(lambda s: s["paused"], what="the pause")
    page.wait_status(lambda s: s["drawnSeq"] == s["frame"]["seq"], what="the last frame drawn")
    shown = np.asarray(page.page.evaluate("Array.from(window.morphspace.viewer.mesh.geometry.attributes.position.array)"),
                       dtype=float).reshape(-1, 3)
    with page.page.expect_download(timeout=20000) as download:
        page.page.click("#download-obj")
    path = tmp_path / download.value.suggested_filename
    download.value.save_as(path)
    assert path.name.startswith("tiny-walk-") and path.suffix == ".obj", path.name
    V = np.array([[float(x) for x in line.split()[1:4]] for line in path.read_text().splitlines()
                  if line.startswith("v ")])
    assert V.shape == shown.shape
    distance = np.linalg.norm(V - shown, axis=1)  # the same pose, root-local (q16 on screen)
    assert distance.max() < 0.002, distance.max()
    assert page.errors() == []


def test_a_space_recording_ends_when_the_page_switches_to_a_graph(graph_web_server, open_page):
    """Record on a space, then pick a graph: the space's recording ends and downloads there
    (docs/web-client.md, Download)."""
    page = open_page(graph_web_server.url + "/app/?space=walk")
    page.wait_status(lambda s: s["topologySpace"] == "walk" and s["framesDrawn"] > 2, what="the walk space")
    page.page.click("#record")
    page.page.wait_for_function("document.getElementById('record').textContent !== 'Stop (0 s)'",
                                polling=100, timeout=10000)
    with page.page.expect_download(timeout=60000) as info:
        page.page.locator("#space").select_option("graph:tiny")
    assert info.value.suggested_filename == "walk-recording.glb"
    assert page.page.locator("#record").get_attribute("aria-pressed") == "false"
    page.wait_status(lambda s: s["topologySpace"] == "graph:tiny" and s["recording"] is None, what="the graph")
    assert page.errors() == []


def test_a_graph_turns_the_heatmap_off_and_disables_its_controls(graph_web_server, open_page):
    """(a docs-only user found the heatmap still checked on a graph, its legend over a grey mesh and
    its scale, auto and compare-mode controls enabled)"""
    page = open_page(graph_web_server.url + "/app/?space=walk&heatmap=1")
    page.wait_status(lambda s: s["topologySpace"] == "walk" and s["heatmap"] and s["framesDrawn"] > 2, what="the heatmap on")
    assert page.page.locator("#legend").is_visible()
    page.page.locator("#space").select_option("graph:tiny")
    page.wait_status(lambda s: s["topologySpace"] == "graph:tiny" and s["frame"] and s["frame"]["node"] == "walk",
                     what="the graph")
    assert not page.status()["heatmap"] and not page.page.is_checked("#heatmap")
    assert not page.page.locator("#legend").is_visible()
    assert page.page.inner_text("#status-space").startswith("tiny (graph) · ")  # as the picker names it
    for control in ("#heatmap", "#heat-scale", "#heat-auto", "#compare-mode", "#compare"):
        assert page.page.is_disabled(control), control
    page.page.wait_for_function("!location.search.includes('heatmap=1')", polling=50, timeout=5000)
    page.page.locator("#space").select_option("walk")
    page.wait_status(lambda s: s["topologySpace"] == "walk" and s["frame"] and s["frame"]["node"] is None, what="walk again")
    for control in ("#heatmap", "#heat-scale", "#heat-auto", "#compare-mode"):
        assert page.page.is_enabled(control), control
    assert page.errors() == []
