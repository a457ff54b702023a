"""A frame's wire bytes, assembled with one copy of its arrays.

The streaming hot path. A Frame message (server/protocol.py) is a msgpack map of about sixteen
small fields and one to two large ``bin`` values (vertices, heatmap distances). Packing it as a
dict copies the arrays into msgpack's buffer, and the WebSocket layers above the socket copy the
result twice more. Here the small fields are packed once (one ``packb``), the map and ``bin``
headers are built by hand, and the arrays stay where they are: ``frame_parts`` returns the body
as a list of buffers, which ``TransportGauge.write_message`` (server/transport.py) hands to the
transport behind the WebSocket frame header in one gathered write, without joining them. The bytes are exactly ``msgpack.packb`` of the whole map in
the same key order (a test checks).

A streamed frame (no pull or heatmap fields) has a fixed layout: ``StreamedFrame`` packs it from
a few ``struct`` calls around constant byte strings, with the fields that change only with the
player's parameters (mode, requested, realised, clamped, weights) packed once per change
(``StreamedFrame.middle``) and a motion graph's node, target and progress packed apart
(``StreamedFrame.graph``); its bytes are those of ``frame_parts`` for the same values (a test
checks).

A tick's streamed frames of players have their heads (every field but the vertices) made in one
compiled pass (``streamed_heads``): the numbers read from each player's clock
(``engine.player.Player.clock``, by address), the counters and middles handed over in flat lists,
the constant pieces copied by ``memcpy``, into one buffer sliced per frame: the bytes of
``StreamedFrame.parts``' first part (a test checks), about 0.1 us a frame instead of 1.8.
"""

from __future__ import annotations

import dataclasses
import struct

import msgpack
import numpy as np
from numba import carray

from engine.jit import compiled, copy_bytes, float64_pointer
from engine.player import CLOCK_SIZE, FINISHED, HEADING, PHASE, ROOT, TIME
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


def row_views(rows):
    """The bytes of each row of ``rows`` (K, m) (each row C-contiguous, e.g. a tick's frames of
    one table or blend) as memoryviews: slices of one view of the whole array, which costs one
    buffer export instead of one per row (a frame's ``vertices`` for ``StreamedFrame.parts``)."""
    K, width = len(rows), rows.shape[1] * rows.itemsize
    if K == 0:
        return []
    step = rows.strides[0]
    if rows.flags.c_contiguous:
        whole = memoryview(rows).cast("B")
    elif rows.strides[1] == rows.itemsize and step >= width:  # padded rows (ManyBlender's float32 ones)
        whole = memoryview(np.lib.stride_tricks.as_strided(rows.view(np.uint8), shape=((K - 1) * step + width,),
                                                           strides=(1,)))
    else:
        return [memoryview(row).cast("B") for row in rows]
    return [whole[start:start + width] for start in range(0, K * step, step)]


def joined(parts):
    """The body's bytes in one piece (for senders that take bytes)."""
    return b"".join(parts)


def _pair(name, value):
    return msgpack.packb(name) + msgpack.packb(value)


_UINT = [bytes([n]) for n in range(128)]  # positive fixints: msgpack's form of 0..127
# the map of a streamed frame: 22 small fields and the vertices, in Frame's order; every Python
# float packs as b"\xcb" and its big-endian float64
_HEAD = b"\xde\x00\x17" + _pair("type", "frame") + _KEYS["seq"]
_ACK, _TIME, _ROOT, _DROPPED = _KEYS["ack"], _KEYS["time"] + b"\xcb", _KEYS["root"] + b"\x93\xcb", _KEYS["dropped"]
_PHASE, _HEADING, _F = _KEYS["phase"] + b"\xcb", _KEYS["heading"] + b"\xcb", b"\xcb"
_TIME_PHASE = struct.Struct(f">d{len(_PHASE)}sd").pack            # time, _PHASE, phase
_ROOT_HEADING = struct.Struct(f">d1sd1sd{len(_HEADING)}sd").pack  # x, _F, y, _F, z, _HEADING, heading
_SENT_AT = struct.Struct(">d").pack
_FINISHED = {True: _pair("finished", True) + _KEYS["sent_at"] + b"\xcb",
             False: _pair("finished", False) + _KEYS["sent_at"] + b"\xcb"}
_NONES_VERTICES = b"".join(_pair(name, None) for name in ("pull_id", "error_max", "error_seq", "node", "target",
                                                           "progress", "error_um")) + _KEYS["vertices"]
_NONES_NODE = b"".join(_pair(name, None) for name in ("pull_id", "error_max", "error_seq")) + _KEYS["node"]
_TARGET, _PROGRESS = _KEYS["target"], _KEYS["progress"]
_NO_ERROR_VERTICES = _pair("error_um", None) + _KEYS["vertices"]
_NIL = msgpack.packb(None)
_PROGRESS_FLOAT = struct.Struct(f">{len(_PROGRESS)}s1sd").pack  # _PROGRESS, _F, progress
_GRAPH_STILL = {}  # (node, target) -> StreamedFrame.graph's bytes without a transition's progress


_MIDDLE = {}  # (mode, lengths, clamped) -> _middle_packer's
_BIN_HEADERS = {}  # a vertices field's length -> its bin header


def _array_header(n):
    return bytes([0x90 | n]) if n <= 15 else b"\xdc" + n.to_bytes(2, "big")


def _middle_packer(mode, n_requested, n_realised, clamped, n_weights):
    """(struct pack, head, between, tail) of ``StreamedFrame.middle`` for these lengths: the
    format interleaves the constant bytes with a ``0xcb`` byte and a big-endian float64 per
    number."""
    head = _KEYS["mode"] + _packb(mode) + _KEYS["requested"] + _array_header(n_requested)
    between = _KEYS["realised"] + _array_header(n_realised)
    tail = _KEYS["clamped"] + _packb(bool(clamped)) + _KEYS["weights"] + _array_header(n_weights)
    fmt = (f">{len(head)}s" + "Bd" * n_requested + f"{len(between)}s" + "Bd" * n_realised + f"{len(tail)}s"
           + "Bd" * n_weights)
    return struct.Struct(fmt).pack, head, between, tail


def _uint(n):
    return _UINT[n] if 0 <= n < 128 else _packb(n)


class StreamedFrame:
    """The wire bytes of a streamed frame of a space: what ``frame_parts`` gives for a ``small``
    map in Frame's order with ``pull_id``, ``error_max``, ``error_seq``, ``node``, ``target``,
    ``progress`` and ``error_um`` nil and one bulk field, ``vertices`` (the class's methods)."""

    @staticmethod
    def middle(mode, requested, realised, clamped, weights):
        """The packed fields from ``mode`` to ``weights`` (a str, three lists of Python floats, a
        bool): the caller keeps them while they stay the same (a steering client's change every
        frame). One ``struct`` call around constant bytes per (mode, lengths, clamped): the
        bytes of msgpack's packing of those five entries (every float a float64, ``0xcb``)."""
        key = (mode, len(requested), len(realised), clamped, len(weights))
        packer = _MIDDLE.get(key)
        if packer is None:
            packer = _middle_packer(*key)
            if len(_MIDDLE) < 1024:
                _MIDDLE[key] = packer
        pack, head, between, tail = packer
        args = [head]
        for value in requested:
            args += (0xCB, value)
        args.append(between)
        for value in realised:
            args += (0xCB, value)
        args.append(tail)
        for value in weights:
            args += (0xCB, value)
        return pack(*args)

    @staticmethod
    def middle_pieces(mode, n_requested, n_realised, clamped, n_weights):
        """The constant bytes of ``middle`` for these lengths: (before the requested values,
        before the realised ones, before the weights); each value follows as 0xcb and a
        big-endian float64 (``streamed_heads`` writes them)."""
        key = (mode, n_requested, n_realised, clamped, n_weights)
        packer = _MIDDLE.get(key)
        if packer is None:
            packer = _middle_packer(*key)
            if len(_MIDDLE) < 1024:
                _MIDDLE[key] = packer
        return packer[1:]

    @staticmethod
    def graph(node, target, progress):
        """The packed ``node``, ``target`` (str or None) and ``progress`` (float or None) fields
        of a motion graph's frame, for ``parts`` (outside a transition, packed once per node and
        target)."""
        if progress is None:
            packed = _GRAPH_STILL.get((node, target))
            if packed is None:
                packed = b"".join((_NONES_NODE, _packb(node), _TARGET, _packb(target), _PROGRESS + _NIL,
                                   _NO_ERROR_VERTICES))
                if len(_GRAPH_STILL) < 1024:
                    _GRAPH_STILL[(node, target)] = packed
            return packed
        return b"".join((_NONES_NODE, _packb(node), _TARGET, _packb(target),
                         _PROGRESS_FLOAT(_PROGRESS, _F, progress), _NO_ERROR_VERTICES))

    @staticmethod
    def parts(seq, ack, time_, phase, middle, root, heading, dropped, finished, sent_at, vertices, graph=None):
        """The frame's body as buffers (``frame_parts``' form: the small fields in one piece, then
        the vertices, not copied). ``seq``, ``ack``, ``dropped``: non-negative ints; ``time_``,
        ``phase``, ``heading``, ``sent_at``: floats; ``root``: three floats; ``finished``: bool;
        ``middle``: from ``middle``; ``vertices``: bytes, a C-contiguous array or a memoryview
        of its bytes (``row_views``: written as it is); ``graph``: a
        motion graph's fields from ``graph`` (None: a space's frame, those fields nil)."""
        x, y, z = root
        view = vertices if vertices.__class__ is memoryview else memoryview(vertices).cast("B")
        size = view.nbytes
        header = _BIN_HEADERS.get(size)
        if header is None:
            header = _bin_header(size)
            if len(_BIN_HEADERS) < 256:
                _BIN_HEADERS[size] = header
        return [b"".join((_HEAD, _uint(seq), _ACK, _uint(ack), _TIME, _TIME_PHASE(time_, _PHASE, phase), middle,
                          _ROOT, _ROOT_HEADING(x, _F, y, _F, z, _HEADING, heading), _DROPPED, _uint(dropped),
                          _FINISHED[finished], _SENT_AT(sent_at), _NONES_VERTICES if graph is None else graph,
                          header)),
                view]


# ``StreamedFrame.heads``: the constant pieces of a streamed frame's head in one array, in the
# order they are written (``_PIECES``: their starts and ends)
_PIECES = [_HEAD, _ACK, _TIME, _PHASE, _ROOT, _F, _HEADING, _DROPPED, _FINISHED[False], _FINISHED[True],
           _NONES_VERTICES]
_CONSTANTS = np.frombuffer(b"".join(_PIECES), dtype=np.uint8)
_BOUNDS = np.cumsum([0] + [len(piece) for piece in _PIECES]).astype(np.int64)
_HEAD_MAX = len(_CONSTANTS) + 3 * 9 + 8 * 8 + 5  # a head's bytes beyond its middle, at most


@compiled
def _put(source, start, end, out, at):  # pragma: no cover (compiled)
    copy_bytes(out, at, source, start, end - start)
    return at + end - start


@compiled
def _put_uint(n, out, at):  # pragma: no cover (compiled)
    """msgpack's bytes of a non-negative int (``_uint``): a fixint below 128, else the smallest
    of uint 8, 16, 32 or 64 (0xcc-0xcf), big-endian."""
    if n < 128:
        out[at] = n
        return at + 1
    if n < 1 << 8:
        out[at], size = 0xCC, 1
    elif n < 1 << 16:
        out[at], size = 0xCD, 2
    elif n < 1 << 32:
        out[at], size = 0xCE, 4
    else:
        out[at], size = 0xCF, 8
    for i in range(size):
        out[at + size - i] = (n >> (8 * i)) & 0xFF
    return at + 1 + size


@compiled
def _put_double(x, scratch, bits, out, at):  # pragma: no cover (compiled)
    """The big-endian bytes of float64 ``x`` (struct's ">d"; ``scratch``: one float64, ``bits``
    its uint64 view)."""
    scratch[0] = x
    b = bits[0]
    for i in range(8):
        out[at + 7 - i] = (b >> np.uint64(8 * i)) & np.uint64(0xFF)
    return at + 8


@compiled
def _streamed_heads(fields, clocks, middles, values, sent_at, constants, bounds, out, ends):  # pragma: no cover
    """The heads of K streamed frames into ``out``, one after another; ``ends`` (K + 1,) their
    bounds (``streamed_heads``). fields (K, 10) int64: seq, ack, dropped, the vertices' bytes,
    then the middle: three pieces of ``middles`` (in order), each followed by that many numbers of
    ``values`` (each written as msgpack's float64: 0xcb, big-endian); clocks (K,) int64: the
    players' ``clock_address``."""
    scratch = np.empty(1, dtype=np.float64)
    bits = scratch.view(np.uint64)
    at = m = v = 0
    for k in range(len(clocks)):
        ends[k] = at
        clock = carray(float64_pointer(clocks[k]), (CLOCK_SIZE,))
        at = _put(constants, bounds[0], bounds[1], out, at)            # map, type, seq key
        at = _put_uint(fields[k, 0], out, at)
        at = _put(constants, bounds[1], bounds[2], out, at)            # ack
        at = _put_uint(fields[k, 1], out, at)
        at = _put(constants, bounds[2], bounds[3], out, at)            # time
        at = _put_double(clock[TIME], scratch, bits, out, at)
        at = _put(constants, bounds[3], bounds[4], out, at)            # phase
        at = _put_double(clock[PHASE], scratch, bits, out, at)
        for j in range(3):                                             # mode ... weights
            length = fields[k, 4 + 2 * j]
            at = _put(middles, m, m + length, out, at)
            m += length
            for i in range(fields[k, 5 + 2 * j]):
                out[at] = 0xCB
                at = _put_double(values[v], scratch, bits, out, at + 1)
                v += 1
        at = _put(constants, bounds[4], bounds[5], out, at)            # root
        at = _put_double(clock[ROOT], scratch, bits, out, at)
        at = _put(constants, bounds[5], bounds[6], out, at)
        at = _put_double(clock[ROOT + 1], scratch, bits, out, at)
        at = _put(constants, bounds[5], bounds[6], out, at)
        at = _put_double(clock[ROOT + 2], scratch, bits, out, at)
        at = _put(constants, bounds[6], bounds[7], out, at)            # heading
        at = _put_double(clock[HEADING], scratch, bits, out, at)
        at = _put(constants, bounds[7], bounds[8], out, at)            # dropped
        at = _put_uint(fields[k, 2], out, at)
        finished = 1 if clock[FINISHED] != 0.0 else 0                  # finished, sent_at
        at = _put(constants, bounds[8 + finished], bounds[9 + finished], out, at)
        at = _put_double(sent_at, scratch, bits, out, at)
        at = _put(constants, bounds[10], bounds[11], out, at)          # nils, the vertices' key
        size = fields[k, 3]                                            # their bin header
        if size < 1 << 8:
            out[at], out[at + 1] = 0xC4, size
            at += 2
        elif size < 1 << 16:
            out[at], out[at + 1], out[at + 2] = 0xC5, size >> 8, size & 0xFF
            at += 3
        else:
            out[at] = 0xC6
            for i in range(4):
                out[at + 4 - i] = (size >> (8 * i)) & 0xFF
            at += 5
    ends[len(clocks)] = at


def streamed_heads(fields, clocks, middles, values, sent_at):
    """The heads of a tick's streamed frames of players (``engine.player.Player``), made in one
    compiled pass from their clocks: the first part of ``StreamedFrame.parts`` for each (the
    same bytes), as memoryviews of one new buffer.

    Parameters
    ----------
    fields : list of int     per frame ten: seq, ack, dropped, the vertices' bytes, then its
                             middle (the fields from ``mode`` to ``weights``) as three (bytes of
                             ``middles``, numbers of ``values``) pairs: a packed
                             ``StreamedFrame.middle`` is (its length, 0, 0, 0, 0, 0), one made
                             here from its numbers is ``StreamedFrame.middle_pieces`` each
                             followed by the requested, realised and weights values
    clocks : list of int     the players' ``clock_address`` (time, phase, root, heading, finished)
    middles : list of bytes  the middles' pieces, in order
    values : list of float   the middles' numbers, in order
    sent_at : float          the frames' ``sent_at``
    """
    K = len(clocks)
    if K == 0:
        return []
    joined_middles = b"".join(middles)
    out = np.empty(K * _HEAD_MAX + len(joined_middles) + 9 * len(values), dtype=np.uint8)
    ends = np.empty(K + 1, dtype=np.int64)
    _streamed_heads(np.array(fields, dtype=np.int64).reshape(K, 10), np.array(clocks, dtype=np.int64),
                    np.frombuffer(joined_middles, dtype=np.uint8), np.array(values, dtype=np.float64),
                    float(sent_at), _CONSTANTS, _BOUNDS, out, ends)
    whole = memoryview(out)
    bounds = ends.tolist()
    return [whole[bounds[k]:bounds[k + 1]] for k in range(K)]


def warm_up():
    """Compile (or load from numba's cache) the heads' pass (a server does so before it serves)."""
    clock = np.zeros(CLOCK_SIZE)
    streamed_heads([1, 0, 0, 4, 1, 1, 0, 0, 0, 0], [clock.ctypes.data], [b"\xc0"], [0.5], 0.0)
