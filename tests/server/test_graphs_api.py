"""GET /v1/graphs: the motion graphs beside the spaces, described from their files; a graph
whose space was rebuilt, or a file that is no graph, is listed as unreadable with the reason."""

from __future__ import annotations

import shutil

import httpx
import pytest
from live_server import LiveServer, data_dir_with_graph


@pytest.fixture(scope="module")
def graph_server(built_graph, tmp_path_factory):
    data = data_dir_with_graph(tmp_path_factory.mktemp("graphs-api"), built_graph)
    with LiveServer(data) as live:
        yield live


def test_the_graph_is_listed_and_described(graph_server):
    listing = httpx.get(graph_server.url + "/v1/graphs", timeout=30).json()
    assert listing["unreadable"] == [] and [g["name"] for g in listing["graphs"]] == ["tiny"]
    graph = httpx.get(graph_server.url + "/v1/graphs/tiny", timeout=30).json()
    assert graph == listing["graphs"][0]
    assert graph["start"] == "walk" and graph["n_vertices"] == 1000
    nodes = {n["name"]: n for n in graph["nodes"]}
    assert list(nodes) == ["walk", "stand", "jump", "reach"]
    assert nodes["walk"]["cyclic"] and nodes["walk"]["return_to"] is None and nodes["walk"]["space"] == "walk"
    assert not nodes["jump"]["cyclic"] and nodes["jump"]["return_to"] == "stand"
    assert nodes["stand"]["parameters"] == []
    (height,) = nodes["jump"]["parameters"]
    assert height["name"] == "jump_height" and height["unit"] == "m" and height["min"] < height["default"] < height["max"]
    assert {"from": "walk", "to": "jump"} in graph["edges"] and {"from": "reach", "to": "stand"} in graph["edges"]
    assert {"from": "jump", "to": "walk"} not in graph["edges"]


def test_unknown_names_are_404(graph_server):
    for name in ("nope", "..", "walk"):  # walk is a space, not a graph
        r = httpx.get(graph_server.url + f"/v1/graphs/{name}", timeout=30)
        assert r.status_code == 404, (name, r.text)
    assert "no motion graph 'nope'" in httpx.get(graph_server.url + "/v1/graphs/nope").json()["detail"]


def test_a_graph_whose_space_changed_or_a_foreign_file_is_unreadable(built_graph, tmp_path):
    data = data_dir_with_graph(tmp_path / "data", built_graph)
    spaces = data / "spaces"
    shutil.copyfile(spaces / "tiny.mgraph", spaces / "other.mgraph")
    (spaces / "junk.mgraph").write_bytes(b"not a graph at all")
    with LiveServer(data) as live:
        listing = httpx.get(live.url + "/v1/graphs", timeout=30).json()
        assert [g["name"] for g in listing["graphs"]] == ["other", "tiny"]
        assert [u["name"] for u in listing["unreadable"]] == ["junk"]
        shutil.copyfile(spaces / "stand.mspace", spaces / "walk.tmp")
        (spaces / "walk.tmp").replace(spaces / "walk.mspace")  # walk rebuilt (here: another space)
        r = httpx.get(live.url + "/v1/graphs/tiny", timeout=30)
        assert r.status_code == 409 and "changed since the graph was built" in r.json()["detail"]
        listing = httpx.get(live.url + "/v1/graphs", timeout=30).json()
        assert listing["graphs"] == [] and {u["name"] for u in listing["unreadable"]} == {"junk", "other", "tiny"}
