"""REST for motion spaces on a real server: list, describe, one frame as OBJ, GLB or JSON."""

import io
import math

import httpx
import numpy as np
import pytest
import trimesh

from engine.motion_space import MotionSpace


@pytest.fixture(scope="module")
def speed_space(built_spaces):
    with MotionSpace.open(built_spaces / "speed.mspace") as space:
        yield space


def test_list_and_describe(server, speed_space):
    listing = httpx.get(server.url + "/v1/spaces").json()
    assert [s["name"] for s in listing["spaces"]] == ["jump", "speed"] and listing["unreadable"] == []
    info = httpx.get(server.url + "/v1/spaces/speed").json()
    assert info["n_vertices"] == speed_space.n_vertices and info["cyclic"] is True
    (p,) = info["parameters"]
    lo, hi = speed_space.parameter_map.domain()[0]
    assert p["name"] == "speed" and p["unit"] == "m/s" and p["min"] == pytest.approx(lo) and p["max"] == pytest.approx(hi)
    assert info["modes"] == ["linear", "hybrid", "nonlinear"]


def test_unknown_and_hostile_names_are_404(server):
    for name in ["nope", "..%2F..%2Fetc%2Fpasswd", "%2Fetc%2Fpasswd", ".hidden"]:
        r = httpx.get(server.url + f"/v1/spaces/{name}")
        assert r.status_code == 404, (name, r.text)


def test_a_broken_file_is_listed_as_unreadable_not_fatal(server):
    bad = server.data_dir / "spaces" / "broken.mspace"
    bad.write_bytes(b"this is not a motion space")
    try:
        listing = httpx.get(server.url + "/v1/spaces").json()
        assert [u["name"] for u in listing["unreadable"]] == ["broken"]
        assert "broken" in listing["unreadable"][0]["error"]
        r = httpx.get(server.url + "/v1/spaces/broken")
        assert r.status_code == 409 and "broken.mspace" in r.text
        assert str(server.data_dir) not in r.text and str(server.data_dir) not in str(listing)  # no server paths
        assert httpx.get(server.url + "/v1/spaces/speed").status_code == 200
    finally:
        bad.unlink()


def test_json_frame_is_the_engine_blend_placed_on_the_root_path(server, speed_space):
    lo, hi = speed_space.parameter_map.domain()[0]
    speed = lo + 0.3 * (hi - lo)
    r = httpx.get(server.url + "/v1/spaces/speed/frame",
                  params={"format": "json", "params": f"speed:{speed}", "time": 0.7, "mode": "linear"})
    assert r.status_code == 200, r.text
    body = r.json()
    solution = speed_space.parameter_map.solve(np.array([speed]))
    np.testing.assert_allclose(body["weights"], solution.weights)
    local = speed_space.blend(solution.weights, body["phase"], "linear")
    root, heading, phase = speed_space.root_track.after(solution.weights, 0.7)
    assert body["phase"] == pytest.approx(phase)
    c, s = math.cos(heading), math.sin(heading)
    placed = local @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T + root
    np.testing.assert_allclose(body["vertices"], placed, atol=2e-6)
    assert body["faces"] == speed_space.faces.tolist()


@pytest.mark.parametrize("fmt, kind", [("obj", "obj"), ("glb", "glb")])
def test_mesh_formats_load_back(server, speed_space, fmt, kind):
    r = httpx.get(server.url + "/v1/spaces/speed/frame", params={"format": fmt, "phase": 0.5, "placed": False})
    assert r.status_code == 200, r.text
    mesh = trimesh.load(io.BytesIO(r.content), file_type=kind, force="mesh", process=False)
    assert len(mesh.vertices) == speed_space.n_vertices and len(mesh.faces) == len(speed_space.faces)
    w = speed_space.parameter_map.solve(np.array([np.mean(speed_space.parameter_map.domain()[0])])).weights
    np.testing.assert_allclose(mesh.vertices, speed_space.blend(w, 0.5), atol=1e-5)


@pytest.mark.parametrize("query, fragment", [
    ({"params": "speed:fast"}, "speed must be a number"),
    ({"params": "speed=1"}, "name:value"),
    ({"params": "flying:1"}, "unknown parameter 'flying'"),
    ({"params": "speed:nan"}, "must be finite"),
    ({"time": -1}, "greater than or equal"),
    ({"phase": 2}, "less than or equal"),
    ({"time": 1, "phase": 0.5}, "not both"),
    ({"mode": "cubic"}, "linear"),
    ({"format": "stl"}, "obj"),
])
def test_bad_frame_requests_are_422_naming_the_problem(server, query, fragment):
    r = httpx.get(server.url + "/v1/spaces/speed/frame", params=query)
    assert r.status_code == 422
    assert fragment in r.text


def test_openapi_describes_every_route(server):
    spec = httpx.get(server.url + "/openapi.json").json()
    assert {"/v1/spaces", "/v1/spaces/{name}", "/v1/spaces/{name}/frame", "/v1/health"} <= set(spec["paths"])
    frame = spec["paths"]["/v1/spaces/{name}/frame"]["get"]
    assert {p["name"] for p in frame["parameters"]} >= {"params", "time", "phase", "mode", "format", "placed"}
