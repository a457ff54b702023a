"""A connection's frames: ``FrameOutput``, the part of a StreamSession the scheduler drives.

The FrameScheduler (server/scheduler.py) calls ``due_step(now)`` (how far the player steps for a
frame on the connection's rate grid, or None when none is to be sent: paused, the window full,
the transport still holding earlier bytes; the scheduler steps the players, steering ones of a
space together), ``frame_source()`` (a phase table to gather the vertices from, or
None), ``streamed_head(...)`` and ``write_frame(head, vertices)`` (a tick's heads are made
together: server/frames.py) or ``send_frame(payload)`` (packed and written here),
``next_frame_due()`` (when to ask for the next one) and ``fail(exc)``. Ticks missed are
counted in ``dropped``, never queued; a connection that takes no due frame for
``stream_stall_timeout`` seconds is closed (``protocol.CLOSE_STALLED``). Pulled frames
(``send_pulled``) are written here too.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time

import numpy as np
from starlette.websockets import WebSocketDisconnect

from engine.blend.cache import weights_key
from engine.player import Player
from server import protocol as P
from server.frames import StreamedFrame, frame_parts, joined
from server.scheduler import URGENT, send_now

log = logging.getLogger("morphspace.stream")
MAX_DT = 0.25  # a stalled connection does not jump the clock by more than this per frame
RETRY = 0.01   # seconds between looks at a full transport holding back an urgent frame


_FLOAT64 = np.dtype(np.float64)


def _floats(values):
    """``values`` (an array or a sequence of numbers) as a list of Python floats."""
    if values.__class__ is np.ndarray and values.dtype is _FLOAT64:
        return values.tolist()
    return np.asarray(values, dtype=float).tolist()


class FrameOutput:
    """The frame side of a StreamSession (mixed into it; the state lives on the session)."""

    # ------------------------------------------------------------ the scheduler's side

    def advance(self, now):
        """Step the player for a frame at loop time ``now``; False when none is to be sent."""
        dt = self.due_step(now)
        if dt is None:
            return False
        self.player.advance(dt)
        return True

    def due_step(self, now):
        """The seconds the player is to step for a frame at loop time ``now`` (the scheduler steps
        it: steering players of a space together), or None when no frame is to be sent."""
        rate = self.rate
        if not self.ready or rate <= 0 or self.player is None:
            return None
        urgent = self.urgent
        streaming = not self.paused  # (and rate > 0)
        if not urgent and not streaming:
            return None
        # the window holds for every frame, urgent ones (answering a message) too: they wait for an ack
        window = self.window
        if window > 0 and self.seq - self.acked_frame >= window:
            self.waiting_ack = True  # the next ack reschedules
            if not self._stalled(now):  # or else, the stall timeout
                self.scheduler.schedule(self, self.stalled_since + self.settings.stream_stall_timeout)
            return None
        gauge = self.gauge
        if gauge is not None and not gauge.ready():
            self._transport_full(now, streaming)
            return None
        if not streaming:
            self.urgent = False
            return 0.0
        period = 1.0 / rate
        late = now - self.next_due
        if late >= period:  # ticks missed by a whole period (waiting for acks, an overloaded
            # loop): dropped, not caught up, whether this frame is urgent or not
            missed = int(late / period)
            self.dropped += missed
            self.next_due += missed * period
        if urgent:  # an extra frame now; the next one back on the grid every connection at this
            # rate shares (multiples of the period, half a period to one and a half away), so
            # that one tick serves them all
            self.urgent = False
            self.next_due = math.floor(now / period + 1.5) * period
        else:       # stay on the grid
            self.next_due += period
        last = self.last_step
        self.last_step = now
        if last is None:
            return 0.0
        dt = now - last
        return dt if dt <= MAX_DT else MAX_DT  # (min(dt, MAX_DT))

    def unsent_ticks(self, now):
        """Ticks of the rate grid that fell due a whole period or more before loop time ``now`` and
        were neither sent nor counted yet (a connection waiting for acks counts them at its next
        frame): what closing now adds to ``dropped``."""
        if self.player is None or self.paused or self.rate <= 0:
            return 0
        late = now - self.next_due
        period = 1.0 / self.rate
        return int(late / period) if late >= period else 0

    def _stalled(self, now):
        """A due frame cannot be written at loop time ``now``: start (or check) the stall clock;
        True when it ran out and the connection is being closed."""
        if self.stalled_since is None:
            self.stalled_since = now
        if now - self.stalled_since < self.settings.stream_stall_timeout:
            return False
        self._close_stalled()
        return True

    def _close_stalled(self):
        """Close the connection with 1008: no frame could be delivered for the stall timeout."""
        timeout = self.settings.stream_stall_timeout
        log.info("stream: closing a connection to %s that took no frame for %.0f s", self.space_name, timeout)
        self.shut(P.CLOSE_STALLED, f"stalled: no frame could be delivered for {timeout:g} s")

    def _transport_full(self, now, streaming):
        """The transport still holds earlier bytes: skip this tick (counted in ``dropped``) and
        look again at the next one (an urgent frame sooner). Only a streaming connection can
        stall: a paused one waits for its reader as long as keepalive pings are answered."""
        self.scheduler.transport_full += 1
        if streaming and self._stalled(now):
            return
        due = now + RETRY
        if streaming:
            if not self.urgent or now >= self.next_due:  # grid ticks have passed: skip them
                period = 1.0 / self.rate
                missed = max(0, int((now - self.next_due) / period)) + 1  # this tick and any before it
                self.dropped += missed
                self.next_due += missed * period
            due = min(due, self.next_due) if self.urgent else self.next_due
        self.scheduler.schedule(self, due)

    def frame_source(self):
        """(phase table or None, codec): a table when this frame is one interpolation of it
        (linear or hybrid at weights that recur; heatmaps too: server/heatmap/ works off the
        loop; a motion graph's while it plays one node's space, no transition blending and no foot
        held); q16 tables are in codec units."""
        player = self.player
        if self.graph is not None:  # a graph's frame reads a table only while it plays one node
            source = self.graph.table_source()
            if source is None:
                return None, self.codec
            (blender, weights), key = source, None
        elif player.mode == "nonlinear":
            return None, self.codec
        else:
            space, mode, blender = self.frame_blender
            if space is not player.space or mode != player.mode:
                blender = player.space.frame_blender(player.mode)
                self.frame_blender = player.space, player.mode, blender
            weights = player.weights
            kept, key = self.weights_key
            if kept is not weights:  # (a Player's weights are replaced, never changed in place)
                key = weights.tobytes() if weights.__class__ is np.ndarray and weights.dtype is _FLOAT64 \
                    else weights_key(weights)  # (the same bytes)
                self.weights_key = weights, key
        table = blender.lookup(weights, key)
        self.table_missed = table is None  # send_frame blends without asking again
        if table is not None and self.codec == "q16":
            source, scaled = self.scaled_table
            if source is not table or self.quantiser.key is not self.scaled_key:
                scaled, self.scaled_key = self.quantiser.table(table), self.quantiser.key
                self.scaled_table = table, scaled
            table = scaled
        return table, self.codec

    def moving_source(self):
        """(blender, weights, phase) when this frame, without a phase table, is a linear or
        hybrid blend the scheduler may make together with others' (``FrameScheduler.many_blender``),
        else None (the non-linear mode, motion graphs). Call after ``frame_source``."""
        player = self.player
        if not self.table_missed or self.graph is not None or player.mode == "nonlinear":
            return None
        return player.space.blender(player.mode), player.weights, player.phase

    def send_frame(self, payload):
        """Write the frame at the player's state; ``payload``: its encoded vertices, or None to
        blend them here."""
        player = self.player
        error_um = error_max = error_seq = None
        if payload is None:
            if self.graph is not None:  # blended by its GraphStream as it advanced
                payload = self._vertex_bytes(player.vertices())
            else:
                space, mode, weights, phase = player.space, player.mode, player.weights, player.phase
                blender = space.frame_blender(mode)
                if self.table_missed and mode != "nonlinear":  # no phase table at these weights: the
                    # scheduler's batched blend for this one alone (the same bytes as in a batch)
                    many = self.scheduler.many_blender(blender.blender)
                    if self.codec == "q16":
                        payload = many.blend([weights], [phase], self.quantiser.codes)[0]
                    else:
                        payload = many.blend([weights], [phase])[0].astype("<f4", copy=False)
                else:
                    payload = self._vertex_bytes(blender.blend(weights, phase))
        self.table_missed = False
        if self.heatmap:  # off the event loop, in a helper process (server/heatmap/)
            distances = self.scheduler.heatmaps.frame_error(self, player.space, player.mode, player.weights,
                                                            player.phase, self.seq + 1)
            if distances is not None:
                error_um, error_max, error_seq = distances
        if self.heatmap:
            parts = self._frame_parts(time_=player.time, phase=player.phase, mode=player.mode,
                                      requested=player.requested, realised=player.realised, clamped=player.clamped,
                                      weights=player.weights, root=player.position, heading=player.heading,
                                      vertices=payload, finished=player.finished, error_um=error_um,
                                      error_max=error_max, error_seq=error_seq)
        else:
            graph = self.graph
            parts = self._streamed_parts(player, payload, None if graph is None else
                                         StreamedFrame.graph(graph.node, graph.target, graph.progress))
        self.write_parts(parts)

    def streamed_head(self, payload, fields, clocks, middles, values):
        """Count this frame and append what its head is made of to the lists of
        ``server.frames.streamed_heads`` (the scheduler makes a tick's heads in one pass, then
        ``write_frame``): the player's clock address to ``clocks``; its fields and middle to
        ``fields``, ``middles`` and ``values``: parameters that changed since the last frame (a
        steering player's, every frame) as their numbers, else the middle packed once. False
        (nothing appended or counted) where ``send_frame`` is to write it: the heatmap, a motion
        graph, a player without a clock."""
        player = self.player
        if self.heatmap or self.graph is not None or player.__class__ is not Player:
            return False
        self.table_missed = False
        self.seq += 1
        self.stats.frames += 1
        key, middle = self.middle
        state = player.state_key
        if key is None or key[0] is not state[0] or key[1] is not state[1] or key[2] is not state[2] \
                or key[3] is not state[3]:  # changed: its numbers (packed when they stay the same)
            mode, requested, realised, clamped, weights = player.reported()
            requested, realised, weights = _floats(requested), _floats(realised), _floats(weights)
            head, between, tail = StreamedFrame.middle_pieces(mode, len(requested), len(realised), clamped,
                                                              len(weights))
            self.middle = state, None
            fields += (self.seq, self.ack, self.dropped, payload.nbytes, len(head), len(requested), len(between),
                       len(realised), len(tail), len(weights))
            middles += (head, between, tail)
            values += requested
            values += realised
            values += weights
        else:
            if middle is None:
                mode, requested, realised, clamped, weights = player.reported()
                middle = StreamedFrame.middle(mode, _floats(requested), _floats(realised), clamped, _floats(weights))
                self.middle = state, middle
            fields += (self.seq, self.ack, self.dropped, payload.nbytes, len(middle), 0, 0, 0, 0, 0)
            middles.append(middle)
        clocks.append(player.clock_address)
        return True

    def write_frame(self, head, vertices):
        """Write a streamed frame from its head and vertices (memoryviews: ``streamed_head``'s),
        or drop it (latest-wins)."""
        write = self.gauge_write
        if write is None:
            self.write_parts([head, vertices])
            return
        scheduler = self.scheduler  # TransportGauge.write_frame: write, and look at what it holds
        try:
            held = write(head, vertices, scheduler.transport_bytes_max)
        except (WebSocketDisconnect, OSError, RuntimeError):
            self.shut(P.CLOSE_INTERNAL, "sending failed")
            return
        if held is None:  # the connection is closing
            self.closed = True
            return
        self.stalled_since = None
        if held > scheduler.transport_bytes_max:
            scheduler.transport_bytes_max = held

    def write_parts(self, parts):
        """Write a frame's body ``parts`` (buffers) to the connection, or drop it (latest-wins)."""
        try:
            if self.gauge is not None:  # straight to the transport, one copy (server/transport.py)
                sent = self.gauge.write_message(parts)
                if not sent:  # the connection is closing
                    self.closed = True
                    return
            else:
                sent = send_now(self.ws.send_bytes(joined(parts)))
        except (WebSocketDisconnect, OSError, RuntimeError):
            self.shut(P.CLOSE_INTERNAL, "sending failed")
            return
        if not sent:  # it would have waited for the transport (no gauge): dropped, not queued
            self.dropped += 1
            self._stalled(asyncio.get_running_loop().time())
            return
        self.stalled_since = None
        self._note_held()

    def _note_held(self):
        """Raise the scheduler's ``transport_bytes_max`` to what this connection holds now (the
        kernel asked only when that may be more: ``TransportGauge.held_above``)."""
        if self.gauge is not None:
            held = self.gauge.held_above(self.scheduler.transport_bytes_max)
            if held is not None and held > self.scheduler.transport_bytes_max:
                self.scheduler.transport_bytes_max = held

    def after_frame(self):
        """Ask the scheduler for the next frame (now if one is urgent)."""
        due = self.next_frame_due()
        if due is not None:
            self.scheduler.schedule(self, due)

    def next_frame_due(self):
        """When the next frame is due after one was written (loop time; ``URGENT``: now), or None
        (none is to come unasked): what ``after_frame`` asks the scheduler for."""
        if self.closed or not self.ready:
            return None
        if self.urgent:
            return URGENT
        if not self.paused and self.rate > 0:
            return self.next_due
        return None

    def fail(self, exc):
        """The scheduler failed on this connection: report, close it, keep everyone else."""
        log.error("stream: frame for %s failed", self.space_name, exc_info=exc)
        self.stats.errors += 1
        self.closed = True
        asyncio.get_running_loop().create_task(self._fail_message(exc))

    async def _fail_message(self, exc):
        try:
            await self.ws.send_bytes(P.to_wire(P.Error(code="internal", message=f"the server failed to produce a "
                                                       f"frame: {type(exc).__name__}: {exc}")))
            await self.ws.close(code=P.CLOSE_INTERNAL, reason="internal error: no frame could be made")
        except (WebSocketDisconnect, OSError, RuntimeError):
            pass

    # ------------------------------------------------------------ pulled frames

    async def send_pulled(self, *, time_, phase, mode, requested, realised, clamped, weights, root, heading,
                          vertices, pull_id, space):
        """A pulled frame (streamed ones go through the scheduler: send_frame). Written, like a
        streamed one, only into a transport that has taken every earlier byte: until then the
        connection's next messages wait, and a client that reads nothing for the stall timeout is
        closed (so unread pull answers cannot pile up in the server)."""
        if not await self._drained():
            return
        error_um = error_max = error_seq = None
        if self.heatmap:
            error_um, error_max = self._heatmap(mode, weights, phase, vertices, space)
            error_seq = self.seq + 1
        await self.send(joined(self._frame_parts(
            time_=time_, phase=phase, mode=mode, requested=requested, realised=realised, clamped=clamped,
            weights=weights, root=root, heading=heading, vertices=self._vertex_bytes(vertices), finished=False,
            pull_id=pull_id, error_um=error_um, error_max=error_max, error_seq=error_seq)))
        self._note_held()

    async def _drained(self):
        """Wait until the transport has taken every byte written so far; False when the stall
        timeout ran out first (the connection is then being closed) or it has closed."""
        if self.gauge is None or self.gauge.ready():
            return not self.closed
        loop = asyncio.get_running_loop()
        started = loop.time()
        while not self.gauge.ready():
            if self.closed:
                return False
            if loop.time() - started >= self.settings.stream_stall_timeout:
                self._close_stalled()
                return False
            await asyncio.sleep(RETRY)
        return not self.closed

    def _heatmap(self, mode, weights, phase, vertices, space):
        """(error_um bytes, error_max) of ``vertices`` against the non-linear blend."""
        if mode == "nonlinear":
            distance = np.zeros(len(vertices), dtype=np.float32)
        else:
            reference = space.blender("nonlinear").blend(weights, phase)
            distance = np.linalg.norm(vertices - reference, axis=1)
        return np.minimum(np.rint(distance * 1e6), 65535).astype("<u2").tobytes(), float(distance.max())

    # ------------------------------------------------------------ encoding

    def _vertex_bytes(self, vertices):
        """The frame's encoded vertices: a new buffer (the transport may keep it a while)."""
        if self.codec == "q16":
            return self.quantiser.encode_array(vertices)
        return P.encode_vertices(vertices, "f32", None)  # a copy: ``vertices`` may be a blender's scratch

    def _streamed_parts(self, player, vertices, graph=None):
        """``_frame_parts`` of a streamed frame without the heatmap (the same bytes): the fields
        that change only with the parameters are packed once per change; ``graph``: a motion
        graph's fields (``StreamedFrame.graph``), ``player`` its GraphStream."""
        self.seq += 1
        self.stats.frames += 1
        key, middle = self.middle
        state = player.state_key
        if middle is None or key is None or key[0] is not state[0] or key[1] is not state[1] \
                or key[2] is not state[2] or key[3] is not state[3]:
            middle = StreamedFrame.middle(player.mode, _floats(player.requested), _floats(player.realised),
                                          bool(player.clamped), _floats(player.weights))
            self.middle = state, middle
        return StreamedFrame.parts(self.seq, self.ack, float(player.time), float(player.phase), middle,
                                   player.position.tolist(), float(player.heading), self.dropped,
                                   bool(player.finished), time.time(), vertices, graph)

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
                 "sent_at": time.time(), "pull_id": pull_id, "error_max": error_max, "error_seq": error_seq,
                 "node": None, "target": None, "progress": None}
        bulk = [("vertices", vertices)]
        if error_um is None:
            small["error_um"] = None
        else:
            bulk.append(("error_um", error_um))
        return frame_parts(small, bulk)
