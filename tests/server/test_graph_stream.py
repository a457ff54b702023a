"""A motion graph on /v1/stream against a real server and a real built graph (walk, stand, jump,
reach): topology, actions and their notices, frames saying node / target / progress, the root
carried across transitions, the shown node's parameters, and clear errors that leave the stream
(and everyone else's) going."""

from __future__ import annotations

import asyncio
import concurrent.futures
import time

import msgpack
import numpy as np
import pytest
import websockets
from live_server import LiveServer, data_dir_with_graph

from engine.graph.clock import foot_vertices
from engine.graph.legs import LegRig
from engine.motion_space import MotionSpace
from server.client import StreamClient, StreamError


def run(coroutine):
    """Run a client coroutine to completion (90 s at most) on its own loop in a thread."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, asyncio.wait_for(coroutine, 90)).result()


@pytest.fixture(scope="module")
def graph_server(built_graph, tmp_path_factory):
    data = data_dir_with_graph(tmp_path_factory.mktemp("graph-stream"), built_graph)
    with LiveServer(data) as live:
        yield live


@pytest.fixture(scope="module")
def spaces(built_graph):
    opened = {name: MotionSpace.open(built_graph / f"{name}.mspace") for name in ("walk", "stand", "jump", "reach")}
    yield opened
    for space in opened.values():
        space.close()


async def collect(client, until, seconds=12.0):
    """Streamed frames until ``until(frames)`` is true (or ``seconds`` pass)."""
    frames, deadline = [], time.monotonic() + seconds
    while time.monotonic() < deadline:
        frames.append(await client.next_frame())
        if until(frames):
            break
    return frames


def test_topology_describes_the_graph_and_frames_name_the_node(graph_server, spaces):
    async def go():
        async with StreamClient.connect(graph_server.ws_url, graph="tiny", params={"speed": 1.2}, rate=30,
                                        mode="linear") as c:
            return c.topology, [await c.next_frame() for _ in range(6)]
    topology, frames = run(go())
    assert topology.graph == "tiny" and topology.space == "walk" and topology.cyclic
    assert [n["name"] for n in topology.nodes] == ["walk", "stand", "jump", "reach"]
    jump = topology.nodes[2]
    assert jump["space"] == "jump" and not jump["cyclic"] and jump["return_to"] == "stand"
    assert [p["name"] for p in jump["parameters"]] == ["jump_height"]
    assert topology.parameters[0]["name"] == "speed" and topology.parameters[0]["value"] == 1.2
    assert {"from": "walk", "to": "jump"} in topology.edges and len(topology.edges) == 7
    for f in frames:
        assert f.node == "walk" and f.target is None and f.progress is None
        assert f.requested == {"speed": 1.2}
        # not blending: exactly the node's own blend, root-local
        np.testing.assert_allclose(f.vertices, spaces["walk"].blend(f.weights, f.phase, "linear"), atol=1e-5)
    assert frames[-1].root[2] > frames[0].root[2]  # walking forward (+Z)


def test_walk_jump_walk_reach_keeps_the_character_in_its_place(graph_server, spaces):
    async def go():
        async with StreamClient.connect(graph_server.ws_url, graph="tiny", params={"speed": 1.2}, rate=30,
                                        mode="linear", codec="f32") as c:
            frames = [await c.next_frame() for _ in range(5)]
            seq = await c.action("jump", {"jump_height": 0.4})
            frames += await collect(c, lambda fs: fs[-1].ack >= seq and fs[-1].node == "stand")
            seq = await c.action("walk", {"speed": 1.0})
            frames += await collect(c, lambda fs: fs[-1].ack >= seq and fs[-1].node == "walk" and fs[-1].target is None)
            seq = await c.action("reach", {"reach_height": 1.5})
            frames += await collect(c, lambda fs: fs[-1].ack >= seq and fs[-1].node == "reach")
            frames += await collect(c, lambda fs: fs[-1].node == "stand")
            return frames, list(c.notices), list(c.errors)
    frames, notices, errors = run(go())
    assert errors == []
    assert [n.code for n in notices] == ["planned", "planned", "planned"]
    assert notices[0].message.startswith("walk -> jump:") and notices[2].message.startswith("walk -> stand -> reach:")
    nodes = [f.node for f in frames]
    visited = [n for i, n in enumerate(nodes) if i == 0 or nodes[i - 1] != n]
    assert visited == ["walk", "jump", "stand", "walk", "stand", "reach", "stand"]
    blending = [f for f in frames if f.progress is not None]
    assert blending and all(0.0 <= f.progress <= 1.0 and f.target is not None for f in blending)
    jump = [f for f in frames if f.node == "jump" and f.progress is None]
    assert jump and all(f.target == "stand" for f in jump)  # a one-shot's return, planned
    assert max(f.realised.get("jump_height", 0.0) for f in jump) == pytest.approx(
        spaces["jump"].parameter_map.solve(np.array([0.4])).realised[0])
    reach = [f for f in frames if f.node == "reach"]
    assert reach[0].requested == {"reach_height": 1.5}
    # the root is continuous: no step faster than the fastest motion here (a 0.5 m jump over its
    # flight, the walk at 1.6 m/s), and heading stays put (straight motions)
    root = np.array([f.root for f in frames])
    times = np.array([f.time for f in frames])
    speed = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=1) / np.maximum(np.diff(times), 1e-3)
    assert speed.max() < 2.5, speed.max()
    assert np.abs(np.diff([f.heading for f in frames])).max() < 1e-3
    assert root[-1, 2] > root[0, 2] + 0.5  # it went somewhere, and never back to the origin
    rest = np.asarray(spaces["walk"].container["rest"])
    legs = np.zeros(len(rest), dtype=bool)  # below the crotch: where a held foot moves the mesh (engine/graph/legs.py)
    legs[LegRig(rest, foot_vertices(rest)).index] = True
    feet = np.concatenate(foot_vertices(rest))
    for f in frames:
        if f.progress is None:  # between transitions: the node's own blend, but for a held foot's leg
            own = spaces[f.node].blend(f.weights, f.phase, "linear")
            np.testing.assert_allclose(f.vertices[~legs], own[~legs], atol=1e-5)
            np.testing.assert_allclose(f.vertices[feet, 1], own[feet, 1], atol=1e-5)  # feet moved along the ground only
            assert np.abs(f.vertices[legs] - own[legs]).max() < 0.4
        world = f.world_vertices()
        assert world[:, 1].min() > -0.05  # never through the floor


def test_params_steer_the_shown_node_and_reset_starts_again(graph_server):
    async def go():
        async with StreamClient.connect(graph_server.ws_url, graph="tiny", node="walk", params={"speed": 1.0},
                                        rate=30, codec="q16") as c:
            await collect(c, lambda fs: len(fs) >= 10)
            seq = await c.set_params(speed=1.5)
            steered = await c.next_frame(after=seq)
            later = await collect(c, lambda fs: len(fs) >= 5)
            seq = await c.reset()
            again = await c.next_frame(after=seq)
            return steered, later, again, c.topology, list(c.errors)
    steered, later, again, topology, errors = run(go())
    assert errors == []
    assert steered.node == "walk" and steered.requested == {"speed": 1.5} and steered.target is None
    assert all(f.node == "walk" and f.progress is None for f in later)
    assert again.time == 0.0 and np.allclose(again.root, 0.0) and again.requested == {"speed": 1.0}
    lo, hi = np.array(topology.bounds_min), np.array(topology.bounds_max)
    assert (steered.vertices >= lo - 1e-6).all() and (steered.vertices <= hi + 1e-6).all()


def test_errors_name_the_problem_and_the_stream_goes_on(graph_server):
    async def raw_errors(messages):
        async with websockets.connect(graph_server.ws_url, max_size=2**26) as ws:
            answers = []
            for message in messages:
                await ws.send(msgpack.packb(message))
                while True:
                    reply = msgpack.unpackb(await asyncio.wait_for(ws.recv(), 20))
                    if reply["type"] in ("error", "topology", "notice"):
                        answers.append(reply)
                        break
            # the connection still streams: frames keep coming
            frames = 0
            while frames < 3:
                reply = msgpack.unpackb(await asyncio.wait_for(ws.recv(), 20))
                frames += reply["type"] == "frame"
            return answers

    answers = run(raw_errors([
        {"type": "hello", "graph": "nope", "seq": 1},
        {"type": "hello", "graph": "tiny", "space": "walk", "seq": 2},
        {"type": "hello", "graph": "tiny", "node": "fly", "seq": 3},
        {"type": "hello", "graph": "tiny", "params": {"height": 1.0}, "seq": 4},
        {"type": "hello", "graph": "tiny", "heatmap": True, "seq": 5},
        {"type": "hello", "space": "walk", "seq": 6},
        {"type": "action", "node": "jump", "seq": 7},  # on a space stream
        {"type": "hello", "graph": "tiny", "rate": 30, "seq": 8},
        {"type": "action", "node": "fly", "seq": 9},
        {"type": "action", "node": "jump", "params": {"speed": 1.0}, "seq": 10},
        {"type": "action", "node": "jump", "budget": 0.0, "seq": 11},
        {"type": "params", "params": {"jump_height": 0.3}, "seq": 12},  # the walk has no jump_height
        {"type": "seek", "phase": 0.5, "seq": 13},
        {"type": "heatmap", "on": True, "seq": 14},
        {"type": "pull", "id": 15, "phase": 0.2},
        {"type": "action", "node": "jump", "params": {"jump_height": 9.0}, "seq": 16},
    ]))
    codes = [(a["type"], a.get("code"), a.get("seq")) for a in answers]
    assert codes == [
        ("error", "unknown_graph", 1), ("error", "invalid_field", 2), ("error", "unknown_node", 3),
        ("error", "invalid_params", 4), ("error", "unsupported", 5), ("topology", None, None),
        ("error", "unsupported", 7), ("topology", None, None), ("error", "unknown_node", 9),
        ("error", "invalid_params", 10), ("error", "invalid_field", 11), ("error", "invalid_params", 12),
        ("error", "unsupported", 13), ("error", "unsupported", 14), ("error", "unsupported", 15),
        ("notice", "planned", 16)]
    messages = [a.get("message", "") for a in answers]
    assert "no motion graph 'nope' (have: tiny)" in messages[0]
    assert "exactly one of space or graph" in messages[1]
    assert "no node 'fly' in graph 'tiny'; nodes: walk, stand, jump, reach" in messages[2]
    assert "has no parameter(s) height; it has speed" in messages[3]
    assert "budget must be in [0.05, 60]" in messages[10]
    assert "node 'walk' has no parameter(s) jump_height" in messages[11]
    assert messages[15].startswith("walk -> jump:") and "clamped: jump_height 9 m -> 0.48" in messages[15]


def test_a_graph_stream_does_not_disturb_a_space_stream(graph_server):
    async def go():
        async with StreamClient.connect(graph_server.ws_url, "walk", rate=30) as space, \
                StreamClient.connect(graph_server.ws_url, graph="tiny", rate=30) as graph:
            await graph.action("jump")
            with pytest.raises(StreamError, match="unknown_graph"):
                async with StreamClient.connect(graph_server.ws_url, graph="nope"):
                    pass
            frames = [await space.next_frame() for _ in range(10)]
            jumped = await collect(graph, lambda fs: fs[-1].node == "jump")
            return frames, jumped
    frames, jumped = run(go())
    assert all(f.node is None and f.target is None and f.progress is None for f in frames)
    assert jumped[-1].node == "jump"


def test_a_replaced_action_is_told_and_a_queued_one_planned_later(graph_server):
    """During a jump (no edge jump -> reach), a reach is queued; a second reach replaces it (the
    first gets ``superseded``); when the jump's return enters the stand, the second is planned
    (a second notice with its seq) and carried out. A planned transition replaced before it
    starts is ``superseded`` too; an action for the node shown drops the plan it replaces."""
    async def go():
        async with StreamClient.connect(graph_server.ws_url, graph="tiny", params={"speed": 1.2}, rate=30,
                                        mode="linear", codec="f32") as c:
            jump = await c.action("jump", {"jump_height": 0.4})
            await collect(c, lambda fs: fs[-1].ack >= jump and fs[-1].node == "jump" and fs[-1].progress is None)
            first = await c.action("reach", {"reach_height": 1.2})
            second = await c.action("reach", {"reach_height": 1.6})
            frames = await collect(c, lambda fs: fs[-1].node == "reach" and fs[-1].progress is None)
            stand = await c.action("stand")   # the reach's own return: planned
            walk = await c.action("walk", {"speed": 1.0})  # queued: the reach cannot be left for a walk
            frames += await collect(c, lambda fs: fs[-1].node == "walk" and fs[-1].progress is None, seconds=20)
            shown = await c.action("walk", {"speed": 1.4})  # the node shown: set
            await collect(c, lambda fs: fs[-1].ack >= shown)
            for _ in range(20):  # the last notices may trail the frames
                if len(c.notices) >= 9:
                    break
                await asyncio.sleep(0.05)
            return (jump, first, second, stand, walk, shown), frames, list(c.notices), list(c.errors)
    seqs, frames, notices, errors = run(go())
    jump, first, second, stand, walk, shown = seqs
    assert errors == []
    told = [(n.code, n.seq) for n in notices]
    assert told[:5] == [("planned", jump), ("queued", first), ("superseded", first), ("queued", second),
                        ("planned", second)]
    assert notices[2].message.startswith("dropped before it was carried out: action") and "(reach)" in notices[2].message
    assert notices[4].message.startswith("stand -> reach:")  # the second notice: how the queued one goes
    assert ("planned", stand) in told and ("queued", walk) in told and ("planned", walk) in told[told.index(("queued", walk)):]
    assert told.count(("superseded", first)) == 1 and all(code != "superseded" or seq == first for code, seq in told)
    assert max(f.requested.get("reach_height", 0.0) for f in frames if f.node == "reach") == pytest.approx(1.6)
    assert told[-1] == ("planned", shown) and "already there" in notices[-1].message


def test_a_graph_hello_after_a_space_starts_the_acks_afresh(graph_server):
    """A second hello starts the stream afresh, as on a new connection, a graph's too: its frames'
    ack is the hello's seq, not the space stream's highest (as it was until 2026-11-30)."""
    async def go():
        async with websockets.connect(graph_server.ws_url, max_size=2**26) as ws:
            await ws.send(msgpack.packb({"type": "hello", "space": "walk", "rate": 30, "seq": 1}))
            await ws.send(msgpack.packb({"type": "params", "params": {"speed": 1.2}, "seq": 50}))
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline:
                m = msgpack.unpackb(await asyncio.wait_for(ws.recv(), 5))
                if m["type"] == "frame" and m["ack"] == 50:
                    break
            await ws.send(msgpack.packb({"type": "hello", "graph": "tiny", "rate": 30, "seq": 2}))
            while time.monotonic() < deadline:
                m = msgpack.unpackb(await asyncio.wait_for(ws.recv(), 5))
                if m["type"] == "topology":
                    break
            while time.monotonic() < deadline:
                m = msgpack.unpackb(await asyncio.wait_for(ws.recv(), 5))
                if m["type"] == "frame":
                    return m
    first = run(go())
    assert first["node"] is not None and first["seq"] == 1 and first["ack"] == 2 and first["dropped"] == 0, first
