"""A small async Python client for the morphspace stream (what a game-engine bridge builds on).

    async with StreamClient.connect("ws://127.0.0.1:8000/v1/stream", "locomotion", codec="q16") as c:
        await c.set_params(speed=2.0, turn_rate=20)
        async for frame in c.frames():
            draw(frame.world_vertices(), c.faces)
        frame = await c.pull({"speed": 1.5}, time=0.4)   # engines with their own clock

    async with StreamClient.connect(url, graph="demo", params={"speed": 1.2}) as c:   # a motion graph
        await c.action("jump", {"jump_height": 0.5})   # frame.node, frame.target, frame.progress follow it

Frames arrive as numpy arrays (root-local ``vertices`` plus the root transform). A reader task
keeps only the newest streamed frame if the caller falls behind (latest-wins on this side too)
and sends acks when the connection asked for a window. Errors from the server are raised by the
call that caused them where it is known (``pull``) and kept in ``errors`` otherwise.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from dataclasses import dataclass

import msgpack
import numpy as np
import websockets

from engine.rotations import rot_y
from server import protocol as P


class StreamError(RuntimeError):
    """The server answered with an Error message."""

    def __init__(self, error):
        super().__init__(f"{error.code}: {error.message}")
        self.code, self.message, self.ref, self.seq = error.code, error.message, error.ref, error.seq


@dataclass
class ClientFrame:
    seq: int
    ack: int
    time: float
    phase: float
    mode: str
    requested: dict
    realised: dict
    clamped: bool
    weights: np.ndarray
    root: np.ndarray
    heading: float
    vertices: np.ndarray        # (n, 3) float32, root-local
    dropped: int
    finished: bool
    sent_at: float
    received_at: float
    pull_id: int | None = None
    error: np.ndarray | None = None   # (n,) float32 metres from the non-linear blend (heatmap)
    error_seq: int | None = None      # the frame ``error`` describes (this one once parameters settle)
    node: str | None = None           # graph streams: the node shown, the transition's target, its progress
    target: str | None = None
    progress: float | None = None

    def world_vertices(self):
        """(n, 3) float32 vertices placed by the root transform."""
        return self.vertices @ rot_y(self.heading).T.astype(np.float32) + self.root.astype(np.float32)


class StreamClient:
    """One streaming connection. Use ``StreamClient.connect(...)`` (an async context manager)."""

    def __init__(self, websocket, *, window=0):
        self.ws = websocket
        self.window = window
        self.topology = None
        self.faces = None
        self.names = []
        self.errors = []
        self.notices = []
        self._seq = itertools.count(1)
        self._pull_ids = itertools.count(1)
        self._pulls = {}
        self._latest = None
        self._frame_ready = asyncio.Event()
        self._topology_ready = asyncio.Event()
        self._closed = False
        self._topology_error = None  # an error answering the hello, raised by connect()
        self._reader = None
        self.last_seq = 0

    # ------------------------------------------------------------ connection

    @classmethod
    def connect(cls, url, space=None, *, graph=None, node=None, codec="f32", rate=60.0, mode="hybrid", params=None,
                smoothing=0.25, window=0, heatmap=False, token=None, open_timeout=10.0):
        """Stream ``space``, or the motion graph ``graph`` (from ``node``)."""
        return _Connection(cls, url, dict(space=space, graph=graph, node=node, codec=codec, rate=rate, mode=mode,
                                          params=params, smoothing=smoothing, window=window, heatmap=heatmap),
                           token, open_timeout)

    async def _start(self, hello, timeout):
        self._reader = asyncio.create_task(self._read_loop())
        await self.hello(**hello)
        await asyncio.wait_for(self._topology_ready.wait(), timeout)

    async def close(self):
        self._closed = True
        await self.ws.close()
        if self._reader is not None:
            self._reader.cancel()
            try:
                await self._reader
            except (asyncio.CancelledError, Exception):  # closing either way
                pass

    async def send(self, message):
        """Send a protocol message object (server.protocol); returns its seq if it has one."""
        await self.ws.send(P.to_wire(message))
        return getattr(message, "seq", None)

    async def _read_loop(self):
        try:
            async for data in self.ws:
                if isinstance(data, str):
                    continue
                raw = msgpack.unpackb(data, raw=False)
                kind = raw.get("type")
                if kind == "frame":
                    self._on_frame(raw)
                elif kind == "topology":
                    self._on_topology(P.decode_server(data))
                elif kind == "error":
                    error = P.decode_server(data)
                    self.errors.append(error)
                    if error.ref == "pull" and error.seq in self._pulls:
                        self._pulls.pop(error.seq).set_exception(StreamError(error))
                    elif error.ref == "hello" and not self._topology_ready.is_set() or (
                            error.code == "server_busy" and not self._topology_ready.is_set()):
                        self._topology_error = StreamError(error)
                        self._topology_ready.set()
                elif kind == "notice":
                    self.notices.append(P.decode_server(data))
        except websockets.ConnectionClosed:
            pass
        finally:
            self._closed = True
            self._frame_ready.set()
            self._topology_ready.set()
            for future in self._pulls.values():
                if not future.done():
                    future.set_exception(ConnectionError("the stream closed"))

    def _on_topology(self, t):
        self.topology = t
        self.faces = np.frombuffer(t.faces, dtype="<u4").reshape(t.n_faces, 3)
        self.names = [p["name"] for p in t.parameters]
        self.node_names = {n["name"]: [p["name"] for p in n["parameters"]] for n in (t.nodes or [])}
        self._topology_error = None
        self._topology_ready.set()

    def _on_frame(self, raw):
        t = self.topology
        error = None
        if raw.get("error_um") is not None:
            error = np.frombuffer(raw["error_um"], dtype="<u2").astype(np.float32) * 1e-6
        names = self.node_names.get(raw.get("node"), self.names)
        frame = ClientFrame(
            seq=raw["seq"], ack=raw["ack"], time=raw["time"], phase=raw["phase"], mode=raw["mode"],
            requested=dict(zip(names, raw["requested"])), realised=dict(zip(names, raw["realised"])),
            clamped=raw["clamped"], weights=np.asarray(raw["weights"]), root=np.asarray(raw["root"]),
            heading=raw["heading"],
            vertices=P.decode_vertices(raw["vertices"], t.codec, t.n_vertices, t.bounds_min, t.bounds_max),
            dropped=raw["dropped"], finished=raw["finished"], sent_at=raw["sent_at"], received_at=time.time(),
            pull_id=raw.get("pull_id"), error=error, error_seq=raw.get("error_seq"), node=raw.get("node"),
            target=raw.get("target"), progress=raw.get("progress"))
        if self.window:
            asyncio.get_running_loop().create_task(self._ack(frame.seq))
        if frame.pull_id is not None:
            future = self._pulls.pop(frame.pull_id, None)
            if future is not None and not future.done():
                future.set_result(frame)
            return
        self._latest = frame
        self._frame_ready.set()

    async def _ack(self, seq):
        try:
            await self.ws.send(P.to_wire(P.Ack(frame=seq)))
        except websockets.ConnectionClosed:
            pass

    # ------------------------------------------------------------ requests

    async def hello(self, space=None, codec="f32", rate=60.0, mode="hybrid", params=None, smoothing=0.25, window=0,
                    heatmap=False, graph=None, node=None):
        """(Re)start streaming ``space`` (or the motion graph ``graph``, from ``node``); a new topology follows."""
        self._topology_ready.clear()
        self.window = window
        await self._control(P.Hello, space=space, graph=graph, node=node, codec=codec, rate=rate, mode=mode,
                            params=params, smoothing=smoothing, window=window, heatmap=heatmap)

    async def _control(self, message_type, **fields):
        """Send a control message with the next sequence number; returns it (frames with
        ``ack >= seq`` reflect the message)."""
        self.last_seq = next(self._seq)
        return await self.send(message_type(seq=self.last_seq, **fields))

    async def set_params(self, params=None, *, immediate=False, **named):
        """Request parameters; returns the message's seq (frames with ``ack >= seq`` reflect it)."""
        return await self._control(P.Params, params=dict(params or {}, **named), immediate=immediate)

    async def set_mode(self, mode):
        return await self._control(P.Mode, mode=mode)

    async def set_rate(self, rate):
        return await self._control(P.Rate, rate=rate)

    async def pause(self):
        return await self._control(P.Pause)

    async def resume(self):
        return await self._control(P.Resume)

    async def seek(self, phase):
        return await self._control(P.Seek, phase=phase)

    async def reset(self):
        return await self._control(P.Reset)

    async def heatmap(self, on=True):
        return await self._control(P.Heatmap, on=on)

    async def action(self, node, params=None, *, budget=None):
        """On a graph stream: go to ``node`` at ``params`` (within ``budget`` seconds); returns the
        message's seq. The server's notice (planned or queued) lands in ``notices``."""
        return await self._control(P.Action, node=node, params=params, budget=budget)

    async def pull(self, params=None, *, time=None, phase=None, mode=None, timeout=10.0):
        """The frame at ``params`` and ``time`` (s) or ``phase``, independent of the stream's clock."""
        pull_id = next(self._pull_ids)
        future = asyncio.get_running_loop().create_future()
        self._pulls[pull_id] = future
        await self.send(P.Pull(id=pull_id, params=params, time=time, phase=phase, mode=mode))
        return await asyncio.wait_for(future, timeout)

    # ------------------------------------------------------------ frames

    async def next_frame(self, timeout=10.0, after=0):
        """The newest streamed frame with ``ack >= after`` (waits for one)."""
        deadline = asyncio.get_running_loop().time() + timeout
        while True:
            frame = self._latest
            if frame is not None and frame.ack >= after:
                self._latest = None
                return frame
            if self._closed:
                raise ConnectionError("the stream closed")
            self._frame_ready.clear()
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                raise TimeoutError(f"no frame with ack >= {after} within {timeout} s")
            try:
                await asyncio.wait_for(self._frame_ready.wait(), remaining)
            except asyncio.TimeoutError:
                pass

    async def frames(self, timeout=10.0):
        """Streamed frames as they come (frames the caller was too slow for are skipped)."""
        while True:
            try:
                yield await self.next_frame(timeout)
            except ConnectionError:
                return


class _Connection:
    def __init__(self, cls, url, hello, token, open_timeout):
        self.cls, self.url, self.hello, self.token, self.open_timeout = cls, url, hello, token, open_timeout

    async def __aenter__(self):
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else None
        ws = await websockets.connect(self.url, additional_headers=headers, open_timeout=self.open_timeout,
                                      max_size=64 * 2**20, compression=None)
        self.client = self.cls(ws, window=self.hello["window"])
        try:
            await self.client._start(self.hello, self.open_timeout)
            if self.client._topology_error is not None:
                raise self.client._topology_error
            if self.client.topology is None:
                raise ConnectionError("the stream closed before its topology arrived")
        except BaseException:
            await self.client.close()
            raise
        return self.client

    async def __aexit__(self, *exc):
        await self.client.close()
