"""One ``/v1/stream`` connection: ``StreamSession`` (and the server-wide ``StreamStats``).

The session accepts the WebSocket, refuses it when the server streams to its most clients,
then receives client messages until the client leaves: each is rate-limited (``TokenBucket``),
decoded and checked (server/decoding.py) and handed to its handler (server/stream/messages.py,
``HANDLERS``); a refused message is answered with an error message and the connection stays
open. Frames come from the scheduler through the session's FrameOutput side
(server/stream/output.py).
"""

from __future__ import annotations

import asyncio
import logging
import time

from starlette.websockets import WebSocket, WebSocketDisconnect

from server import protocol as P
from server.decoding import decode_client
from server.graph_stream import HANDLERS as GRAPH_HANDLERS
from server.scheduler import URGENT
from server.stream.messages import BEFORE_HELLO, HANDLERS
from server.stream.output import FrameOutput
from server.transport import GAUGE

log = logging.getLogger("morphspace.stream")
CLOSE_GRACE = 5.0  # seconds a closing client has to read the close frame before the TCP connection drops


def message_seq(m):
    """What stands for client message ``m`` in an error's ``seq``: a pull's ``id``, else its
    ``seq`` (docs/protocol.md, Errors)."""
    return m.id if m.type == P.Pull.type else getattr(m, "seq", None)


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


class StreamSession(FrameOutput):
    """One connection's state; ``await StreamSession(ws, registry, settings, stats, scheduler).run()``
    (``graphs``: the server's GraphRegistry, for hellos naming a motion graph)."""

    def __init__(self, websocket: WebSocket, registry, settings, stats: StreamStats, scheduler, graphs=None):
        self.ws, self.registry, self.settings, self.stats = websocket, registry, settings, stats
        self.scheduler = scheduler
        self.graphs = graphs
        self.graph = None       # a GraphStream (server/graph_stream.py) while streaming a motion graph
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
        self.closing = None  # the task writing the server's close frame (shut)
        self.ready = False      # the topology has gone out: frames may follow
        self.version = 0        # the scheduler's bookkeeping
        self.payload = None     # encoded vertices the scheduler prepared for the next frame
        self.middle = (None, b"")  # (player.state_key, its packed fields): FrameOutput._streamed_parts
        self.frame_blender = (None, None, None)  # (space, mode, space.frame_blender(mode)): frame_source
        self.weights_key = (None, None)  # (weights, their phase-table key): frame_source
        self.scaled_table = (None, None)  # (a phase table, it in this connection's q16 units)
        self.scaled_key = None             # the quantiser key of scaled_table
        self.table_missed = False  # frame_source found no phase table for this frame
        self.heatmap_job = None   # server/heatmap/: the id of this connection's distances being computed
        self.heatmap_last = None  # and the newest finished: (error_um, error_max, error_seq)
        self.quantiser = None
        self.gauge = (websocket.scope.get("extensions") or {}).get(GAUGE)  # None under other servers
        self.gauge_write = getattr(self.gauge, "write_frame", None)  # (TransportGauge.write_frame)
        self.limits = {"max_message": settings.stream_max_message, "max_rate": settings.stream_max_rate,
                       "burst": settings.stream_burst, "max_fps": settings.stream_max_fps,
                       "stall_timeout": settings.stream_stall_timeout}  # topology.limits, P.LIMITS order
        self.stalled_since = None  # loop time since which due frames could not be written
        self.last_step = None      # loop time of the player's last step
        self.next_due = 0.0        # loop time the next frame is due on the rate grid

    # ------------------------------------------------------------ plumbing

    async def send(self, message):
        """Send a message object, or wire bytes."""
        if self.closed:
            return
        gauge = self.gauge
        if gauge is not None:  # (what it holds is then read from the kernel: server/transport.py)
            gauge.sending_elsewhere(True)
        try:
            await self.ws.send_bytes(message if isinstance(message, bytes) else P.to_wire(message))
        except (WebSocketDisconnect, OSError, RuntimeError):
            self.shut(P.CLOSE_INTERNAL, "sending failed")
        finally:
            if gauge is not None:
                gauge.sending_elsewhere(False)

    def shut(self, code, reason):
        """End the connection from the server's side: a close frame with ``code``, and the TCP
        connection dropped if the client has not read it ``CLOSE_GRACE`` seconds later."""
        if self.closed:
            return
        self.closed = True
        self.closing = asyncio.get_running_loop().create_task(self._close_socket(code, reason))

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
        await self.send(P.Error(code=code, message=message, ref=ref, seq=seq))

    def poke(self, seq=0):
        """Make the next frame due at once, acknowledging client message ``seq`` (a pull-only
        connection, rate 0, gets no streamed frame: its next pull carries the ack)."""
        self.ack = max(self.ack, seq)
        self.urgent = True
        if self.ready and not self.closed and self.rate > 0:
            self.scheduler.schedule(self, URGENT)

    async def prepare_mode(self, mode):
        """Build the blender of ``mode`` in a thread (the non-linear solver factorises once)."""
        space = self.player.space if self.player is not None else None
        if space is not None:
            await asyncio.to_thread(space.blender, mode)

    # ------------------------------------------------------------ connection

    async def run(self):
        await self.ws.accept()
        if self.stats.connections >= self.settings.stream_max_clients:
            limit = self.settings.stream_max_clients
            await self.error("server_busy", f"the server streams to at most {limit} clients at once; try again later")
            await self.ws.close(code=P.CLOSE_BUSY, reason=f"server busy: at most {limit} streaming clients")
            return
        self.stats.connections += 1
        self.scheduler.add(self)
        try:
            await self._receive_loop()
            if self.closing is not None:
                # shut() from a message's handler (a pull that waited out the stall timeout) ends
                # the receive loop at once; returning now would let the server close the TCP
                # connection before the close frame is written (it waits behind the unread bytes)
                await self.closing
        finally:
            self.scheduler.remove(self)
            self.stats.connections -= 1
            self.stats.dropped += self.dropped + self.unsent_ticks(asyncio.get_running_loop().time())

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
            self.closed = True

    async def _on_data(self, data):
        message = failure = None
        try:
            message = decode_client(data, self.settings.stream_max_message, self.limits)
        except P.ProtocolError as exc:
            failure = exc
        if not self.bucket.take(0.25 if isinstance(message, P.Ack) else 1.0):
            ref, seq = (message.type, message_seq(message)) if message is not None else \
                (failure.ref, failure.seq)  # what could be read of it
            await self.error("rate_limited", f"more than {self.settings.stream_max_rate:g} messages per second "
                                             f"(burst {self.settings.stream_burst}); message dropped", ref, seq)
            return
        try:
            if failure is not None:
                raise failure
            await self._apply(message)
        except P.ProtocolError as exc:
            await self.error(exc.code, exc.message, exc.ref, exc.seq)
        except ValueError as exc:  # the engine's checks on values (unknown parameters, ranges)
            await self.error("invalid_field", str(exc), message.type, message_seq(message))
        except Exception as exc:  # noqa: BLE001 - report, keep the connection and the server
            log.exception("stream: failed to apply %r", data[:200])
            await self.error("internal", f"the server failed on this message: {type(exc).__name__}: {exc}",
                             message.type, message_seq(message))

    async def _apply(self, m):
        """Hand client message ``m`` to its handler (server/stream/messages.py; on a graph stream,
        server/graph_stream.py's where it has one)."""
        if self.player is None and m.type not in BEFORE_HELLO:
            raise P.ProtocolError("not_ready", f"send hello before {m.type}", ref=m.type, seq=message_seq(m))
        handler = GRAPH_HANDLERS.get(m.type) if self.graph is not None else None
        await (handler or HANDLERS[m.type])(self, m)
