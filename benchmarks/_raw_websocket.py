"""A blocking WebSocket client (RFC 6455) on a plain socket with a tiny receive buffer.

What a stalled client looks like to the server: it reads only when asked to, and answers pings
only then. Used by benchmarks/stream_stall.py and tests/server/test_stream_stall.py.
"""

from __future__ import annotations

import base64
import os
import socket

import msgpack


class RawWebSocket:
    """Connects to ``/v1/stream`` on 127.0.0.1 and sends ``hello`` (a dict)."""

    def __init__(self, port, hello, *, receive_buffer=4096, timeout=10.0):
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
        self.sock.settimeout(timeout)
        self.sock.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET /v1/stream HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n")
                          .encode())
        self.buffer = b""
        while b"\r\n\r\n" not in self.buffer:
            self._fill()
        head, self.buffer = self.buffer.split(b"\r\n\r\n", 1)
        if not head.startswith(b"HTTP/1.1 101"):
            raise ConnectionError(head[:200].decode(errors="replace"))
        self.send(hello)

    def _fill(self):
        chunk = self.sock.recv(65536)
        if not chunk:
            raise EOFError("the server closed the TCP connection without a close frame")
        self.buffer += chunk

    def send(self, message, opcode=0x2):
        """Send a dict (as msgpack) or bytes, masked as a client must."""
        payload = message if isinstance(message, bytes) else msgpack.packb(message)
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x80 | opcode]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + n.to_bytes(2, "big"))
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))

    def receive_frame(self):
        """(opcode, payload) of the next data or close frame; pings are answered on the way."""
        while True:
            while len(self.buffer) < 2:
                self._fill()
            opcode, length, header = self.buffer[0] & 0x0F, self.buffer[1] & 0x7F, 2
            if length >= 126:
                header = 4 if length == 126 else 10
                while len(self.buffer) < header:
                    self._fill()
                length = int.from_bytes(self.buffer[2:header], "big")
            while len(self.buffer) < header + length:
                self._fill()
            payload, self.buffer = self.buffer[header:header + length], self.buffer[header + length:]
            if opcode == 0x9:
                self.send(payload, opcode=0xA)
                continue
            return opcode, payload

    def close(self):
        self.sock.close()
