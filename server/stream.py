"""``/v1/stream``: one WebSocket connection streaming a motion space under live parameters.

A connection is a task receiving, checking and applying client messages; its frames are
produced by the server's FrameScheduler (server/scheduler.py), which steps every connection's
Player on its own clock in shared ticks and writes the frames. Latest-wins, down to the socket:
a frame is computed only when it is due *and* the connection's transport has taken every byte
written before (server/transport.py: the kernel holds at most ``UNSENT_LIMIT`` bytes unsent), and
with a client ``window`` also only while fewer than ``window`` frames are unacknowledged. Ticks
missed meanwhile are counted in ``dropped``, never queued, so a slow client gets fewer, fresh
frames, the first frame after a stall of any length is fresh, and nobody else waits. A
connection that has taken no due frame for ``stream_stall_timeout`` seconds is closed with code
1008 (``protocol.CLOSE_STALLED``). A message that changes what the client sees (params, mode, seek,
reset, resume) makes the next frame due at once, so it reflects the change within one blend.

All blending runs on the event loop thread (the engine's blenders keep scratch buffers); only
the slow one-off set-up (opening a space, building the non-linear solver) goes to a thread.
"""

from __future__ import annotations

import asyncio
import logging
import time

import numpy as np
from starlette.websockets import WebSocket, WebSocketDisconnect

from engine.player import Player
from server import protocol as P
from server.decoding import decode_client
from server.frames import frame_parts, joined
from server.registry import BrokenSpace, UnknownSpace
from server.scheduler import URGENT, send_now
from server.transport import GAUGE

log = logging.getLogger("morphspace.stream")
MAX_DT = 0.25  # a stalled connection does not jump the clock by more than this per frame
CLOSE_GRACE = 5.0     # seconds a closing client has to read the close frame before the TCP connection drops
RETRY = 0.01          # seconds between looks at a full transport holding back an urgent frame


class TokenBucket:
    """``rate`` tokens per second, at most ``burst`` saved."""

    def __init__(self, rate, burst):
        self.rate, self.burst = float(rate), float(burst)
        self.tokens, self.stamp = float(burst), time.monotonic()

    def take(self, cost=1.0):
        now = time.monotonic()
        self.tokens = min(self.burst, self.tokens + (now - self.stamp) * self.rate)
        self.stamp = now
        if self.tokens < cost:
            return False
        self.tokens -= cost
        return True


class StreamStats:
    """Server-wide counters (reported by /v1/health)."""

    def __init__(self):
        self.connections = 0
        self.frames = 0
        self.dropped = 0
        self.errors = 0


class StreamSession:
    """One connection's state; ``await StreamSession(ws, registry, settings, stats, scheduler).run()``."""

    def __init__(self, websocket: WebSocket, registry, settings, stats: StreamStats, scheduler):
        self.ws, self.registry, self.settings, self.stats = websocket, registry, settings, stats
        self.scheduler = scheduler
        self.bucket = TokenBucket(settings.stream_max_rate, settings.stream_burst)
        self.player = None
        self.space_name = None
        self.codec = "f32"
        self.bounds = None
        self.rate = 60.0
        self.window = 0
        self.waiting_ack = False
        self.heatmap = False
        self.paused = False
        self.ack = 0
        self.seq = 0
        self.acked_frame = 0
        self.dropped = 0
        self.urgent = False
        self.closed = False
        self.ready = False      # the topology has gone out: frames may follow
        self.version = 0        # the scheduler's bookkeeping
        self.payload = None     # encoded vertices the scheduler prepared for the next frame
        self.heatmap_job = None   # server/heatmap.py: this connection's distances being computed
        self.heatmap_last = None  # and the newest finished: (error_um, error_max, error_seq)
        self.loop = None
        self.quantiser = None
        self.gauge = (websocket.scope.get("extensions") or {}).get(GAUGE)  # None under other servers
        self._limits = {"max_message": settings.stream_max_message, "max_rate": settings.stream_max_rate,
                        "burst": settings.stream_burst, "max_fps": settings.stream_max_fps,
                        "stall_timeout": settings.stream_stall_timeout}  # topology.limits, P.LIMITS order
        self._stalled_since = None  # loop time since which due frames could not be written
        self._last_step = None
        self._next_due = 0.0

    # ------------------------------------------------------------ plumbing

    async def _send(self, message):
        """Send a message object, or wire bytes."""
        if self.closed:
            return
        try:
            await self.ws.send_bytes(message if isinstance(message, bytes) else P.to_wire(message))
        except (WebSocketDisconnect, OSError, RuntimeError):
            self._shut(P.CLOSE_INTERNAL, "sending failed")

    def _close(self):
        self.closed = True

    def _shut(self, code, reason):
        """End the connection from the server's side: a close frame with ``code``, and the TCP
        connection dropped if the client has not read it ``CLOSE_GRACE`` seconds later."""
        if self.closed:
            return
        self.closed = True
        asyncio.get_running_loop().create_task(self._close_socket(code, reason))

    async def _close_socket(self, code, reason):
        try:
            await asyncio.wait_for(self.ws.close(code=code, reason=reason), CLOSE_GRACE)
        except asyncio.TimeoutError:  # the transport never drained enough to take the close frame
            if self.gauge is not None:
                self.gauge.abort()
            return
        except (WebSocketDisconnect, OSError, RuntimeError):  # already gone
            return
        if self.gauge is not None:  # a no-op once the closing handshake has completed
            asyncio.get_running_loop().call_later(CLOSE_GRACE, self.gauge.abort)

    async def error(self, code, message, ref=None, seq=None):
        self.stats.errors += 1
        await self._send(P.Error(code=code, message=message, ref=ref, seq=seq))

    def _poke(self, seq=0):
        """Make the next frame due at once, acknowledging client message ``seq`` (a pull-only
        connection, rate 0, gets no streamed frame: its next pull carries the ack)."""
        self.ack = max(self.ack, seq)
        self.urgent = True
        if self.ready and not self.closed and self.rate > 0:
            self.scheduler.schedule(self, URGENT)

    # ------------------------------------------------------------ connection

    async def run(self):
        self.loop = asyncio.get_running_loop()
        await self.ws.accept()
        if self.stats.connections >= self.settings.stream_max_clients:
            await self.error("server_busy", f"the server streams to at most {self.settings.stream_max_clients} "
                                            "clients at once; try again later")
            await self.ws.close(code=P.CLOSE_BUSY)
            return
        self.stats.connections += 1
        self.scheduler.add(self)
        try:
            await self._receive_loop()
        finally:
            self.scheduler.remove(self)
            self.stats.connections -= 1
            self.stats.dropped += self.dropped

    async def _receive_loop(self):
        try:
            while not self.closed:
                message = await self.ws.receive()
                if message["type"] == "websocket.disconnect":
                    break
                data = message.get("bytes")
                if data is None:
                    data = message.get("text") or ""
                await self._on_data(data)
        except (WebSocketDisconnect, OSError, RuntimeError):
            pass
        finally:
            self._close()

    async def _on_data(self, data):
        message = failure = None
        try:
            message = decode_client(data, self.settings.stream_max_message, self._limits)
        except P.ProtocolError as exc:
            failure = exc
        if not self.bucket.take(0.25 if isinstance(message, P.Ack) else 1.0):
            await self.error("rate_limited", f"more than {self.settings.stream_max_rate:g} messages per second "
                                             f"(burst {self.settings.stream_burst}); message dropped")
            return
        try:
            if failure is not None:
                raise failure
            await self._apply(message)
        except P.ProtocolError as exc:
            await self.error(exc.code, exc.message, exc.ref, exc.seq)
        except ValueError as exc:  # the engine's checks on values (unknown parameters, ranges)
            await self.error("invalid_field", str(exc), message.type, getattr(message, "seq", None))
        except Exception as exc:  # noqa: BLE001 - report, keep the connection and the server
            log.exception("stream: failed to apply %r", data[:200])
            await self.error("internal", f"the server failed on this message: {type(exc).__name__}: {exc}")

    # ------------------------------------------------------------ client messages

    async def _apply(self, m):
        if isinstance(m, P.Hello):
            return await self._hello(m)
        if isinstance(m, P.Ack):
            self.acked_frame = max(self.acked_frame, min(m.frame, self.seq))
            if self.waiting_ack and self.seq - self.acked_frame < self.window:
                self.waiting_ack = False
                self.after_frame()
            return
        if self.player is None:
            raise P.ProtocolError("not_ready", f"send hello before {m.type}", ref=m.type, seq=getattr(m, "seq", None))
        if isinstance(m, P.Params):
            self._set_params(m.params, m.immediate, m.seq, m.type)
        elif isinstance(m, P.Mode):
            await self._prepare_mode(m.mode)
            self.player.set_mode(m.mode)
        elif isinstance(m, P.Rate):
            self.rate = m.rate
            self._next_due = asyncio.get_running_loop().time()
            self._last_step = None
        elif isinstance(m, P.Pause):
            self.paused = True
        elif isinstance(m, P.Resume):
            self.paused = False
            self._last_step = self._stalled_since = None
        elif isinstance(m, P.Seek):
            self.player.seek(m.phase)
            self._last_step = None  # the next frame shows exactly this phase; the clock runs on from it
        elif isinstance(m, P.Reset):
            self.player.reset()
            self._last_step = None
        elif isinstance(m, P.Heatmap):
            if m.on:
                await self._prepare_mode("nonlinear")  # pulls blend it on the loop
                self.heatmap_last = None
            self.heatmap = m.on
        elif isinstance(m, P.Pull):
            return await self._pull(m)
        self._poke(m.seq)

    async def _prepare_mode(self, mode):
        space = self.player.space if self.player is not None else None
        if space is not None:
            await asyncio.to_thread(space.blender, mode)  # the non-linear solver factorises once

    def _set_params(self, params, immediate, seq, ref):
        names = self.player.names
        unknown = sorted(set(params) - set(names))
        if unknown:
            raise P.ProtocolError("invalid_params", f"{ref}: unknown parameter(s) {', '.join(unknown)}; "
                                                    f"{self.space_name} has {', '.join(names)}", ref, seq)
        solution = self.player.set_params(params, immediate=immediate)
        if solution.clamped:
            asyncio.get_running_loop().create_task(
                self._send(P.Notice(code="clamped", message=solution.message, seq=seq)))

    async def _hello(self, m):
        try:
            space = await asyncio.to_thread(self.registry.get, m.space)
        except UnknownSpace as exc:
            raise P.ProtocolError("unknown_space", str(exc), "hello", m.seq) from None
        except BrokenSpace as exc:
            raise P.ProtocolError("unknown_space", str(exc), "hello", m.seq) from None
        if space.parameter_map is None:
            raise P.ProtocolError("not_playable", f"{m.space} has no parameter map; rebuild it from a spec "
                                                  "with a [parameters] section", "hello", m.seq)
        await asyncio.to_thread(space.blender, m.mode)
        if m.heatmap:
            await asyncio.to_thread(space.blender, "nonlinear")
        player = Player(space, mode=m.mode, smoothing=m.smoothing)
        if m.params:
            unknown = sorted(set(m.params) - set(player.names))
            if unknown:
                raise P.ProtocolError("invalid_params", f"hello: unknown parameter(s) {', '.join(unknown)}; "
                                                        f"{m.space} has {', '.join(player.names)}", "hello", m.seq)
            player.set_params(m.params, immediate=True)
        self.ready = False  # no frames until the new topology has gone out
        self.player, self.space_name, self.rate = player, m.space, m.rate
        self.codec, self.window, self.heatmap = m.codec, m.window, m.heatmap
        description = self.registry.describe(m.space)
        self.bounds = np.asarray(description["bounds"], dtype=np.float32)
        self.paused, self._last_step = False, None
        self.quantiser = P.Quantiser(self.bounds, space.n_vertices) if m.codec == "q16" else None
        current = dict(zip(player.names, player.requested.tolist()))
        parameters = [{key: dict(p, value=current[p["name"]])[key] for key in P.PARAMETER_KEYS}
                      for p in description["parameters"]]
        await self._send(P.Topology(
            protocol=P.PROTOCOL_VERSION, space=m.space, n_vertices=int(space.n_vertices),
            n_faces=int(len(space.faces)), faces=np.ascontiguousarray(space.faces, dtype="<u4").tobytes(),
            codec=m.codec, bounds_min=self.bounds[0].tolist(), bounds_max=self.bounds[1].tolist(),
            quantisation_error=P.quantisation_error(self.bounds) if m.codec == "q16" else 0.0,
            parameters=parameters, sources=space.source_names, durations=space.durations().tolist(),
            cyclic=bool(space.cyclic), mode=m.mode, modes=list(P.MODES), rate=self.rate,
            model_size=float(space.model_size),
            limits=dict(self._limits)))
        self.seq = self.acked_frame = 0
        self.waiting_ack = False
        self._stalled_since = None
        self._next_due = asyncio.get_running_loop().time()
        self.ready = True
        self._poke(m.seq)

    async def _pull(self, m):
        mode = m.mode or self.player.mode
        await self._prepare_mode(mode)
        player = self.player
        names = player.names
        unknown = sorted(set(m.params or {}) - set(names))
        if unknown:
            raise P.ProtocolError("invalid_params", f"pull: unknown parameter(s) {', '.join(unknown)}; "
                                                    f"{self.space_name} has {', '.join(names)}", "pull", m.id)
        request = player.target
        for name, value in (m.params or {}).items():
            request[names.index(name)] = value
        solution = player.map.solve(request)
        w = solution.weights
        space = player.space
        if m.time is not None:
            root, heading, phase = player.track.after(w, m.time)
            seconds = m.time
        else:
            phase = m.phase % 1.0 if space.cyclic and m.phase < 1.0 else m.phase
            root, heading, _ = player.track.after(w, phase * player.track.duration(w))
            seconds = phase * player.track.duration(w)
        vertices = space.blender(mode).blend(w, phase)
        await self._send_frame(time_=seconds, phase=phase, mode=mode, requested=request, realised=solution.realised,
                               clamped=solution.clamped, weights=w, root=root, heading=heading,
                               vertices=vertices, finished=False, pull_id=m.id, space=space)

    # ------------------------------------------------------------ frames

    def _vertex_bytes(self, vertices):
        if self.codec == "q16":
            return self.quantiser.encode(vertices)
        return P.encode_vertices(vertices, "f32", None)

    def _frame_parts(self, *, time_, phase, mode, requested, realised, clamped, weights, root, heading,
                     vertices, finished, pull_id=None, error_um=None, error_max=None, error_seq=None):
        """The next frame's msgpack body as buffers (server/frames.py; numbers as arrays or
        sequences, ``vertices`` and ``error_um`` encoded: bytes or arrays, not copied here)."""
        self.seq += 1
        self.stats.frames += 1
        small = {"type": "frame", "seq": self.seq, "ack": self.ack, "time": float(time_), "phase": float(phase),
                 "mode": mode, "requested": np.asarray(requested, dtype=float).tolist(),
                 "realised": np.asarray(realised, dtype=float).tolist(), "clamped": bool(clamped),
                 "weights": np.asarray(weights, dtype=float).tolist(), "root": np.asarray(root, dtype=float).tolist(),
                 "heading": float(heading), "dropped": self.dropped, "finished": bool(finished),
                 "sent_at": time.time(), "pull_id": pull_id, "error_max": error_max, "error_seq": error_seq}
        bulk = [("vertices", vertices)]
        if error_um is None:
            small["error_um"] = None
        else:
            bulk.append(("error_um", error_um))
        return frame_parts(small, bulk)

    def _heatmap(self, mode, weights, phase, vertices, space):
        """(error_um bytes, error_max) of ``vertices`` against the non-linear blend."""
        if mode == "nonlinear":
            distance = np.zeros(len(vertices), dtype=np.float32)
        else:
            reference = space.blender("nonlinear").blend(weights, phase)
            distance = np.linalg.norm(vertices - reference, axis=1)
        return np.minimum(np.rint(distance * 1e6), 65535).astype("<u2").tobytes(), float(distance.max())

    async def _send_frame(self, *, time_, phase, mode, requested, realised, clamped, weights, root, heading,
                          vertices, finished, pull_id, space):
        """A pulled frame (streamed ones go through the scheduler: send_frame)."""
        error_um = error_max = error_seq = None
        if self.heatmap:
            error_um, error_max = self._heatmap(mode, weights, phase, vertices, space)
            error_seq = self.seq + 1
        await self._send(joined(self._frame_parts(
            time_=time_, phase=phase, mode=mode, requested=requested, realised=realised, clamped=clamped,
            weights=weights, root=root, heading=heading, vertices=self._vertex_bytes(vertices), finished=finished,
            pull_id=pull_id, error_um=error_um, error_max=error_max, error_seq=error_seq)))

    # ------------------------------------------------------------ the scheduler's side

    def advance(self, now):
        """Step the player for a frame at loop time ``now``; False when none is to be sent."""
        if not self.ready or self.player is None or self.rate <= 0:
            return False
        urgent = self.urgent
        streaming = not self.paused and self.rate > 0
        if not urgent:
            if not streaming:
                return False
            if self.window > 0 and self.seq - self.acked_frame >= self.window:
                self.waiting_ack = True  # the next ack reschedules
                if not self._stalled(now):  # or else, the stall timeout
                    self.scheduler.schedule(self, self._stalled_since + self.settings.stream_stall_timeout)
                return False
        if self.gauge is not None and not self.gauge.ready():
            self._transport_full(now, streaming)
            return False
        self.urgent = False
        dt = 0.0
        if streaming:
            period = 1.0 / self.rate
            if urgent:  # an extra frame now; the grid restarts from it
                self._next_due = now + period
            else:       # stay on the grid; ticks missed by a whole period are dropped, not caught up
                late = now - self._next_due
                missed = int(late / period) if late >= period else 0
                self.dropped += missed
                self._next_due += (missed + 1) * period
            dt = 0.0 if self._last_step is None else min(now - self._last_step, MAX_DT)
            self._last_step = now
        self.player.advance(dt)
        return True

    def _stalled(self, now):
        """A due frame cannot be written at loop time ``now``: start (or check) the stall clock;
        True when it ran out and the connection is being closed."""
        if self._stalled_since is None:
            self._stalled_since = now
        timeout = self.settings.stream_stall_timeout
        if now - self._stalled_since < timeout:
            return False
        log.info("stream: closing a connection to %s that took no frame for %.0f s", self.space_name, timeout)
        self._shut(P.CLOSE_STALLED, f"stalled: no frame could be delivered for {timeout:g} s")
        return True

    def _transport_full(self, now, streaming):
        """The transport still holds earlier bytes: skip this tick (counted in ``dropped``) and
        look again at the next one (an urgent frame sooner). Only a streaming connection can
        stall: a paused one waits for its reader as long as keepalive pings are answered."""
        self.scheduler.transport_full += 1
        if streaming and self._stalled(now):
            return
        due = now + RETRY
        if streaming:
            if not self.urgent or now >= self._next_due:  # grid ticks have passed: skip them
                period = 1.0 / self.rate
                missed = max(0, int((now - self._next_due) / period)) + 1  # this tick and any before it
                self.dropped += missed
                self._next_due += missed * period
            due = min(due, self._next_due) if self.urgent else self._next_due
        self.scheduler.schedule(self, due)

    def frame_source(self):
        """(phase table or None, codec): a table when this frame is one interpolation of it
        (linear or hybrid at weights that recur; heatmaps too: server/heatmap.py works off the
        loop); q16 tables are in codec units."""
        player = self.player
        if player.mode == "nonlinear":
            return None, self.codec
        table = player.space.frame_blender(player.mode).lookup(player.weights)
        if table is not None and self.codec == "q16":
            table = self.quantiser.table(table)
        return table, self.codec

    def send_frame(self, payload):
        """Write the frame at the player's state; ``payload``: its encoded vertices, or None to
        blend them here."""
        player = self.player
        error_um = error_max = error_seq = None
        if payload is None:
            space, mode, weights, phase = player.space, player.mode, player.weights, player.phase
            vertices = space.frame_blender(mode).blend(weights, phase)
            payload = self._vertex_bytes(vertices)
        if self.heatmap:  # off the event loop (server/heatmap.py)
            distances = self.scheduler.heatmaps.frame_error(self, player.space, player.mode, player.weights,
                                                            player.phase, self.seq + 1)
            if distances is not None:
                error_um, error_max, error_seq = distances
        parts = self._frame_parts(time_=player.time, phase=player.phase, mode=player.mode,
                                  requested=player.requested, realised=player.realised, clamped=player.clamped,
                                  weights=player.weights, root=player.position, heading=player.heading,
                                  vertices=payload, finished=player.finished, error_um=error_um, error_max=error_max,
                                  error_seq=error_seq)
        try:
            if self.gauge is not None:  # straight to the transport, one copy (server/transport.py)
                sent = self.gauge.write_message(parts)
                if not sent:  # the connection is closing
                    self._close()
                    return
            else:
                sent = send_now(self.ws.send_bytes(joined(parts)))
        except (WebSocketDisconnect, OSError, RuntimeError):
            self._shut(P.CLOSE_INTERNAL, "sending failed")
            return
        if not sent:  # it would have waited for the transport (no gauge): dropped, not queued
            self.dropped += 1
            self._stalled(asyncio.get_running_loop().time())
            return
        self._stalled_since = None
        if self.gauge is not None:
            held = self.gauge.held()
            if held > self.scheduler.transport_bytes_max:
                self.scheduler.transport_bytes_max = held

    def after_frame(self):
        """Ask the scheduler for the next frame (now if one is urgent)."""
        if self.closed or not self.ready:
            return
        if self.urgent:
            self.scheduler.schedule(self, URGENT)
        elif not self.paused and self.rate > 0:
            self.scheduler.schedule(self, self._next_due)

    def fail(self, exc):
        """The scheduler failed on this connection: report, close it, keep everyone else."""
        log.error("stream: frame for %s failed", self.space_name, exc_info=exc)
        self.stats.errors += 1
        self._close()
        asyncio.get_running_loop().create_task(self._fail_message(exc))

    async def _fail_message(self, exc):
        try:
            await self.ws.send_bytes(P.to_wire(P.Error(code="internal", message=f"the server failed to produce a "
                                                       f"frame: {type(exc).__name__}: {exc}")))
            await self.ws.close(code=P.CLOSE_INTERNAL)
        except (WebSocketDisconnect, OSError, RuntimeError):
            pass
