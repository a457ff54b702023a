"""The stream benchmark's load generator (benchmarks/stream_load.py): raw WebSocket clients that
count frames and time parameter updates, and the connect/leave soak clients, each group run in a
process of its own (``client_process``, ``soak_process``). A client process reports the CPU
seconds it used (``cpu_seconds``) and how long it waited for a CPU (``wait_seconds``), so that a
run can say what the load generator itself cost and whether the host kept it waiting."""

from __future__ import annotations

import asyncio
import base64
import os
import random
import resource
import time

import msgpack


class RawClient(asyncio.BufferedProtocol):
    """A minimal WebSocket client (RFC 6455) for load generation: it counts frames by their
    headers and decodes the msgpack body only of frames that may acknowledge a pending update,
    so that the load generator costs little beside the server on a 2-core machine. The socket is
    read straight into one buffer of its own (``asyncio.BufferedProtocol``): no allocation and no
    copy per read, and only a frame cut in two by a read is moved (to the buffer's start)."""

    SIZE = 1 << 20  # the largest read; a message longer than the buffer grows it

    def __init__(self, host, port, on_message):
        self.host, self.port, self.on_message = host, port, on_message
        self.buffer = bytearray(self.SIZE)
        self.view = memoryview(self.buffer)
        self.filled = 0  # bytes of self.buffer holding data not yet parsed
        self.upgraded = asyncio.get_running_loop().create_future()
        self.closed = asyncio.get_running_loop().create_future()
        self.transport = None

    def connection_made(self, transport):
        self.transport = transport
        key = base64.b64encode(os.urandom(16)).decode()
        transport.write((f"GET /v1/stream HTTP/1.1\r\nHost: {self.host}:{self.port}\r\nUpgrade: websocket\r\n"
                         f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())

    def get_buffer(self, sizehint):
        if len(self.buffer) - self.filled < 65536:  # a message longer than the buffer: grow it
            self.view.release()
            self.buffer.extend(bytes(len(self.buffer)))
            self.view = memoryview(self.buffer)
        return self.view[self.filled:]

    def buffer_updated(self, nbytes):
        self.filled += nbytes
        buf, end, offset = self.buffer, self.filled, 0
        if not self.upgraded.done():
            head = buf.find(b"\r\n\r\n", 0, end)
            if head < 0:
                return
            if not buf.startswith(b"HTTP/1.1 101"):
                self.upgraded.set_exception(ConnectionError(bytes(buf[:min(end, 200)]).decode(errors="replace")))
                return
            offset = head + 4
            self.upgraded.set_result(True)
        while end - offset >= 2:
            opcode, length = buf[offset] & 0x0F, buf[offset + 1] & 0x7F
            header = 2
            if length == 126:
                if end - offset < 4:
                    break
                length, header = int.from_bytes(buf[offset + 2:offset + 4], "big"), 4
            elif length == 127:
                if end - offset < 10:
                    break
                length, header = int.from_bytes(buf[offset + 2:offset + 10], "big"), 10
            if end - offset < header + length:
                break
            self.on_message(opcode, buf, offset + header, length)
            offset += header + length
        if offset:  # keep only a message cut by the read, at the buffer's start
            rest = end - offset
            if rest:
                self.view[:rest] = self.view[offset:end]
            self.filled = rest

    def connection_lost(self, exc):
        if not self.closed.done():
            self.closed.set_result(exc)

    def send(self, payload, opcode=0x2):
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x80 | opcode]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + n.to_bytes(2, "big"))
        body = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.transport.write(head + mask + body)


async def one_client(host, port, space, fps, seconds, measure_from, measure_to, updates, update_every, params,
                     rng, out, heatmap=False, graph=None, acting=False):
    """One client streaming ``space`` (or, with ``graph`` = {"name", "every", "nodes"}, that motion
    graph). ``updates``: it sends random params every ``update_every`` seconds; ``acting`` (graph
    only): it sends an ``action`` to a random node of ``graph["nodes"]`` at random parameters every
    0.5-1.5 x ``graph["every"]`` seconds, as a player pressing keys would, and reads every message
    to count its notices and the transitions the frames show (a change of ``node``)."""
    loop = asyncio.get_running_loop()
    state = {"frames": 0, "latencies": [], "pending": {}, "transit": [], "actions": 0, "notices": {},
             "errors": [], "entered": 0, "entered_asked": 0, "action_latencies": [], "node": None, "nodes": None,
             "asked": None}

    def on_graph_message(msg, received):
        """An acting client's message other than a frame's count: topology, notice, error; a
        frame's node (a transition carried out when it changes)."""
        kind = msg.get("type")
        if kind == "topology":
            state["nodes"] = {n["name"]: n["parameters"] for n in msg["nodes"]}
            state["node"] = None
        elif kind == "notice":
            state["notices"][msg["code"]] = state["notices"].get(msg["code"], 0) + 1
        elif kind == "error":
            state["errors"].append(f"{msg['code']}: {msg['message']}")
        elif kind == "frame":
            node = msg["node"]
            if state["node"] is not None and node != state["node"]:
                state["entered"] += 1
            state["node"] = node
            asked = state["asked"]
            if asked is not None and node == asked[0] and msg["progress"] is None and msg["ack"] >= asked[2]:
                state["entered_asked"] += 1  # the node the last action asked for, entered
                state["action_latencies"].append(received - asked[1])
                state["asked"] = None

    def on_message(opcode, buf, start, length):
        if opcode != 0x2:
            return
        received = time.monotonic()
        if acting:
            msg = msgpack.unpackb(bytes(buf[start:start + length]))
            on_graph_message(msg, received)
            if msg.get("type") != "frame":
                return
            for s in [s for s in state["pending"] if s <= msg["ack"]]:
                state["latencies"].append(received - state["pending"].pop(s))
                state["transit"].append(time.time() - msg["sent_at"])
        elif state["pending"]:
            msg = msgpack.unpackb(bytes(buf[start:start + length]))
            if msg.get("type") != "frame":
                return
            for s in [s for s in state["pending"] if s <= msg["ack"]]:
                state["latencies"].append(received - state["pending"].pop(s))
                state["transit"].append(time.time() - msg["sent_at"])  # encoded -> read by the client
        elif b"\xa5frame" not in buf[start:start + 16]:
            return  # the map's first entry is its type: count frames only
        if measure_from <= received < measure_to:
            state["frames"] += 1

    transport, client = await loop.create_connection(lambda: RawClient(host, port, on_message), host, port)
    await client.upgraded
    hello = {"type": "hello", "codec": "q16", "rate": fps, "seq": 0, "heatmap": heatmap}
    hello.update({"graph": graph["name"]} if graph else {"space": space})
    client.send(msgpack.packb(hello))
    seq = 0
    now = time.monotonic()
    stop = now + seconds
    next_update = now + rng.uniform(0.5, 0.5 + update_every) if updates else float("inf")
    next_action = now + rng.uniform(0.5, 0.5 + graph["every"]) if acting else float("inf")
    while time.monotonic() < stop:
        now = time.monotonic()
        if now >= next_update:
            seq += 1
            name, (lo, hi) = rng.choice(params)
            state["pending"][seq] = now
            client.send(msgpack.packb({"type": "params", "params": {name: rng.uniform(lo, hi)}, "seq": seq}))
            next_update += update_every
        if now >= next_action:
            if state["nodes"]:  # once the topology has come
                seq += 1
                choices = [n for n in graph["nodes"] if n in state["nodes"] and n != state["node"]]
                node = rng.choice(choices)  # not the node playing: a key that asks for a change
                values = {p["name"]: rng.uniform(p["min"], p["max"]) for p in state["nodes"][node]}
                state["pending"][seq] = now
                state["asked"] = (node, now, seq)  # a later action replaces it (the server carries out the last)
                state["actions"] += 1
                client.send(msgpack.packb({"type": "action", "node": node, "params": values, "seq": seq}))
            next_action += graph["every"] * rng.uniform(0.5, 1.5)
        await asyncio.sleep(max(0.0, min(stop, next_update, next_action) - time.monotonic()))
    transport.close()
    out.append({"frames": state["frames"], "latencies": state["latencies"], "transit": state["transit"],
                "heatmap": heatmap, "acting": acting, "actions": state["actions"], "notices": state["notices"],
                "errors": state["errors"][:5], "entered": state["entered"], "entered_asked": state["entered_asked"],
                "action_latencies": state["action_latencies"]})


def _runqueue_wait():
    """Seconds this process has been runnable but waiting for a CPU (Linux schedstat; 0 elsewhere)."""
    try:
        with open("/proc/self/schedstat") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, IndexError, ValueError):
        return 0.0


def client_process(host, port, space, n, fps, seconds, warmup, update_share, update_every, params, seed, queue,
                   heatmaps=0, graph=None, acting=0):
    """``n`` clients, the first ``heatmaps`` of them with the heatmap on; with ``graph`` (see
    ``one_client``) they stream that motion graph and the first ``acting`` of them send actions."""
    rng = random.Random(seed)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu_start, wait_start = usage.ru_utime + usage.ru_stime, _runqueue_wait()

    async def main():
        out = []
        start = time.monotonic()
        measure_from, measure_to = start + warmup, start + seconds - 1.0
        tasks = []
        for i in range(n):
            tasks.append(asyncio.create_task(one_client(
                host, port, space, fps, seconds, measure_from, measure_to, rng.random() < update_share, update_every,
                params, random.Random(rng.random()), out, i < heatmaps, graph, i < acting)))
            await asyncio.sleep(0.005)  # do not open every connection in the same instant
        results = await asyncio.gather(*tasks, return_exceptions=True)
        failures = [repr(r) for r in results if isinstance(r, BaseException)]
        return out, failures, measure_to - measure_from

    out, failures, window = asyncio.run(main())
    usage = resource.getrusage(resource.RUSAGE_SELF)
    queue.put({"cpu_seconds": usage.ru_utime + usage.ru_stime - cpu_start,
               "wait_seconds": _runqueue_wait() - wait_start, "clients": out,
               "frames": [c["frames"] for c in out], "latencies": [x for c in out for x in c["latencies"]],
               "transit": [x for c in out for x in c["transit"]], "heatmap": [c["heatmap"] for c in out],
               "failures": failures, "window": window})


async def soak_client(url, space, fps, hold, rng):
    import websockets
    async with websockets.connect(url, max_size=2**26, compression=None) as ws:
        await ws.send(msgpack.packb({"type": "hello", "space": space, "codec": rng.choice(["q16", "f32"]),
                                     "rate": fps, "mode": rng.choice(["hybrid", "linear"])}))
        stop = time.monotonic() + hold
        while time.monotonic() < stop:
            try:
                await asyncio.wait_for(ws.recv(), timeout=max(0.01, stop - time.monotonic()))
            except asyncio.TimeoutError:
                break


def soak_process(url, space, clients, fps, seconds, seed):
    rng = random.Random(seed)

    async def main():
        stop = time.monotonic() + seconds
        running = set()
        while time.monotonic() < stop:
            while len(running) < clients:
                running.add(asyncio.create_task(soak_client(url, space, fps, rng.uniform(1.0, 8.0), rng)))
            done, running = await asyncio.wait(running, timeout=0.5, return_when=asyncio.FIRST_COMPLETED)
        await asyncio.gather(*running, return_exceptions=True)

    asyncio.run(main())
