"""On a graph stream, the notices a message causes arrive before the frame that acknowledges it
(docs/protocol.md, "The session"): a hello's clamped start parameters, and two actions sent back
to back (the first superseded or queued by the second)."""

from __future__ import annotations

import asyncio
import concurrent.futures

import msgpack
import pytest
import websockets
from live_server import LiveServer, data_dir_with_graph


def run(coroutine):
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, asyncio.wait_for(coroutine, 90)).result()


@pytest.fixture(scope="module")
def graph_server(built_graph, tmp_path_factory):
    data = data_dir_with_graph(tmp_path_factory.mktemp("graph-notices"), built_graph)
    with LiveServer(data) as live:
        yield live


async def receive_until(ws, done, limit=600):
    messages = []
    while len(messages) < limit:
        messages.append(msgpack.unpackb(await asyncio.wait_for(ws.recv(), 10)))
        if done(messages):
            break
    return messages


def answered_before_acked(messages, seq):
    """The notice answering action ``seq`` (its first: planned or queued) comes before the first
    frame acknowledging ``seq``. (A ``superseded`` notice carries the seq of the action it
    drops, and is caused by the later action: it precedes that one's frame.)"""
    first_frame = next(i for i, m in enumerate(messages) if m["type"] == "frame" and m["ack"] >= seq)
    answer = next((i for i, m in enumerate(messages) if m["type"] == "notice" and m["seq"] == seq), None)
    return answer is not None and answer < first_frame


def test_notices_come_before_the_frame_that_acknowledges_their_message(graph_server):
    async def go():
        async with websockets.connect(graph_server.ws_url, max_size=2**26) as ws:
            await ws.send(msgpack.packb({"type": "hello", "graph": "tiny", "rate": 30, "mode": "linear", "seq": 1,
                                         "params": {"speed": 99.0}}))
            start = await receive_until(ws, lambda ms: ms[-1]["type"] == "frame")
            runs = []
            for k in range(3):  # seq only grows: a frame's ack is the highest applied
                seq = 10 + 200 * k + 1
                await ws.send(msgpack.packb({"type": "action", "node": "reach", "params": {"reach_height": 1.2},
                                             "seq": seq - 1}))
                await ws.send(msgpack.packb({"type": "action", "node": "jump", "params": {"jump_height": 0.4},
                                             "seq": seq}))
                runs.append((seq, await receive_until(ws, lambda ms: ms[-1]["type"] == "frame" and ms[-1]["ack"] >= seq)))
                await ws.send(msgpack.packb({"type": "reset", "seq": seq + 100}))
                await receive_until(ws, lambda ms: ms[-1]["type"] == "frame" and ms[-1]["ack"] >= seq + 100)
            return start, runs
    start, runs = run(go())
    assert [m["type"] for m in start] == ["topology", "notice", "frame"], start
    assert start[1]["code"] == "clamped" and start[1]["seq"] == 1 and "speed" in start[1]["message"]
    for seq, messages in runs:
        for s in (seq - 1, seq):
            assert answered_before_acked(messages, s), (s, [(m["type"], m.get("seq"), m.get("ack")) for m in messages])
