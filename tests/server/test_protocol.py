"""Wire messages: decoding is strict and never fails with anything but a ProtocolError; the
codecs' error bound is what the topology reports; docs/protocol.md shows the code's messages."""

import re
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server import protocol as P

DOC = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"


def test_a_full_hello_decodes_to_its_dataclass():
    m = P.decode_client(msgpack.packb({"type": "hello", "space": "walk", "codec": "q16", "rate": 30,
                                       "params": {"speed": 2}, "window": 2, "seq": 4}))
    assert m == P.Hello(space="walk", codec="q16", rate=30.0, params={"speed": 2.0}, window=2, seq=4)
    assert isinstance(m.rate, float) and isinstance(m.params["speed"], float)


def test_json_text_decodes_like_msgpack():
    assert P.decode_client('{"type": "seek", "phase": 0.5, "seq": 2}') == P.Seek(phase=0.5, seq=2)


@pytest.mark.parametrize("raw, code", [
    ({"type": "seek"}, "invalid_field"),
    ({"type": "seek", "phase": True}, "invalid_field"),
    ({"type": "seek", "phase": "0.5"}, "invalid_field"),
    ({"type": "seek", "phase": float("nan")}, "invalid_field"),
    ({"type": "hello", "space": "x" * 300}, "invalid_field"),
    ({"type": "params", "params": {"a": float("-inf")}}, "invalid_params"),
    ({"type": "params", "params": {1: 2.0}}, "malformed"),     # non-string map keys are refused by msgpack
    ({"type": "ack", "frame": 2 ** 60}, "invalid_field"),
    ({"type": "Hello", "space": "x"}, "unknown_type"),
])
def test_invalid_messages_name_the_problem(raw, code):
    with pytest.raises(P.ProtocolError) as info:
        P.decode_client(msgpack.packb(raw, strict_types=False))
    assert info.value.code == code
    assert info.value.message


def test_the_size_limit_comes_first():
    with pytest.raises(P.ProtocolError, match="exceeds the limit") as info:
        P.decode_client(b"\x80" * 2000, max_bytes=1000)
    assert info.value.code == "too_large"


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_never_raise_anything_but_protocol_errors(data):
    try:
        P.decode_client(data)
    except P.ProtocolError as exc:
        assert exc.code in P.ERROR_CODES


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.sampled_from(["type", "space", "phase", "params", "seq", "rate", "id", "frame", "x"]),
                       st.one_of(st.none(), st.booleans(), st.integers(-2**63, 2**64 - 1), st.floats(), st.text(max_size=5),
                                 st.sampled_from(list(P.CLIENT_MESSAGES)),
                                 st.dictionaries(st.text(max_size=3), st.floats(), max_size=3)),
                       max_size=5))
def test_random_maps_never_raise_anything_but_protocol_errors(raw):
    try:
        P.decode_client(msgpack.packb(raw))
    except P.ProtocolError as exc:
        assert exc.code in P.ERROR_CODES


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
    assert error <= P.quantisation_error(bounds) * (1 + 1e-3) + 1e-7


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
            assert P.markdown_table(message) in doc, \
                f"docs/protocol.md's table for {kind} differs from server/protocol.py (python -m server.protocol --markdown)"
    documented = set(re.findall(r"^### `([a-z_]+)`", doc, flags=re.M))
    assert documented == set(P.CLIENT_MESSAGES) | set(P.SERVER_MESSAGES)
    for code in P.ERROR_CODES:
        assert f"| `{code}` |" in doc
