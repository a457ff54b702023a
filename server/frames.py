"""A frame's wire bytes, assembled with one copy of its arrays.

The streaming hot path. A Frame message (server/protocol.py) is a msgpack map of about sixteen
small fields and one to two large ``bin`` values (vertices, heatmap distances). Packing it as a
dict copies the arrays into msgpack's buffer, and the WebSocket layers above the socket copy the
result twice more. Here the small fields are packed once (one ``packb``), the map and ``bin``
headers are built by hand, and the arrays stay where they are: ``frame_parts`` returns the body
as a list of buffers, which ``TransportGauge.write_message`` (server/transport.py) hands to the
transport behind the WebSocket frame header in one gathered write, without joining them. The bytes are exactly ``msgpack.packb`` of the whole map in
the same key order (a test checks).
"""

from __future__ import annotations

import dataclasses

import msgpack

from server.protocol import Frame

_KEYS = {f.name: msgpack.packb(f.name) for f in dataclasses.fields(Frame)}
_packb = msgpack.Packer(use_bin_type=True, autoreset=True).pack


def _map_header(n):
    return bytes([0x80 | n]) if n <= 15 else b"\xde" + n.to_bytes(2, "big")


def _bin_header(n):
    if n < 1 << 8:
        return b"\xc4" + bytes([n])
    if n < 1 << 16:
        return b"\xc5" + n.to_bytes(2, "big")
    return b"\xc6" + n.to_bytes(4, "big")


def frame_parts(small, bulk):
    """The msgpack body of a Frame as a list of buffers.

    Parameters
    ----------
    small : dict   every field that is not an array, ``type`` first (numbers, strings, lists)
    bulk : list of (name, buffer)   the array fields (bytes, or C-contiguous numpy arrays whose
                                    raw bytes are the value), appended in this order, not copied
    """
    packed = _packb(small)
    skip = 1 if len(small) <= 15 else 3  # packb's own map header
    parts = [_map_header(len(small) + len(bulk)), memoryview(packed)[skip:]]
    for name, data in bulk:
        view = memoryview(data).cast("B")
        parts.append(_KEYS[name] + _bin_header(view.nbytes))
        parts.append(view)
    return parts


def joined(parts):
    """The body's bytes in one piece (for senders that take bytes)."""
    return b"".join(parts)
