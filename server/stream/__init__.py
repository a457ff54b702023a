"""``/v1/stream``: one WebSocket connection streaming a motion space or a motion graph live.

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
the slow one-off set-up (opening a space, building the non-linear solver) goes to a thread, and
heatmap distances to a helper process (server/heatmap/).

One concept per module:

- ``session.py``: ``StreamSession``, the connection: accept, receive, rate-limit, decode and
  dispatch client messages, send, close; ``StreamStats`` (server-wide counters).
- ``messages.py``: what each client message does; ``HANDLERS`` maps a message type to its
  handler (the one place to add a message kind).
- ``output.py``: the connection's frames: what the scheduler calls (advance on the rate grid,
  window and stall handling, the frame's source, writing it), and pulled frames.

A graph stream (``hello`` names ``graph`` instead of ``space``) plays a GraphPlayer; its
``action`` message and the frames' ``node``, ``target`` and ``progress`` are in
``server/graph_stream.py``.
"""

from server.stream.session import CLOSE_GRACE, StreamSession, StreamStats

__all__ = ["CLOSE_GRACE", "StreamSession", "StreamStats"]
