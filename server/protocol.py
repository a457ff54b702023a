"""The streaming protocol's wire messages, defined once.

Every WebSocket message is a msgpack map with a ``type`` field. The messages are the frozen
dataclasses below: ``CLIENT_MESSAGES`` (browser or engine -> server) and ``SERVER_MESSAGES``.
Each field carries its wire kind, its range and a one-line description in its metadata, and
decoding checks them from there; docs/protocol.md (its message tables, error codes and their
order, close codes) and web_client/static/protocol.js are rendered from these definitions by
server/protocol_docs.py and checked against them by tests.

Arrays travel as raw little-endian bytes (msgpack ``bin``): faces as uint32 triples, vertices in
one of the codecs of server/codecs.py (re-exported here).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import msgpack

from engine.player import MODES  # the blend modes a client may ask for
from server.codecs import Quantiser, decode_vertices, encode_vertices, quantisation_error  # noqa: F401 (re-exported)

PROTOCOL_VERSION = 1
CODECS = ("f32", "q16")
INT_LIMIT = 2**53  # integers travel as JSON-safe numbers: |n| <= 2^53

# wire kinds: how a field is checked and documented
KINDS = {
    "str": "string",
    "int": "integer (-2^53 to 2^53)",
    "float": "number (finite)",
    "bool": "boolean",
    "params": "map of parameter name -> number (at most 64)",
    "numbers": "map of name -> number",
    "floats": "array of numbers",
    "strs": "array of strings",
    "bytes": "binary (msgpack bin)",
    "objects": "array of maps",
}

# the keys of each topology.parameters entry, topology.nodes entry and of topology.limits, in order
PARAMETER_KEYS = ("name", "unit", "min", "max", "default", "value")
NODE_KEYS = ("name", "space", "cyclic", "return_to", "parameters")
LIMITS = {"max_message": "bytes", "max_rate": "messages/s", "burst": "messages", "max_fps": "frames/s",
          "stall_timeout": "s"}


def wire(kind, doc, *, default=dataclasses.MISSING, optional=False, low=None, high=None, one_of=None,
         choices=None):
    """A message field: its wire ``kind`` (a KINDS key), description, default if optional, the
    range ``[low, high]`` decoding enforces (``high`` may name a ``topology.limits`` key), the
    ``choices`` a string must be one of, and ``one_of``: a group of optional fields of which a
    message must carry exactly one."""
    metadata = {"kind": kind, "doc": doc, "optional": optional or default is not dataclasses.MISSING,
                "low": low, "high": high, "one_of": one_of, "choices": choices}
    if default is dataclasses.MISSING and optional:
        default = None
    return field(default=default, metadata=metadata)


def spring_times(fractions=(0.5, 0.9, 0.99)):
    """Times, in units of the smoothing time constant, at which the player's critically damped
    spring (engine.player) has covered ``fractions`` of a step: ``1 - (1 + x) exp(-x) = f``."""
    out = []
    for f in fractions:
        lo, hi = 0.0, 50.0
        for _ in range(100):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if 1 - (1 + mid) * math.exp(-mid) < f else (lo, mid)
        out.append(round((lo + hi) / 2, 2))
    return out


_SPRING = spring_times()


class ProtocolError(ValueError):
    """A client message the server cannot act on; answered with an Error message."""

    def __init__(self, code, message, ref=None, seq=None):
        super().__init__(message)
        self.code, self.message, self.ref, self.seq = code, message, ref, seq


# ---------------------------------------------------------------- client -> server

@dataclass(frozen=True)
class Hello:
    """Start (or switch) streaming a motion space, or a motion graph (its nodes are spaces; steer it
    with Action). The server answers with Topology, then frames."""
    type = "hello"
    space: str = wire("str", "motion space name (GET /v1/spaces lists them)", optional=True, one_of="stream")
    graph: str = wire("str", "or a motion graph name (GET /v1/graphs lists them)", optional=True, one_of="stream")
    node: str = wire("str", "with graph: the start node (default: the graph's first cyclic node); with space: invalid_field",
                     optional=True)
    codec: str = wire("str", "vertex codec: 'f32' (float32) or 'q16' (16-bit quantised over bounds)", default="f32",
                      choices=CODECS)
    rate: float = wire("float", "frames per second wanted; 0 = pull only (no streamed frames at all)", default=60.0,
                       low=0.0, high="max_fps")
    mode: str = wire("str", "blend mode", default="hybrid", choices=MODES)
    params: dict = wire("params", "initial parameters (default: the middle of each range); with graph: the start "
                        "node's", optional=True)
    smoothing: float = wire("float", "time constant (s) of the critically damped spring that moves the parameters "
                            "to a new request: 50% / 90% / 99% of the way after "
                            f"{_SPRING[0]} / {_SPRING[1]} / {_SPRING[2]} x smoothing; 0 = at once (a graph's "
                            "nodes take new parameters at once)", default=0.25,
                            low=0.0, high=10.0)
    window: int = wire("int", "frames in flight before the server waits for Ack (0 = no acks, TCP backpressure only)",
                       default=0, low=0, high=64)
    heatmap: bool = wire("bool", "send each frame's per-vertex distance from the non-linear blend (spaces only)",
                         default=False)
    seq: int = wire("int", "client sequence number, echoed as the frames' ack", default=0)


@dataclass(frozen=True)
class Params:
    """Request new high-level parameters (only the named ones change)."""
    type = "params"
    params: dict = wire("params", "parameter name -> value, in the space's units")
    immediate: bool = wire("bool", "jump there at once instead of smoothing (while paused, the only way to "
                                            "see new parameters before Resume)", default=False)
    seq: int = wire("int", "client sequence number, echoed as the frames' ack", default=0)


@dataclass(frozen=True)
class Mode:
    """Switch the blend mode (compare linear / hybrid / non-linear live)."""
    type = "mode"
    mode: str = wire("str", "blend mode", choices=MODES)
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Rate:
    """Change the frame rate. With ``rate`` 0 the streamed frames stop and none answers this
    message: the next Pull's frame carries its ``seq`` as ``ack``."""
    type = "rate"
    rate: float = wire("float", "frames per second (0 = pull only: no streamed frames)", low=0.0, high="max_fps")
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Pause:
    """Stop the clock; frames stop until Resume (Seek and Params still answer with one frame). A
    smoothed Params waits for the clock: the frame answering it shows the parameters where they
    were, and the move towards the new ones starts on Resume (with ``immediate``, at once)."""
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
    phase: float = wire("float", "phase of the cycle or clip; the next frame shows exactly this phase (on a looping "
                             "space 1 is the cycle's start and shows as 0; on a one-shot 1 is its last pose, "
                             "`finished` from the frame after)", low=0.0, high=1.0)
    seq: int = wire("int", "client sequence number", default=0)


@dataclass(frozen=True)
class Reset:
    """Back to phase 0 at the origin, facing +Z (the next frame shows exactly that: time 0)."""
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
    transform is the path from the origin over ``time`` seconds at constant parameters (with
    ``phase``, over the time that phase is into the cycle or clip: the frame's ``time``; REST's
    ``GET /v1/spaces/{name}/frame?phase=`` puts the root at the origin instead). Every pull is
    answered, in order, none dropped or merged; an answer is written, as a streamed frame is,
    only once the connection has taken every earlier byte, and the connection's later messages
    wait for it (a client that reads nothing for the stall timeout is closed with 1008).
    """
    type = "pull"
    id: int = wire("int", "request id, echoed as the frame's pull_id")
    params: dict = wire("params", "parameter name -> value (missing ones: the stream's current request)", optional=True)
    time: float = wire("float", "seconds since the start of the cycle or clip", optional=True, low=0.0, high=86400.0,
                       one_of="when")
    phase: float = wire("float", "or the phase directly", optional=True, low=0.0, high=1.0, one_of="when")
    mode: str = wire("str", "blend mode (default: the stream's)", optional=True, choices=MODES)


@dataclass(frozen=True)
class Action:
    """On a graph stream: go to a node at these parameters (walk -> jump 0.5 m high). The server
    plans the transition at once (when to leave, where to enter, how long to blend) and plays it;
    frames say the node, the target and the blend's progress. A node without an edge from the
    current one is reached along the shortest route; an action during a blend, or during a
    one-shot that cannot be left for that node, waits for it to end. A one-shot returns to its
    cyclic node by itself."""
    type = "action"
    node: str = wire("str", "target node (topology.nodes lists them)")
    params: dict = wire("params", "the node's parameters (missing ones: what the node was last asked for, at first "
                        "the middle of each range)", optional=True)
    budget: float = wire("float", "seconds within which the transition should be complete (default: the search's "
                         "own balance of smoothness and latency; if nothing fits, the quickest)", optional=True,
                         low=0.05, high=60.0)
    seq: int = wire("int", "client sequence number, echoed as the frames' ack", default=0)


@dataclass(frozen=True)
class Ack:
    """Acknowledge a frame (needed only when Hello asked for a window; ignored without one). A
    ``frame`` beyond the newest frame sent counts as the newest."""
    type = "ack"
    frame: int = wire("int", "seq of the newest frame received", low=0)


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
    parameters: list = wire("objects", "per parameter {" + ", ".join(PARAMETER_KEYS) + "}: value is the current "
                            "request as it was asked (before any clamping), default the middle of the range; "
                            "min and max bound the captured parameters, not every combination is reachable "
                            "(see Limits)")
    sources: list = wire("strs", "source sequence names, in weight order")
    durations: list = wire("floats", "seconds per source (one cycle or the clip)")
    cyclic: bool = wire("bool", "the motion loops")
    mode: str = wire("str", "current blend mode")
    modes: list = wire("strs", "available blend modes")
    rate: float = wire("float", "frames per second the server will send")
    model_size: float = wire("float", "largest extent of the rest mesh (m)")
    limits: dict = wire("numbers", ", ".join(f"{k} ({unit})" for k, unit in LIMITS.items()))
    graph: str = wire("str", "the motion graph streamed, or nil for a space (then space, parameters, sources, "
                      "durations and cyclic describe the start node; bounds cover every node)", optional=True)
    nodes: list = wire("objects", "with graph: per node {" + ", ".join(NODE_KEYS) + "}; parameters as in "
                       "`parameters` (value: what the node is asked for now)", optional=True)
    edges: list = wire("objects", "with graph: the allowed transitions, {from, to} node names", optional=True)


@dataclass(frozen=True)
class Frame:
    """One blended frame. Vertices are root-local; place them with the root transform
    (rotate by ``heading`` about +Y, then translate by ``root``)."""
    type = "frame"
    seq: int = wire("int", "frame number on this connection (pulls included)")
    ack: int = wire("int", "the highest seq of the client messages applied so far (not the most recent "
                         "one's: keep seq increasing)")
    time: float = wire("float", "seconds on the stream's clock")
    phase: float = wire("float", "phase in [0, 1] of the cycle or clip")
    mode: str = wire("str", "blend mode of this frame")
    requested: list = wire("floats", "a streamed frame: the parameters on their way (smoothed) to the nearest "
                            "reachable ones of the last request; a pulled frame: the pull's request as asked; "
                            "a graph's frame: the node's parameters as last asked (not smoothed, not clamped)")
    realised: list = wire("floats", "parameters the blend realises")
    clamped: bool = wire("bool", "the request is outside the reachable domain")
    weights: list = wire("floats", "blend weights, one per source")
    root: list = wire("floats", "root position [x, y, z] (m, world)")
    heading: float = wire("float", "root heading (radians about +Y; 0 faces +Z)")
    vertices: bytes = wire("bytes", "n_vertices x 3, f32 or q16 per the topology's codec")
    dropped: int = wire("int", "frames skipped so far: due frames not sent because the client fell behind "
                               "(its transport still held earlier bytes) or the server did (a frame more "
                               "than a period late)")
    finished: bool = wire("bool", "a one-shot clip reached its end")
    sent_at: float = wire("float", "server wall clock (s since the epoch) when encoded")
    pull_id: int = wire("int", "the Pull's id, or nil for streamed frames", optional=True)
    error_um: bytes = wire("bytes", "with heatmap on: n_vertices uint16 distances from the non-linear blend (micrometres, saturating)", optional=True)
    error_max: float = wire("float", "with heatmap on: the largest of those distances (m)", optional=True)
    error_seq: int = wire("int", "with heatmap on: the seq of the frame error_um describes (computed off the event "
                                 "loop: an earlier frame, a few frames or, with dozens of heatmap viewers, a few "
                                 "tenths of a second back; this one in nonlinear mode); nil until the first is ready (1-2 s "
                                 "after turning it on for a space no client has used it on yet: the helper "
                                 "process first loads the space and factorises its non-linear solver; that "
                                 "first one describes a frame as old as the wait)",
                          optional=True)
    node: str = wire("str", "graph streams: the node shown (during a blend, the one being left); nil for a space",
                     optional=True)
    target: str = wire("str", "graph streams: the node a planned or blending transition goes to, else nil",
                       optional=True)
    progress: float = wire("float", "graph streams: the blend's progress 0..1, nil when not blending (phase, "
                           "requested, realised, clamped and weights are the node's)", optional=True)


@dataclass(frozen=True)
class Notice:
    """Something the client should know that is not an error (e.g. a request was clamped)."""
    type = "notice"
    code: str = wire("str", "'clamped' (a request was outside the reachable domain), 'planned' (an action's "
                     "transition: when it leaves, how long it blends; sent again, with the action's seq, when a "
                     "queued action is planned), 'queued' (an action waits for a blend or a one-shot to end), "
                     "'superseded' (an earlier action, seq, is dropped before it was carried out: a later one "
                     "replaced it)")
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
    "unknown_graph": "no motion graph of that name, or its file cannot be used (the message says why)",
    "unknown_node": "the graph has no node of that name",
    "unsupported": "the message does not apply to this stream (`action` on a space; `seek`, `heatmap`, `pull` "
                   "or a hello's `heatmap` on a graph)",
    "not_playable": "the space has no parameter map",
    "not_ready": "a message other than hello (or ack) before the first hello",
    "too_large": "the message exceeds `limits.max_message` bytes",
    "rate_limited": "more messages than the per-connection rate allows; the message was dropped",
    "invalid_params": "unknown parameter names or non-finite values",
    "server_busy": "the server has as many connections as it accepts",
    "internal": "the server failed to act on a valid message (reported, connection kept)",
}

# The order of a client message's checks: the first that fails answers (a message failing two
# checks gets the earlier one's error).
CHECK_ORDER = (
    ("rate_limited", "the connection's message budget"),
    ("too_large", "the message's size"),
    ("malformed", "msgpack (or JSON text) holding a map with a string `type`"),
    ("unknown_type", "the `type`"),
    ("invalid_field", "every field: present if required, no unknown ones, its kind, finite, in its range or "
                      "among its choices, exactly one of a `one of` group (non-finite parameter values: "
                      "`invalid_params`)"),
    ("not_ready", "a `hello` first (an `ack` before it is ignored)"),
    ("unknown_space", "the space (then `not_playable`), for `hello`"),
    ("unknown_graph", "the graph, for a `hello` naming one"),
    ("unsupported", "the message for what the connection streams (a space or a graph)"),
    ("unknown_node", "the node, for `action` and a `hello` naming a graph"),
    ("invalid_params", "parameter names, for `hello`, `params`, `pull` and `action`"),
)

# WebSocket close codes the server sends (the connection ends; see docs/protocol.md)
CLOSE_STALLED, CLOSE_TOO_BIG, CLOSE_INTERNAL, CLOSE_BUSY = 1008, 1009, 1011, 1013
CLOSE_CODES = {
    CLOSE_STALLED: "the client took no due frame for `stall_timeout` seconds (reason `stalled: ...`)",
    CLOSE_TOO_BIG: "a message over max(1 MiB, 4 x `max_message`): refused by the WebSocket layer itself",
    CLOSE_INTERNAL: "the server failed to produce a frame (after an `internal` error; reason `internal error: ...`) "
                    "or to send (reason `sending failed`), or the client answered no keepalive ping (reason "
                    "`keepalive ping timeout`)",
    CLOSE_BUSY: "the server has as many connections as it accepts (after a `server_busy` error; reason "
                "`server busy: ...`)",
}


def websocket_max_size(max_message):
    """Bytes of the largest message the WebSocket layer accepts before closing with 1009."""
    return max(1 << 20, 4 * max_message)


CLIENT_MESSAGES = {m.type: m for m in (Hello, Params, Mode, Rate, Pause, Resume, Seek, Reset, Heatmap, Pull, Action,
                                        Ack)}
SERVER_MESSAGES = {m.type: m for m in (Topology, Frame, Notice, Error)}


def fields_of(message):
    """[(name, kind, optional, doc)] of a message class, ``type`` first."""
    rows = [("type", "str", False, f"'{message.type}'")]
    for f in dataclasses.fields(message):
        rows.append((f.name, f.metadata["kind"], f.metadata["optional"], f.metadata["doc"]))
    return rows


# ---------------------------------------------------------------- encoding

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


def decode_server(data):
    """A server message object from msgpack bytes (for clients written in Python)."""
    raw = msgpack.unpackb(data, raw=False)
    cls = SERVER_MESSAGES.get(raw.get("type")) if isinstance(raw, dict) else None
    if cls is None:
        raise ProtocolError("malformed", f"unknown server message {raw!r:.80}")
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in raw.items() if k in names})
