"""Wire messages: decoding is strict and never fails with anything but a ProtocolError; the
codecs' error bound is what the topology reports; docs/protocol.md shows the code's messages."""

import json
import re
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server import protocol as P
from server import protocol_docs as D
from server.decoding import decode_client

DOC = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"


def test_a_full_hello_decodes_to_its_dataclass():
    m = decode_client(msgpack.packb({"type": "hello", "space": "walk", "codec": "q16", "rate": 30,
                                       "params": {"speed": 2}, "window": 2, "seq": 4}))
    assert m == P.Hello(space="walk", codec="q16", rate=30.0, params={"speed": 2.0}, window=2, seq=4)
    assert isinstance(m.rate, float) and isinstance(m.params["speed"], float)


def test_json_text_decodes_like_msgpack():
    assert decode_client('{"type": "seek", "phase": 0.5, "seq": 2}') == P.Seek(phase=0.5, seq=2)


@pytest.mark.parametrize("raw, code", [
    ({"type": "seek"}, "invalid_field"),
    ({"type": "seek", "phase": True}, "invalid_field"),
    ({"type": "seek", "phase": "0.5"}, "invalid_field"),
    ({"type": "seek", "phase": float("nan")}, "invalid_field"),
    ({"type": "hello", "space": "x" * 300}, "invalid_field"),
    ({"type": "params", "params": {"a": float("-inf")}}, "invalid_params"),
    ({"type": "params", "params": {1: 2.0}}, "invalid_field"),  # valid msgpack; the field names the problem
    ({1: "hello", "type": "hello", "space": "x"}, "invalid_field"),  # an unknown non-string field
    ({"type": "ack", "frame": 2 ** 60}, "invalid_field"),
    ({"type": "Hello", "space": "x"}, "unknown_type"),
])
def test_invalid_messages_name_the_problem(raw, code):
    with pytest.raises(P.ProtocolError) as info:
        decode_client(msgpack.packb(raw, strict_types=False))
    assert info.value.code == code
    assert info.value.message


def test_the_size_limit_comes_first():
    with pytest.raises(P.ProtocolError, match="exceeds the limit") as info:
        decode_client(b"\x80" * 2000, max_bytes=1000)
    assert info.value.code == "too_large"


def test_a_text_message_is_measured_in_utf8_bytes():
    text = json.dumps({"type": "pause", "seq": 1, "pad": "\u20ac" * 400}, ensure_ascii=False)  # 3 bytes a euro
    assert len(text) < 1000 < len(text.encode("utf-8"))
    with pytest.raises(P.ProtocolError, match="message of 12.. bytes exceeds the limit of 1000") as info:
        decode_client(text, max_bytes=1000)
    assert info.value.code == "too_large"
    with pytest.raises(P.ProtocolError) as info:  # within the limit: on to the field checks
        decode_client(text, max_bytes=2000)
    assert info.value.code == "invalid_field"


@pytest.mark.parametrize("number", [2 ** 53 + 1, -(2 ** 53) - 1, 2 ** 64 - 1])
def test_an_error_echoes_only_a_seq_in_range(number):
    for raw in ({"type": "resume", "seq": number}, {"type": "pull", "id": number, "phase": 0.5}):
        with pytest.raises(P.ProtocolError) as info:
            decode_client(json.dumps(raw))
        assert info.value.code == "invalid_field" and info.value.seq is None, raw
    with pytest.raises(P.ProtocolError) as info:
        decode_client(json.dumps({"type": "resume", "seq": 2 ** 53, "x": 1}))
    assert info.value.seq == 2 ** 53


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_never_raise_anything_but_protocol_errors(data):
    try:
        decode_client(data)
    except P.ProtocolError as exc:
        assert exc.code in P.ERROR_CODES


def test_a_message_that_is_no_msgpack_gives_a_reason_without_an_empty_part():
    """msgpack's FormatError carries no text: the reason was "(FormatError: )" (a docs-only client)."""
    with pytest.raises(P.ProtocolError) as info:
        decode_client(b"\xc1\xc1\xc1")
    assert info.value.code == "malformed" and str(info.value).endswith("message (FormatError)"), str(info.value)


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.sampled_from(["type", "space", "phase", "params", "seq", "rate", "id", "frame", "x"]),
                       st.one_of(st.none(), st.booleans(), st.integers(-2**63, 2**64 - 1), st.floats(), st.text(max_size=5),
                                 st.sampled_from(list(P.CLIENT_MESSAGES)),
                                 st.dictionaries(st.text(max_size=3), st.floats(), max_size=3)),
                       max_size=5))
def test_random_maps_never_raise_anything_but_protocol_errors(raw):
    try:
        decode_client(msgpack.packb(raw))
    except P.ProtocolError as exc:
        assert exc.code in P.ERROR_CODES


@pytest.mark.parametrize("field", ['"rate": {n}', '"smoothing": {n}', '"params": {{"speed": {n}}}'])
@pytest.mark.parametrize("n", [2**53 + 1, -2**63, 2**64 + 5, 10**400, -10**400])
def test_any_integer_is_a_number(field, n):
    """Integers of any size where the doc says number (a docs-only client found params past 2^53
    refused, and a JSON integer past a double's range raised OverflowError out of the decoder): a
    parameter clamps as any finite number does, a number field past its range is refused by name."""
    text = '{"type": "hello", "space": "s", ' + field.format(n=n) + "}"
    try:
        hello = decode_client(text, None, {"max_fps": 120})
    except P.ProtocolError as exc:
        assert exc.code == "invalid_field" and not field.startswith('"params"'), exc
        assert ("rate" if "rate" in field else "smoothing") in exc.message
        return
    assert field.startswith('"params"')
    speed = hello.params["speed"]
    assert isinstance(speed, float) and speed == speed and abs(speed) < float("inf") and (speed > 0) == (n > 0)


def test_an_error_shows_the_value_sent():
    with pytest.raises(P.ProtocolError) as info:
        decode_client('{"type": "pull", "id": 7, "time": 86400.01}', None, {"max_time": 86400})
    assert info.value.message.endswith("got 86400.01"), info.value.message


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_q16_round_trip_error_is_within_the_reported_bound(seed):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-2, 0, 3).astype(np.float32)
    hi = (lo + rng.uniform(0.1, 3, 3)).astype(np.float32)
    V = rng.uniform(lo, hi, (500, 3)).astype(np.float32)
    bounds = np.stack([lo, hi])
    decoded = P.decode_vertices(P.encode_vertices(V, "q16", bounds), "q16", len(V), lo, hi)
    error = np.linalg.norm(decoded - V, axis=1).max()
    # half a step per axis, plus the float32 rounding of encoding and decoding (a few ulps of the
    # coordinates: 2.4e-7 m at 2 m)
    ulps = 4 * float(np.spacing(np.abs(bounds).max())) * np.sqrt(3)
    assert error <= P.quantisation_error(bounds) + ulps


def test_q16_clamps_outside_the_box_and_f32_is_exact():
    bounds = np.array([[0, 0, 0], [1, 1, 1]], dtype=np.float32)
    V = np.array([[-1, 0.5, 2]], dtype=np.float32)
    np.testing.assert_allclose(P.decode_vertices(P.encode_vertices(V, "q16", bounds), "q16", 1, *bounds),
                               [[0, 0.5, 1]], atol=1e-4)
    W = np.random.default_rng(0).normal(size=(10, 3)).astype(np.float32)
    np.testing.assert_array_equal(P.decode_vertices(P.encode_vertices(W, "f32", None), "f32", 10), W)


def test_server_messages_round_trip_through_msgpack():
    e = P.Error(code="malformed", message="bad", ref=None, seq=None)
    assert P.decode_server(P.to_wire(e)) == e


def test_the_protocol_doc_shows_every_message_as_defined():
    doc = DOC.read_text()
    for table in (P.CLIENT_MESSAGES, P.SERVER_MESSAGES):
        for kind, message in table.items():
            assert f"### `{kind}`" in doc, f"docs/protocol.md lacks a section for {kind}"
            assert D.markdown_section(message) in doc, \
                f"docs/protocol.md's section for {kind} differs from server/protocol.py (python -m server.protocol_docs --markdown)"
    documented = set(re.findall(r"^### `([a-z_]+)`", doc, flags=re.M))
    assert documented == set(P.CLIENT_MESSAGES) | set(P.SERVER_MESSAGES)
    assert D.markdown_errors() in doc, "docs/protocol.md's error codes or their order differ from server/protocol.py"
    assert D.markdown_close_codes() in doc, "docs/protocol.md's close codes differ from server/protocol.py"


@pytest.mark.parametrize("raw", [
    {"type": "pull", "id": 1, "time": 86400.5},
    {"type": "pull", "id": 1, "phase": 1.01},
    {"type": "pull", "id": 1, "time": 1.0, "phase": 0.5},      # exactly one of time, phase
    {"type": "pull", "id": 1, "params": {"speed": 1.0}},
    {"type": "hello", "space": "s", "window": 65},
    {"type": "hello", "space": "s", "window": -1},
    {"type": "hello", "space": "s", "smoothing": 10.5},
    {"type": "hello", "space": "s", "rate": -1},
    {"type": "hello", "space": "s", "codec": "png"},
    {"type": "mode", "mode": "cubic"},
    {"type": "seek", "phase": -0.1},
    {"type": "ack", "frame": -1},
])
def test_ranges_choices_and_groups_in_the_definitions_are_enforced(raw):
    with pytest.raises(P.ProtocolError) as info:
        decode_client(msgpack.packb(raw))
    assert info.value.code == "invalid_field" and info.value.ref == raw["type"]
    if raw["type"] == "pull":
        assert info.value.seq == 1   # a pull's errors carry its id


def test_a_range_bound_naming_a_limit_is_read_from_the_limits():
    hello = msgpack.packb({"type": "hello", "space": "s", "rate": 100})
    assert decode_client(hello).rate == 100.0
    assert decode_client(hello, limits={"max_fps": 120}).rate == 100.0
    with pytest.raises(P.ProtocolError, match=r"max_fps\] = 30, got 100"):
        decode_client(hello, limits={"max_fps": 30})


@pytest.mark.parametrize("value", [b"speed", msgpack.ExtType(5, b"x"), msgpack.Timestamp(1, 0)])
def test_bin_and_ext_values_in_fields_are_invalid_fields_not_malformed(value):
    with pytest.raises(P.ProtocolError, match="hello.space: expected string, got msgpack") as info:
        decode_client(msgpack.packb({"type": "hello", "space": value}))
    assert info.value.code == "invalid_field"
    with pytest.raises(P.ProtocolError) as info:
        decode_client(msgpack.packb({"type": b"hello", "space": "x"}))
    assert info.value.code == "malformed"


def test_the_smoothing_milestones_in_the_doc_are_the_players_spring():
    from engine.player import _critically_damped

    tau = 0.25
    for fraction, factor in zip((0.5, 0.9, 0.99), P.spring_times()):
        x, v = _critically_damped(np.zeros(1), np.zeros(1), np.ones(1), factor * tau, tau)
        assert x[0] == pytest.approx(fraction, abs=0.002)
    assert "50% / 90% / 99% of the way after 1.68 / 3.89 / 6.64 x smoothing" in D.markdown_table(P.Hello)


def test_serve_gives_the_websocket_layer_the_documented_size_limit():
    from server.commands.serve import uvicorn_options
    from server.settings import Settings

    for max_message in (1024, 64 * 1024, 1 << 20):
        options = uvicorn_options(Settings(stream_max_message=max_message), "warning")
        assert options["ws_max_size"] == P.websocket_max_size(max_message) == max(1 << 20, 4 * max_message)


@pytest.mark.parametrize("n_bytes", [0, 100, 6000, 70000])
def test_frame_parts_are_the_bytes_msgpack_packs_for_the_whole_map(n_bytes):
    from server.frames import frame_parts, joined

    small = {"type": "frame", "seq": 7, "ack": 3, "time": 1.5, "phase": 0.25, "mode": "hybrid",
             "requested": [1.0, 2.0], "realised": [1.0, 2.0], "clamped": False, "weights": [0.5, 0.5],
             "root": [0.0, 0.0, 1.0], "heading": 0.1, "dropped": 2, "finished": False, "sent_at": 1e9,
             "pull_id": None, "error_max": None}
    vertices = np.arange(n_bytes // 2, dtype="<u2")
    error = bytes(range(256)) * 3
    expected = msgpack.packb({**small, "vertices": vertices.tobytes(), "error_um": error})
    assert joined(frame_parts(small, [("vertices", vertices), ("error_um", error)])) == expected
    decoded = P.decode_server(joined(frame_parts(small, [("vertices", vertices)])))
    assert isinstance(decoded, P.Frame) and decoded.vertices == vertices.tobytes() and decoded.seq == 7


@pytest.mark.parametrize("seq, ack, dropped, finished", [(1, 0, 0, False), (127, 128, 255, True),
                                                         (65536, 2**32, 300, False), (2**40, 5, 2**31, True)])
def test_a_streamed_frame_is_the_bytes_frame_parts_gives(seq, ack, dropped, finished):
    from server.frames import StreamedFrame, frame_parts, joined

    rng = np.random.default_rng(seq % 1000)
    requested, realised, weights = rng.normal(size=2).tolist(), rng.normal(size=2).tolist(), rng.random(4).tolist()
    time_, phase, heading, sent_at = 1e3 * rng.random(), float(rng.random()), -2.5 * rng.random(), 1.7e9 + rng.random()
    root = [float(rng.normal()), -0.0, float(rng.normal())]
    vertices = rng.integers(0, 65535, size=9000).astype("<u2")
    small = {"type": "frame", "seq": seq, "ack": ack, "time": time_, "phase": phase, "mode": "linear",
             "requested": requested, "realised": realised, "clamped": not finished, "weights": weights, "root": root,
             "heading": heading, "dropped": dropped, "finished": finished, "sent_at": sent_at, "pull_id": None,
             "error_max": None, "error_seq": None, "node": None, "target": None, "progress": None, "error_um": None}
    middle = StreamedFrame.middle("linear", requested, realised, not finished, weights)
    fast = joined(StreamedFrame.parts(seq, ack, time_, phase, middle, root, heading, dropped, finished, sent_at,
                                      vertices))
    assert fast == joined(frame_parts(small, [("vertices", vertices)]))
    assert fast == msgpack.packb({**small, "vertices": vertices.tobytes()})  # key order and all
    # a motion graph's frame: its node, target and progress (none, or a blend's progress)
    for node, target, progress in (("walk", None, None), ("stand", "jump", 0.375), ("é" * 40, "reach", 1.0)):
        graph = StreamedFrame.graph(node, target, progress)
        fast = joined(StreamedFrame.parts(seq, ack, time_, phase, middle, root, heading, dropped, finished, sent_at,
                                          vertices, graph))
        with_graph = {**small, "node": node, "target": target, "progress": progress}
        assert fast == msgpack.packb({**with_graph, "vertices": vertices.tobytes()})


def test_middle_fields_are_msgpacks_bytes_for_any_floats():
    from server.frames import StreamedFrame

    rng = np.random.default_rng(5)
    special = [0.0, -0.0, float("nan"), float("inf"), -float("inf"), 5e-324, 1e308]
    for n_weights in (1, 4, 15, 16, 40):
        values = rng.normal(size=2 + 2 + n_weights).tolist()
        values[rng.integers(len(values))] = special[n_weights % len(special)]
        requested, realised, weights = values[:2], values[2:4], values[4:]
        for mode, clamped in (("hybrid", False), ("nonlinear", True)):
            expected = msgpack.packb({"mode": mode, "requested": requested, "realised": realised, "clamped": clamped,
                                      "weights": weights})[1:]
            assert StreamedFrame.middle(mode, requested, realised, clamped, weights) == expected


def test_row_views_are_the_bytes_of_each_row():
    from engine.blend.many import aligned_rows
    from server.frames import StreamedFrame, row_views

    padded = aligned_rows(5, 9001)  # rows padded to 64-byte boundaries
    padded[...] = np.random.default_rng(1).random(padded.shape)
    for rows in (np.arange(24 * 9000, dtype="<u2").reshape(24, 9000), padded, np.ones((1, 3), "<u2"),
                 np.empty((0, 3), np.float32)):
        views = row_views(rows)
        assert [bytes(view) for view in views] == [row.tobytes() for row in rows]
    # a frame written from a row's view is the frame written from the row
    middle = StreamedFrame.middle("linear", [1.0], [1.0], False, [0.5, 0.5])
    assert [bytes(p) for p in StreamedFrame.parts(3, 0, 0.5, 0.25, middle, [0.0, 0.0, 1.0], 0.0, 0, False, 1.0,
                                                  row_views(padded)[2])] == \
        [bytes(p) for p in StreamedFrame.parts(3, 0, 0.5, 0.25, middle, [0.0, 0.0, 1.0], 0.0, 0, False, 1.0, padded[2])]


@pytest.mark.parametrize("length", [0, 125, 126, 65535, 65536, 200000])
def test_the_websocket_header_is_rfc_6455s(length):
    from websockets.frames import Frame, Opcode

    from server.transport import websocket_header

    payload = b"x" * length
    assert websocket_header(length) + payload == Frame(Opcode.BINARY, payload).serialize(mask=False)


def test_streamed_heads_are_the_heads_streamed_frame_parts_gives():
    """A tick's heads made in one compiled pass from the players' clocks: the bytes of
    StreamedFrame.parts' first part for each frame (ints of every msgpack size, signed zeros and
    NaN, finished or not, vertices of every bin header's size), middles packed or made from their
    numbers there (any lengths, special floats)."""
    from engine.player import CLOCK_SIZE
    from server.frames import StreamedFrame, streamed_heads

    rng = np.random.default_rng(9)
    special = [0.0, -0.0, float("nan"), float("inf"), -float("inf"), 5e-324, 1e308]
    clocks, fields, middles, values, expected = [], [], [], [], []
    for k in range(160):
        clock = np.zeros(CLOCK_SIZE)
        clock[:6] = rng.uniform(-1e4, 1e4, 6)
        clock[6] = k % 2
        if k % 7 == 0:
            clock[3], clock[1] = -0.0, float("nan")
        clocks.append(clock)
        seq = int(rng.choice([0, 5, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32, 2**40]))
        ack, dropped = int(rng.integers(300)), int(rng.choice([0, 130, 70000]))
        size = int(rng.choice([0, 100, 255, 256, 18000, 65535, 65536, 100000]))
        mode, clamped = ["linear", "hybrid", "nonlinear"][k % 3], bool(k % 5)
        requested, realised, weights = (rng.normal(size=1 + k % 2).tolist(), rng.normal(size=2).tolist(),
                                        rng.random(1 + k % 20).tolist())
        weights[0] = special[k % len(special)]
        middle = StreamedFrame.middle(mode, requested, realised, clamped, weights)
        if k % 2:  # packed
            fields += (seq, ack, dropped, size, len(middle), 0, 0, 0, 0, 0)
            middles.append(middle)
        else:      # from its numbers
            head, between, tail = StreamedFrame.middle_pieces(mode, len(requested), len(realised), clamped,
                                                              len(weights))
            fields += (seq, ack, dropped, size, len(head), len(requested), len(between), len(realised), len(tail),
                       len(weights))
            middles += (head, between, tail)
            values += requested + realised + weights
        time_, phase, heading, x, y, z, finished = clock[:7].tolist()
        expected.append(StreamedFrame.parts(seq, ack, time_, phase, middle, [x, y, z], heading, dropped,
                                            bool(finished), 1.7e9 + 0.123, np.zeros(size, np.uint8))[0])
    heads = streamed_heads(fields, [clock.ctypes.data for clock in clocks], middles, values, 1.7e9 + 0.123)
    assert [bytes(head) for head in heads] == expected
    assert streamed_heads([], [], [], [], 0.0) == []
