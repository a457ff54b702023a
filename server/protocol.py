"""The streaming protocol's wire messages, defined once.

Every WebSocket message is a msgpack map with a ``type`` field. The messages are the frozen
dataclasses below: ``CLIENT_MESSAGES`` (browser or engine -> server) and ``SERVER_MESSAGES``.
Each field carries its wire kind and a one-line description in its metadata; docs/protocol.md
and web_client/static/protocol.js are checked against these definitions by tests
(``python -m server.protocol --js`` writes the JavaScript table).

Arrays travel as raw little-endian bytes (msgpack ``bin``): faces as uint32 triples, vertices as
float32 triples or, with the ``q16`` codec, uint16 triples quantised over the topology's
``bounds``: ``v = bounds_min + q * (bounds_max - bounds_min) / 65535``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from dataclasses import dataclass, field

import msgpack
import numpy as np

from engine.player import MODES  # the blend modes a client may ask for

PROTOCOL_VERSION = 1
CODECS = ("f32", "q16")

# wire kinds: how a field is checked and documented
KINDS = {
    "str": "string",
    "int": "integer",
    "float": "number (finite)",
    "bool": "boolean",
    "params": "map of parameter name -> number",
    "floats": "array of numbers",
    "strs": "array of strings",
    "bytes": "binary (msgpack bin)",
    "objects": "array of maps",
}


def wire(kind, doc, *, default=dataclasses.MISSING, optional=False):
    """A message field: its wire ``kind`` (a KINDS key), description, and default if optional."""
    metadata = {"kind": kind, "doc": doc, "optional": optional or default is not dataclasses.MISSING}
    if default is dataclasses.MISSING and optional:
        default = None
    return field(default=default, metadata=metadata)


class ProtocolError(ValueError):
    """A client message the server cannot act on; answered with an Error message."""

    def __init__(self, code, message, ref=None, seq=None):
        super().__init__(message)
        self.code, self.message, self.ref, self.seq = code, message, ref, seq


# ---------------------------------------------------------------- client -> server

@dataclass(frozen=True)
class Hello:
    """Start (or switch) streaming a motion space. The server answers with Topology, then frames."""
    type = "hello"
    space: str = wire("str", "motion space name (GET /v1/spaces lists them)")
    codec: str = wire("str", "vertex codec: 'f32' (float32) or 'q16' (16-bit quantised over bounds)", default="f32")
    rate: float = wire("float", "frames per second wanted (0 < rate <= server limit, default 60); 0 = pull only", default=60.0)
    mode: str = wire("str", "blend mode: 'linear', 'hybrid' or 'nonlinear'", default="hybrid")
    params: dict = wire("params", "initial parameters (default: the middle of each range)", optional=True)
    smoothing: float = wire("float", "seconds of parameter smoothing (critically damped; 0 = none)", default=0.25)
    window: int = wire("int", "frames in flight before the server waits for Ack (0 = no acks, TCP backpressure only)", default=0)
    heatmap: bool = wire("bool", "send each frame's per-vertex distance from the non-linear blend", default=False)
    seq: int = wire("int", "client sequence number, echoed as the frames' ack", default=0)


@dataclass(frozen=True)
class Params:
    """Request new high-level parameters (only the named ones change)."""
    type = "params"
    params: dict = wire("params", "parameter name -> value, in the space's units")
    immediate: bool = wire("bool", "jump there at once instead of smoothing", default=False)
    seq: int = wire("int", "client sequence number, echoed as the frames' ack", default=0)


@dataclass(frozen=True)
class Mode:
    """Switch the blend mode (compare linear / hybrid / non-linear live)."""
    type = "mode"
    mode: str = wire("str", "'linear', 'hybrid' or 'nonlinear'")
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Rate:
    """Change the frame rate."""
    type = "rate"
    rate: float = wire("float", "frames per second (0 = pull only)")
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Pause:
    """Stop the clock; frames stop until Resume (Seek and Params still answer with one frame)."""
    type = "pause"
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Resume:
    """Restart the clock after Pause."""
    type = "resume"
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Seek:
    """Jump to a phase of the cycle (or clip); the root stays where it is."""
    type = "seek"
    phase: float = wire("float", "phase in [0, 1]")
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Reset:
    """Back to phase 0 at the origin, facing +Z."""
    type = "reset"
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Heatmap:
    """Turn the per-vertex error against the non-linear blend on or off."""
    type = "heatmap"
    on: bool = wire("bool", "send error_um with every frame")
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Pull:
    """Ask for the frame at these parameters and this time (engines with their own clock).

    Answered by one Frame with ``pull_id`` set; the stream's own state is not changed. The root
    transform is the path from the origin over ``time`` seconds at constant parameters.
    """
    type = "pull"
    id: int = wire("int", "request id, echoed as the frame's pull_id")
    params: dict = wire("params", "parameter name -> value (missing ones: the stream's current request)", optional=True)
    time: float = wire("float", "seconds since the start of the cycle or clip (>= 0)", optional=True)
    phase: float = wire("float", "or the phase in [0, 1] directly", optional=True)
    mode: str = wire("str", "blend mode (default: the stream's)", optional=True)


@dataclass(frozen=True)
class Ack:
    """Acknowledge a frame (needed only when Hello asked for a window)."""
    type = "ack"
    frame: int = wire("int", "seq of the newest frame received")


# ---------------------------------------------------------------- server -> client

@dataclass(frozen=True)
class Topology:
    """Sent once per Hello, before any frame: the mesh structure and how frames are coded."""
    type = "topology"
    protocol: int = wire("int", "protocol version")
    space: str = wire("str", "motion space name")
    n_vertices: int = wire("int", "vertices per frame")
    n_faces: int = wire("int", "triangles")
    faces: bytes = wire("bytes", "n_faces x 3 uint32, little-endian, counter-clockwise")
    codec: str = wire("str", "'f32' or 'q16'")
    bounds_min: list = wire("floats", "q16 box minimum corner (m, root-local)")
    bounds_max: list = wire("floats", "q16 box maximum corner (m, root-local)")
    quantisation_error: float = wire("float", "largest position error the codec adds (m); 0 for f32")
    parameters: list = wire("objects", "per parameter {name, unit, min, max, value}")
    sources: list = wire("strs", "source sequence names, in weight order")
    durations: list = wire("floats", "seconds per source (one cycle or the clip)")
    cyclic: bool = wire("bool", "the motion loops")
    mode: str = wire("str", "current blend mode")
    modes: list = wire("strs", "available blend modes")
    rate: float = wire("float", "frames per second the server will send")
    model_size: float = wire("float", "largest extent of the rest mesh (m)")
    limits: dict = wire("params", "max_message (bytes), max_rate (messages/s), burst, max_fps")


@dataclass(frozen=True)
class Frame:
    """One blended frame. Vertices are root-local; place them with the root transform
    (rotate by ``heading`` about +Y, then translate by ``root``)."""
    type = "frame"
    seq: int = wire("int", "frame number on this connection (pulls included)")
    ack: int = wire("int", "seq of the newest client message applied to this frame")
    time: float = wire("float", "seconds on the stream's clock")
    phase: float = wire("float", "phase in [0, 1] of the cycle or clip")
    mode: str = wire("str", "blend mode of this frame")
    requested: list = wire("floats", "parameters on their way (smoothed) to the nearest reachable ones of the last request")
    realised: list = wire("floats", "parameters the blend realises")
    clamped: bool = wire("bool", "the request is outside the reachable domain")
    weights: list = wire("floats", "blend weights, one per source")
    root: list = wire("floats", "root position [x, y, z] (m, world)")
    heading: float = wire("float", "root heading (radians about +Y; 0 faces +Z)")
    vertices: bytes = wire("bytes", "n_vertices x 3, f32 or q16 per the topology's codec")
    dropped: int = wire("int", "frames skipped so far because the client fell behind")
    finished: bool = wire("bool", "a one-shot clip reached its end")
    sent_at: float = wire("float", "server wall clock (s since the epoch) when encoded")
    pull_id: int = wire("int", "the Pull's id, or nil for streamed frames", optional=True)
    error_um: bytes = wire("bytes", "with heatmap on: n_vertices uint16 distances from the non-linear blend (micrometres, saturating)", optional=True)
    error_max: float = wire("float", "with heatmap on: the largest of those distances (m)", optional=True)


@dataclass(frozen=True)
class Notice:
    """Something the client should know that is not an error (e.g. a request was clamped)."""
    type = "notice"
    code: str = wire("str", "'clamped' (a request was outside the reachable domain)")
    message: str = wire("str", "human-readable explanation")
    seq: int = wire("int", "the client message it answers", default=0)


@dataclass(frozen=True)
class Error:
    """A client message was not acted on. The connection stays open."""
    type = "error"
    code: str = wire("str", "one of ERROR_CODES")
    message: str = wire("str", "human-readable explanation naming the problem")
    ref: str = wire("str", "type of the offending message, if known", optional=True)
    seq: int = wire("int", "seq of the offending message, if known", optional=True)


ERROR_CODES = {
    "malformed": "not msgpack, or not a map with a string `type`",
    "unknown_type": "`type` names no client message",
    "invalid_field": "a field is missing, of the wrong kind, non-finite or out of range",
    "unknown_space": "no motion space of that name",
    "not_playable": "the space has no parameter map",
    "not_ready": "a message other than hello before the first hello",
    "too_large": "the message exceeds the per-connection size limit",
    "rate_limited": "more messages than the per-connection rate allows; the message was dropped",
    "invalid_params": "unknown parameter names or non-finite values",
    "server_busy": "the server has as many connections as it accepts",
    "internal": "the server failed to act on a valid message (reported, connection kept)",
}

CLIENT_MESSAGES = {m.type: m for m in (Hello, Params, Mode, Rate, Pause, Resume, Seek, Reset, Heatmap, Pull, Ack)}
SERVER_MESSAGES = {m.type: m for m in (Topology, Frame, Notice, Error)}


def fields_of(message):
    """[(name, kind, optional, doc)] of a message class, ``type`` first."""
    rows = [("type", "str", False, f"'{message.type}'")]
    for f in dataclasses.fields(message):
        rows.append((f.name, f.metadata["kind"], f.metadata["optional"], f.metadata["doc"]))
    return rows


# ---------------------------------------------------------------- decoding and encoding

def _check(kind, name, value, ref, seq):
    def bad(what):
        raise ProtocolError("invalid_field", f"{ref}.{name}: {what}", ref=ref, seq=seq)
    if kind == "str":
        if not isinstance(value, str):
            bad(f"expected a string, got {type(value).__name__}")
        if len(value) > 256:
            bad("longer than 256 characters")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            bad(f"expected true or false, got {type(value).__name__}")
        return value
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            bad(f"expected an integer, got {type(value).__name__}")
        if not -2**53 <= value <= 2**53:
            bad("integer out of range")
        return value
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            bad(f"expected a number, got {type(value).__name__}")
        if not math.isfinite(value):
            bad(f"must be finite, got {value}")
        return float(value)
    if kind == "params":
        if not isinstance(value, dict):
            bad(f"expected a map of name -> number, got {type(value).__name__}")
        if len(value) > 64:
            bad("more than 64 entries")
        out = {}
        for key, number in value.items():
            if not isinstance(key, str):
                bad("parameter names must be strings")
            if isinstance(number, bool) or not isinstance(number, (int, float)):
                bad(f"{key!r} must be a number, got {type(number).__name__}")
            if not math.isfinite(number):
                raise ProtocolError("invalid_params", f"{ref}.{name}: {key} must be finite, got {number}",
                                    ref=ref, seq=seq)
            out[key] = float(number)
        return out
    raise AssertionError(f"no client decoding for kind {kind}")


def decode_client(data, max_bytes=None):
    """A client message object from raw WebSocket data (bytes, or text holding JSON).

    Raises ProtocolError naming the problem: malformed data, an unknown ``type``, missing or
    invalid fields, unknown extra fields.
    """
    if max_bytes is not None and len(data) > max_bytes:
        raise ProtocolError("too_large", f"message of {len(data)} bytes exceeds the limit of {max_bytes}")
    try:
        if isinstance(data, str):
            raw = json.loads(data)
        else:
            raw = msgpack.unpackb(data, raw=False, strict_map_key=True, max_bin_len=0, max_ext_len=0)
    except (ValueError, msgpack.UnpackException, msgpack.ExtraData, TypeError, RecursionError) as exc:
        raise ProtocolError("malformed", f"not a msgpack (or JSON text) message ({type(exc).__name__}: {exc})") from None
    if not isinstance(raw, dict) or not isinstance(raw.get("type"), str):
        raise ProtocolError("malformed", "a message must be a map with a string 'type' field")
    kind = raw["type"]
    seq = raw.get("seq") if isinstance(raw.get("seq"), int) and not isinstance(raw.get("seq"), bool) else None
    cls = CLIENT_MESSAGES.get(kind)
    if cls is None:
        raise ProtocolError("unknown_type", f"unknown message type {kind[:64]!r}; expected one of "
                            f"{', '.join(CLIENT_MESSAGES)}", ref=kind[:64], seq=seq)
    known = {f.name: f for f in dataclasses.fields(cls)}
    extra = sorted(set(raw) - set(known) - {"type"})
    if extra:
        raise ProtocolError("invalid_field", f"{kind}: unknown field(s) {', '.join(map(str, extra))[:200]}",
                            ref=kind, seq=seq)
    values = {}
    for name, f in known.items():
        if name not in raw or raw[name] is None:
            if not f.metadata["optional"]:
                raise ProtocolError("invalid_field", f"{kind}.{name} is required", ref=kind, seq=seq)
            continue
        values[name] = _check(f.metadata["kind"], name, raw[name], kind, seq)
    return cls(**values)


_FIELD_NAMES = {}


def to_wire(message):
    """The msgpack bytes of a server (or client) message object."""
    cls = type(message)
    names = _FIELD_NAMES.get(cls)
    if names is None:
        names = _FIELD_NAMES[cls] = tuple(f.name for f in dataclasses.fields(cls))
    body = {"type": message.type}
    for name in names:
        body[name] = getattr(message, name)
    return msgpack.packb(body, use_bin_type=True)


def frame_wire(**values):
    """The msgpack bytes of ``Frame(**values)`` without building the object: the streaming hot
    path. Give every required Frame field (tests decode these bytes into a Frame)."""
    return msgpack.packb({"type": "frame", **values}, use_bin_type=True)


def decode_server(data):
    """A server message object from msgpack bytes (for clients written in Python)."""
    raw = msgpack.unpackb(data, raw=False)
    cls = SERVER_MESSAGES.get(raw.get("type")) if isinstance(raw, dict) else None
    if cls is None:
        raise ProtocolError("malformed", f"unknown server message {raw!r:.80}")
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in raw.items() if k in names})


# ---------------------------------------------------------------- vertex codecs

def quantisation_error(bounds):
    """Largest distance (m) between a point in ``bounds`` and its q16 reconstruction: half a
    step along each axis."""
    step = (np.asarray(bounds[1], dtype=np.float64) - np.asarray(bounds[0], dtype=np.float64)) / 65535.0
    return float(np.linalg.norm(step / 2))


class Quantiser:
    """The q16 codec over a box: ``q = round((v - lo) * 65535 / (hi - lo))`` per axis, clamped
    to [0, 65535].

    ``Quantiser(bounds, n_vertices).encode(V)`` is the hot path: the per-axis scale and offset
    are tiled over the flat (x, y, z, x, ...) array once, so every step is one contiguous pass.
    ``scale`` and ``offset`` (3,) float32 map metres to the codec's units *before* rounding
    (``offset`` includes the + 0.5 of round-to-nearest): ``floor(v * scale + offset)``.
    """

    def __init__(self, bounds, n_vertices):
        lo, hi = np.asarray(bounds[0], dtype=np.float32), np.asarray(bounds[1], dtype=np.float32)
        self.scale = (np.float32(65535.0) / np.maximum(hi - lo, np.float32(1e-12))).astype(np.float32)
        self.offset = (np.float32(0.5) - lo * self.scale).astype(np.float32)
        self.n_vertices = int(n_vertices)
        self._scale = np.tile(self.scale, self.n_vertices)
        self._offset = np.tile(self.offset, self.n_vertices)
        self._q = np.empty(3 * self.n_vertices, dtype=np.float32)
        self.key = ("q16", self.scale.tobytes(), self.offset.tobytes())

    def encode(self, V):
        """Raw little-endian uint16 bytes of (n, 3) vertices."""
        q = self._q
        np.multiply(np.asarray(V, dtype=np.float32).reshape(-1), self._scale, out=q)
        np.add(q, self._offset, out=q)
        np.maximum(q, np.float32(0.0), out=q)
        np.minimum(q, np.float32(65535.0), out=q)
        return q.astype("<u2").tobytes()

    def table(self, table):
        """A PhaseTable (engine.blend.cache) in codec units: interpolating its rows and
        truncating to uint16 gives the encoded frame."""
        return table.scaled(self.scale, self.offset, 0.0, 65535.0, key=self.key)


def encode_vertices(V, codec, bounds):
    """Raw little-endian bytes of (n, 3) vertices in ``codec``; q16 clamps to ``bounds``."""
    if codec == "f32":
        return np.ascontiguousarray(V, dtype="<f4").tobytes()
    return Quantiser(bounds, len(V)).encode(V)


def decode_vertices(data, codec, n_vertices, bounds_min=None, bounds_max=None):
    """(n, 3) float32 vertices from a frame's bytes (the inverse of encode_vertices)."""
    if codec == "f32":
        return np.frombuffer(data, dtype="<f4").reshape(n_vertices, 3)
    lo = np.asarray(bounds_min, dtype=np.float32)
    hi = np.asarray(bounds_max, dtype=np.float32)
    q = np.frombuffer(data, dtype="<u2").reshape(n_vertices, 3).astype(np.float32)
    return lo + q * ((hi - lo) / np.float32(65535.0))


# ---------------------------------------------------------------- documentation tables

def markdown_table(message):
    """The field table of one message as docs/protocol.md shows it (a test compares them)."""
    defaults = {f.name: f.default for f in dataclasses.fields(message)}
    rows = ["| field | kind | required | meaning |", "|---|---|---|---|"]
    for name, kind, optional, doc in fields_of(message):
        default = defaults.get(name)
        required = "yes" if not optional else ("no" if default is None else f"no (default `{json.dumps(default)}`)")
        rows.append(f"| `{name}` | {KINDS[kind]} | {required} | {doc.replace('|', '/')} |")
    return "\n".join(rows)


# ---------------------------------------------------------------- JavaScript table

def javascript():
    """web_client/static/protocol.js: the message table the browser client builds its messages from."""
    def table(messages):
        return {t: [name for name, *_ in fields_of(cls)] for t, cls in messages.items()}
    lines = [
        "// Generated from server/protocol.py by `python -m server.protocol --js`; do not edit.",
        "// A test checks that this file matches the server's message definitions.",
        f"export const PROTOCOL_VERSION = {PROTOCOL_VERSION};",
        f"export const CODECS = {json.dumps(list(CODECS))};",
        f"export const MODES = {json.dumps(list(MODES))};",
        f"export const CLIENT_MESSAGES = {json.dumps(table(CLIENT_MESSAGES), indent=2)};",
        f"export const SERVER_MESSAGES = {json.dumps(table(SERVER_MESSAGES), indent=2)};",
        f"export const ERROR_CODES = {json.dumps(list(ERROR_CODES))};",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    if sys.argv[1:] == ["--js"]:
        sys.stdout.write(javascript())
    elif sys.argv[1:] == ["--markdown"]:
        for table in (CLIENT_MESSAGES, SERVER_MESSAGES):
            for kind, message in table.items():
                print(f"### `{kind}`\n\n{markdown_table(message)}\n")
    else:
        print("usage: python -m server.protocol --js | --markdown", file=sys.stderr)
        sys.exit(2)
