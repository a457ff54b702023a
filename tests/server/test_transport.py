"""server/transport.py: a streamed frame written in one call is the message write_message writes."""

import asyncio
import math
from types import SimpleNamespace

import numpy as np
from websockets.protocol import State

from server.transport import TransportGauge, websocket_header


class Transport:
    """Keeps what is written; ``buffered`` bytes wait in it."""

    def __init__(self, buffered=0):
        self.writes, self.buffered, self.closing = [], buffered, False

    def get_extra_info(self, name):
        return None

    def get_write_buffer_size(self):
        return self.buffered

    def is_closing(self):
        return self.closing

    def writelines(self, parts):
        self.writes.append(b"".join(bytes(part) for part in parts))


def gauge(buffered=0, state=State.OPEN):
    protocol = SimpleNamespace(transport=Transport(buffered), close_sent=False, disconnected=False,
                               conn=SimpleNamespace(state=state), writable=asyncio.Event())
    protocol.writable.set()
    return TransportGauge(protocol)


def test_write_frame_writes_write_messages_bytes_and_says_what_may_be_held():
    head = memoryview(bytes(range(200)))
    for size in (10, 18000, 70000):
        vertices = memoryview(np.arange(size // 2, dtype="<u2")).cast("B")
        one, other = gauge(), gauge()
        assert one.write_message([head, vertices])
        held = other.write_frame(head, vertices, math.inf)
        assert held == 0 and other._transport.writes == one._transport.writes
        assert one._transport.writes[0] == websocket_header(200 + vertices.nbytes) + bytes(head) + bytes(vertices)
        # the kernel not asked (no socket here): what the transport holds, where it may exceed the floor
        assert gauge(buffered=5000).write_frame(head, vertices, 0) == 5000
    assert gauge(state=State.CLOSING).write_frame(head, head, 0) is None


def test_ready_when_the_transport_holds_nothing_takes_writes_and_is_open():
    one = gauge()
    assert one.ready()
    one._transport.buffered = 1
    assert not one.ready()
    one._transport.buffered = 0
    one._protocol.writable.clear()  # (the protocol paused writing)
    assert not one.ready()
    one._protocol.writable.set()
    one._transport.closing = True
    assert not one.ready()
