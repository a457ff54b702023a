"""One task produces the frames of every streaming connection: ``FrameScheduler``.

Connections wait in a heap keyed by the time their next frame is due: for a streaming
connection, a multiple of its period (``1 / rate``), on a grid every connection at that rate
shares (``FrameOutput.due_step``), so that the frames of a tick are as many as can be made
together (the per-tick work, the compiled calls and the wake-up, is shared by more frames, and
the clients' processes are woken by bursts, not by every frame). A tick takes every
connection due within half a tick (``TICK``), steps its player, blends, encodes and hands the
frame to its transport, then sleeps until the next one falls due (at least a tick later, unless a
client message makes a frame urgent). Per tick:

- the players of the tick's due connections step first (engine/player_steps.py, the same floats
  as one by one): the settled ones in one compiled pass on their clocks (``Player.clock``), the
  steering ones (parameters on their way to a request) of each space in one compiled call
  (spring, warm solve, weights and root rates), the others one at a time;
- clients whose weights have a phase table (settled parameters, or many viewers at the same
  ones) are grouped by table; each group's rows are interpolated and cast in one call, one
  compiled pass a row (``PhaseTable.rows_cast``), q16 clients' straight from the table in codec
  units (``Quantiser.table``), so their integers need one truncating cast;
- clients at moving weights (steering, linear or hybrid) are grouped by blender: each group is
  one ``ManyBlender.blend`` per codec (engine/blend/many.py: a hybrid frame interpolates its
  simplex leaf's reference blends, q16 clients' codes made in the same compiled pass); a row's
  bytes do not depend on the rest of its group, so a client blended alone (``send_frame(None)``)
  gets the same frame;
- a motion graph's client playing one node, no transition blending and no foot held, reads its
  node's phase table like a space's client (``GraphPlayer.table_source``); the non-linear mode
  and the rest of a graph's frames (transitions, held feet: blended by its player) are made one
  client at a time;
- the heads of the tick's streamed frames of a space (every field but the vertices) are made in
  one compiled pass from the players' clocks and the sessions' counters
  (``server.frames.streamed_heads``; a heatmap's or a motion graph's frame is packed by its
  session, ``send_frame``);
- frames are written without a task switch, straight to the transport (server/transport.py: the
  head and the vertices in one gathered write), and only into a transport that has taken everything before
  it (the session checks before it blends; a connection whose transport still holds bytes skips
  the tick, counted in its ``dropped``: latest-wins, never queued). Under an ASGI server
  without that access the ASGI send is run by hand and completes in the call; a send that
  would wait is abandoned: that frame is dropped.

All of it runs on the event loop thread: the engine's blenders keep scratch buffers and the
work per frame is a few tens of microseconds.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import logging
import math
import time
import weakref

from engine.blend.many import ManyBlender
from engine.player_steps import advance_together
from server.frames import row_views, streamed_heads

log = logging.getLogger("morphspace.stream")
TICK = 0.002      # seconds: ticks come at most this often (urgent frames excepted)
MAX_BATCH = 64    # frames per tick at most; then the loop reads sockets before the next tick
URGENT = -math.inf


def send_now(coro):
    """Run a send coroutine ``coro`` in the caller. True when it completed in the call (its
    exceptions propagate); False when it would have waited (for a full transport): it is then
    closed, which abandons that send.

    Notes
    -----
    A coroutine started by hand cannot be handed on to a Task once it has suspended: the future
    it yielded is marked as awaited, and awaiting it again raises RuntimeError("await wasn't
    used with future") (the bug behind issue 13's stalled streams). Latest-wins wants the frame
    dropped anyway.
    """
    try:
        coro.send(None)
    except StopIteration:
        return True
    except BaseException:
        coro.close()
        raise
    coro.close()
    return False


class FrameScheduler:
    """Produces the frames of every StreamSession added to it, on one task of the running loop.

    ``scheduler.add(session)``; ``scheduler.schedule(session, due)`` whenever a session wants a
    frame at loop time ``due``; ``scheduler.remove(session)``. The task starts with the first
    session and ends when the last one leaves.

    A session (server.stream.StreamSession) provides ``version`` (int, bumped here), ``closed``,
    ``player`` (its ``phase`` is read; stepped here), ``payload`` (set here), ``due_step(now)`` ->
    seconds or None (how far its player is to step for a frame now; None: no frame now, and the
    session reschedules itself if it wants one),
    ``frame_source()`` -> (table or None, codec), ``moving_source()`` -> (blender, weights,
    phase) or None (without a table: a linear or hybrid blend this scheduler may do with
    others'), ``codec`` and ``quantiser``, ``streamed_head(vertices, fields, clocks, middles,
    values)`` (appends what its frame's head is made of, for ``server.frames.streamed_heads``;
    False: ``send_frame`` writes this one) and ``write_frame(head, vertices)``,
    ``send_frame(payload)`` where payload is the encoded vertices or None (blend this one alone),
    ``next_frame_due()`` (when its next frame is due, or None; pushed here) and ``fail(exc)``.
    Sessions count ``transport_full`` and raise ``transport_bytes_max`` here.
    """

    def __init__(self):
        self._heap = []
        self._order = itertools.count()
        self._sessions = set()
        self._task = None
        self._wakeup = None
        self._planned = math.inf
        self.ticks = 0           # ticks that produced frames
        self.frames = 0          # frames written
        self.table_frames = 0    # of which interpolated from a phase table
        self.batched_frames = 0  # of which blended together with the tick's other moving clients
        self._many = weakref.WeakKeyDictionary()  # blender -> its ManyBlender
        self._heatmaps = None
        self.transport_full = 0  # due frames skipped because the transport still held bytes
        self.transport_bytes_max = 0  # the most one connection's transport held after a frame

    @property
    def heatmaps(self):
        """The HeatmapService of these sessions (server/heatmap/), started on first use."""
        if self._heatmaps is None:
            from server.heatmap import HeatmapService
            self._heatmaps = HeatmapService()
        return self._heatmaps

    def close(self):
        """End the heatmap helper process, if one was started (the app's shutdown)."""
        if self._heatmaps is not None:
            self._heatmaps.close()

    def counters(self):
        """Ticks, frames, frames from phase tables, frames skipped for a full transport, the
        most bytes one connection's transport held."""
        return {"ticks": self.ticks, "frames": self.frames, "table_frames": self.table_frames,
                "batched_frames": self.batched_frames, "transport_full": self.transport_full, "transport_bytes_max": self.transport_bytes_max}

    def many_blender(self, blender):
        """The ManyBlender of a linear or hybrid ``blender`` (its reference rows kept while the
        blender is)."""
        many = self._many.get(blender)
        if many is None:
            many = self._many[blender] = ManyBlender(blender)
        return many

    def add(self, session):
        self._sessions.add(session)
        if self._task is None or self._task.done():
            self._wakeup, self._planned = asyncio.Event(), math.inf
            self._task = asyncio.get_running_loop().create_task(self._run())

    def remove(self, session):
        self._sessions.discard(session)
        session.version += 1
        if not self._sessions and self._wakeup is not None:
            self._wakeup.set()

    def schedule(self, session, due):
        """Produce ``session``'s next frame at loop time ``due`` (replacing any earlier request);
        ``URGENT``: ahead of every frame already due (a client message changed what it sees)."""
        session.version += 1
        heapq.heappush(self._heap, (due, next(self._order), session.version, session))
        if due < self._planned and self._wakeup is not None:
            self._wakeup.set()

    async def _run(self):
        loop = asyncio.get_running_loop()
        try:
            while self._sessions:
                now = loop.time()
                batch = []
                heap, pop, limit = self._heap, heapq.heappop, now + 0.5 * TICK
                while heap and heap[0][0] <= limit and len(batch) < MAX_BATCH:
                    _, _, version, session = pop(heap)
                    if version == session.version and not session.closed:
                        batch.append(session)
                if batch:
                    self.ticks += 1
                    try:
                        self._produce(batch, now)
                    except Exception:  # noqa: BLE001 - a bug here must not stop everyone's stream
                        log.exception("stream: a tick failed; its connections are rescheduled")
                        for session in batch:
                            session.payload = None
                            session.after_frame()
                if not self._sessions:
                    break
                if heap and heap[0][0] <= loop.time() + 0.5 * TICK:
                    await asyncio.sleep(0)  # behind: let the loop read sockets, then go on
                    continue
                # sleep until the next frame falls due, at least a tick from now
                self._planned = max(heap[0][0] - 0.5 * TICK, now + TICK) if heap else math.inf
                handle = loop.call_at(self._planned, self._wakeup.set) if heap else None
                await self._wakeup.wait()
                self._wakeup.clear()
                self._planned = -math.inf  # a schedule() during the tick must not wake it again
                if handle is not None:
                    handle.cancel()
        finally:
            self._heap.clear()

    def _step_players(self, ready, steps):
        """Step the players of ``ready`` by ``steps`` (seconds): steering players of a space in one
        compiled call (engine/player_steps.py: the same numbers as one by one), the others one at
        a time. Returns the sessions whose step did not fail."""
        try:
            alone = advance_together([session.player for session in ready], steps)
        except Exception:  # noqa: BLE001 - the compiled step changes no player before it returns
            log.exception("stream: stepping %d players together failed; they step one by one", len(ready))
            alone = range(len(ready))
        failed = set()
        for k in alone:
            try:
                ready[k].player.advance(steps[k])
            except Exception as exc:  # noqa: BLE001 - one connection's failure stays its own
                ready[k].fail(exc)
                failed.add(k)
        return [session for k, session in enumerate(ready) if k not in failed] if failed else ready

    def _blend_together(self, blender, members):
        """The frames of ``members`` [(session, weights, phase)] at moving weights of one blender:
        one blend per codec (q16 clients' codes made in the same pass); sets each session's
        payload."""
        many = self.many_blender(blender)
        by_codec = {}
        for member in members:
            quantiser = member[0].quantiser if member[0].codec == "q16" else None
            by_codec.setdefault(None if quantiser is None else quantiser.key, (quantiser, []))[1].append(member)
        for quantiser, group in by_codec.values():
            rows = many.blend([m[1] for m in group], [m[2] for m in group],
                              None if quantiser is None else quantiser.codes)
            if quantiser is None:
                rows = rows.astype("<f4", copy=False)  # (no copy on little-endian machines)
            for (session, _, _), view in zip(group, row_views(rows)):
                session.payload = view  # the frame's vertices
        self.batched_frames += len(members)

    def _produce(self, batch, now):
        ready, steps = [], []
        for session in batch:
            try:
                dt = session.due_step(now)
            except Exception as exc:  # noqa: BLE001 - one connection's failure stays its own
                session.fail(exc)
                continue
            if dt is not None:
                ready.append(session)
                steps.append(dt)
        ready = self._step_players(ready, steps)
        # clients at weights with a phase table: one gather per table; the others at linear or
        # hybrid weights: one blend per blender
        groups, moving = {}, {}
        for session in ready:
            session.payload = None
            try:
                table, codec = session.frame_source()
                source = None if table is not None else session.moving_source()
            except Exception as exc:  # noqa: BLE001
                session.fail(exc)
                continue
            if table is not None:
                group = groups.get(id(table))
                if group is None:
                    group = groups[id(table)] = (table, codec, [])
                group[2].append(session)
            elif source is not None:
                group = moving.get(id(source[0]))
                if group is None:
                    group = moving[id(source[0])] = (source[0], [])
                group[1].append((session, source[1], source[2]))
        for table, codec, members in groups.values():
            try:
                # a q16 table is in codec units, + 0.5: truncating to uint16 rounds
                rows = table.rows_cast([m.player.phase for m in members], "<u2" if codec == "q16" else "<f4")
            except Exception:  # noqa: BLE001 - its members blend one by one below
                log.exception("stream: gathering %d frames from a phase table failed", len(members))
                continue
            for member, view in zip(members, row_views(rows)):
                member.payload = view  # the frame's vertices (written without a copy here)
            self.table_frames += len(members)
        for blender, members in moving.values():
            try:
                self._blend_together(blender, members)
            except Exception:  # noqa: BLE001 - its members blend one by one below
                log.exception("stream: blending %d moving frames together failed", len(members))
        self._send(ready)

    def _send(self, ready):
        """Write the frames of ``ready``: the heads of the plain streamed ones (a space's player,
        no heatmap) made in one compiled pass from their players' clocks
        (``server.frames.streamed_heads``), the others by ``send_frame``; then each session asks
        for its next frame."""
        heads, fields, clocks, middles, values = [], [], [], [], []
        for session in ready:
            payload = session.payload
            if session.closed or payload.__class__ is not memoryview:
                continue
            try:
                if session.streamed_head(payload, fields, clocks, middles, values):
                    heads.append(session)
            except Exception as exc:  # noqa: BLE001
                session.fail(exc)
        if heads:
            try:
                made = streamed_heads(fields, clocks, middles, values, time.time())
            except Exception:  # noqa: BLE001 - (a bug) send_frame writes them: their seq skips one
                log.exception("stream: making %d frames' heads together failed", len(heads))
                made = ()
            for session, head in zip(heads, made):
                session.payload = (head, session.payload)  # the frame's head and vertices
        heap, order, push, earliest, written = self._heap, self._order, heapq.heappush, math.inf, 0
        for session in ready:
            if session.closed:
                continue
            payload = session.payload
            session.payload = None
            try:
                if payload.__class__ is tuple:
                    session.write_frame(*payload)
                else:
                    session.send_frame(payload)
                due = session.next_frame_due()
            except Exception as exc:  # noqa: BLE001
                session.fail(exc)
                continue
            written += 1
            if due is not None:  # (schedule(), inline)
                session.version = version = session.version + 1
                push(heap, (due, next(order), version, session))
                if due < earliest:
                    earliest = due
        self.frames += written
        if earliest < self._planned and self._wakeup is not None:
            self._wakeup.set()
