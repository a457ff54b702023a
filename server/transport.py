"""What a stream connection sees of its transport: ``StreamProtocol`` and ``TransportGauge``.

Latest-wins has to hold down to the socket: a frame written into a transport that still holds
an earlier one waits behind it, and a client that stops reading for seconds would get seconds of
stale frames first when it reads again. So the server writes a frame only into an empty
transport, and bounds what the kernel holds:

- ``StreamProtocol`` is uvicorn's sans-I/O WebSocket protocol (``morphspace serve`` runs it)
  with two additions: it sets ``TCP_NOTSENT_LOWAT`` on each connection's socket, so the kernel
  takes new bytes only while fewer than ``UNSENT_LIMIT`` wait unsent (the rest stays in the
  asyncio transport, where the server sees it), and it hands the stream a ``TransportGauge``
  in the connection's ASGI scope (``scope["extensions"][GAUGE]``).
- ``TransportGauge.ready()`` is true when the transport has taken everything written so far;
  ``held()`` is what the server holds for the connection: the asyncio buffer plus the kernel's
  send queue (sent and unacknowledged, or unsent: ``SIOCOUTQ``); ``held_above(floor)`` is
  ``held()`` where that may exceed ``floor``, without the system call where it cannot (the
  kernel's queue grows only by what is written: it holds at most what it held when last asked
  plus the bytes written since).
- ``TransportGauge.write_message(parts)`` writes one binary WebSocket message straight to the
  transport: the frame header and the parts in one gathered write (``writelines``: one
  ``writev`` under uvloop, the parts not copied in Python), instead of through the ASGI send,
  Starlette and the websockets library (three copies and most of a frame's CPU).
  Frames go out uncompressed even where permessage-deflate was negotiated (RFC 7692 lets a
  sender leave any message uncompressed: RSV1 clear). ``write_frame(head, vertices, floor)``
  is the same for a streamed frame's two parts, with ``held_above(floor)`` in the same call.

Under another ASGI server there is no gauge; the stream then relies on the send itself: a send
that would wait for a full transport is abandoned (the frame is dropped, never queued).
"""

from __future__ import annotations

import fcntl
import logging
import math
import socket
import termios

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from websockets.protocol import State

log = logging.getLogger("morphspace.stream")
GAUGE = "morphspace.transport"
UNSENT_LIMIT = 32 * 1024          # bytes the kernel may hold unsent per connection (TCP_NOTSENT_LOWAT)
_NOTSENT_LOWAT = getattr(socket, "TCP_NOTSENT_LOWAT", None)
_OUTQ = getattr(termios, "TIOCOUTQ", None)  # == SIOCOUTQ on Linux: bytes in a TCP socket's send queue


class TransportGauge:
    """How full one connection's transport is (see the module docstring)."""

    def __init__(self, protocol):
        self._protocol = protocol
        self._transport = protocol.transport
        sock = self._transport.get_extra_info("socket")
        self._fd = sock.fileno() if sock is not None and _OUTQ is not None else -1
        self._word = bytearray(4)
        self.peak = 0   # the most ``held()`` has returned
        # an upper bound of the kernel's send queue now: what it held when last asked plus the bytes
        # written since (infinite: not known, e.g. after a message sent through the ASGI layers)
        self._queued_at_most = math.inf
        self._elsewhere = 0  # messages being sent through the ASGI layers
        # ready()'s three questions, asked every due frame (the protocol's Event lives as long as it)
        self._buffered = self._transport.get_write_buffer_size
        self._writable = protocol.writable.is_set
        self._closing = self._transport.is_closing

    def ready(self):
        """True when a frame written now would not wait behind earlier bytes in the transport."""
        return self._buffered() == 0 and self._writable() and not self._closing()

    def held(self):
        """Bytes the server holds for this connection: the transport's buffer plus the kernel's
        send queue (0 where the kernel cannot say). Updates ``peak``."""
        total = self._transport.get_write_buffer_size()
        if self._fd >= 0:
            try:
                fcntl.ioctl(self._fd, _OUTQ, self._word)
                queued = int.from_bytes(self._word, "little")
                total += queued
                self._queued_at_most = queued
            except OSError:   # the socket has closed meanwhile
                pass
        if total > self.peak:
            self.peak = total
        return total

    def held_above(self, floor):
        """``held()`` where it may exceed ``floor`` bytes, else None (the kernel not asked: what
        its send queue held when last asked plus the bytes ``write_message`` has written since,
        plus the transport's buffer, is at most ``floor``). A message written to the connection
        another way (the ASGI send) goes between ``sending_elsewhere(True)`` and ``(False)``;
        the protocol's own pings and pongs (a few bytes each) are not counted."""
        if self._queued_at_most + self._transport.get_write_buffer_size() <= floor and not self._elsewhere:
            return None
        return self.held()

    def sending_elsewhere(self, started):
        """A message is being written to the transport outside ``write_message`` (``started``),
        or has been: meanwhile ``held_above`` always asks the kernel, and next time after."""
        self._elsewhere += 1 if started else -1
        self._queued_at_most = math.inf

    def write_message(self, parts):
        """Write one binary WebSocket message whose payload is ``parts`` (buffers) joined; False
        (nothing written) when the connection is no longer open."""
        protocol = self._protocol
        if protocol.close_sent or protocol.disconnected or protocol.conn.state is not State.OPEN:
            return False
        length = 0
        for part in parts:
            length += part.nbytes if isinstance(part, memoryview) else len(part)
        # one gathered write (writev), no copy here: the transport keeps a reference to what the
        # kernel does not take at once, so the parts must not change afterwards (they are new
        # buffers each frame: server/frames.py)
        header = _HEADERS.get(length)
        if header is None:
            header = websocket_header(length)
            if len(_HEADERS) < 256:
                _HEADERS[length] = header
        self._transport.writelines([header, *parts])
        self._queued_at_most += len(header) + length
        return True

    def write_frame(self, head, vertices, floor):
        """``write_message([head, vertices])`` for two memoryviews (a streamed frame's parts),
        then ``held_above(floor)`` in the same call: None when the connection is no longer open
        (nothing written), else the bytes held where they may exceed ``floor``, 0 where not."""
        protocol = self._protocol
        if protocol.close_sent or protocol.disconnected or protocol.conn.state is not State.OPEN:
            return None
        length = head.nbytes + vertices.nbytes
        header = _HEADERS.get(length)
        if header is None:
            header = websocket_header(length)
            if len(_HEADERS) < 256:
                _HEADERS[length] = header
        transport = self._transport
        transport.writelines((header, head, vertices))  # (as write_message: one writev, no copy)
        self._queued_at_most += len(header) + length
        if self._queued_at_most + transport.get_write_buffer_size() <= floor and not self._elsewhere:
            return 0
        return self.held()

    def abort(self):
        """Drop the TCP connection at once, unsent bytes and all (a client that reads nothing)."""
        self._transport.abort()


_HEADERS = {}  # length -> websocket_header(length), for the few lengths a server's frames have


def websocket_header(length):
    """The header of an unmasked, final, binary WebSocket frame of ``length`` payload bytes
    (RFC 6455 5.2; a server never masks)."""
    if length < 126:
        return bytes([0x82, length])
    if length < 1 << 16:
        return b"\x82\x7e" + length.to_bytes(2, "big")
    return b"\x82\x7f" + length.to_bytes(8, "big")


def limit_unsent(transport):
    """Set TCP_NOTSENT_LOWAT on ``transport``'s socket (where the platform has it)."""
    sock = transport.get_extra_info("socket")
    if sock is None or _NOTSENT_LOWAT is None:
        return
    try:
        sock.setsockopt(socket.IPPROTO_TCP, _NOTSENT_LOWAT, UNSENT_LIMIT)
    except OSError as exc:  # not TCP (a Unix socket), or refused: the asyncio bound still holds
        log.debug("stream: TCP_NOTSENT_LOWAT not set: %s", exc)


class StreamProtocol(WebSocketsSansIOProtocol):
    """uvicorn's sans-I/O WebSocket protocol, with the kernel's unsent bytes bounded and a
    ``TransportGauge`` in each connection's scope (``uvicorn.run(app, ws=StreamProtocol)``)."""

    def connection_made(self, transport):
        super().connection_made(transport)
        limit_unsent(transport)

    def handle_connect(self, event):
        super().handle_connect(event)
        scope = getattr(self, "scope", None)
        if scope is not None:  # the handshake was accepted: the ASGI task has not run yet
            scope["extensions"][GAUGE] = TransportGauge(self)
