"""Decoding client messages: ``decode_client(data, max_bytes, limits)``, strict and driven by the
definitions in server/protocol.py (each field's kind, range, choices and ``one_of`` group), in
the order ``protocol.CHECK_ORDER`` documents. It raises nothing but ProtocolError.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys

import msgpack

from server.protocol import CLIENT_MESSAGES, INT_LIMIT, KINDS, ProtocolError


def _check(kind, name, value, ref, seq):
    def bad(what):
        raise ProtocolError("invalid_field", f"{ref}.{name}: {what}", ref=ref, seq=seq)
    if isinstance(value, (bytes, msgpack.ExtType, msgpack.Timestamp)):
        bad(f"expected {KINDS[kind]}, got msgpack {'bin' if isinstance(value, bytes) else 'ext'}")
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
        if not -INT_LIMIT <= value <= INT_LIMIT:
            bad(f"integer out of range (-2^53 to 2^53), got {value}")
        return value
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            bad(f"expected a number, got {type(value).__name__}")
        if isinstance(value, int):  # any integer is a number; one past a double's range is out of every range
            try:
                value = float(value)
            except OverflowError:
                bad(f"an integer of {len(str(abs(value)))} digits is out of range")
        if not math.isfinite(value):
            bad(f"must be finite, got {value}")
        return value
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
            if isinstance(number, int):  # any integer is a number and clamps; past a double's range, as its end
                try:
                    number = float(number)
                except OverflowError:
                    number = sys.float_info.max if number > 0 else -sys.float_info.max
            if not math.isfinite(number):
                raise ProtocolError("invalid_params", f"{ref}.{name}: {key} must be finite, got {number}",
                                    ref=ref, seq=seq)
            out[key] = float(number)
        return out
    raise AssertionError(f"no client decoding for kind {kind}")


def _in_range(f, name, value, ref, seq, limits):
    low, high = f.metadata["low"], f.metadata["high"]
    if isinstance(high, str):
        high = (limits or {}).get(high)
    if (low is not None and value < low) or (high is not None and value > high):
        bound = f.metadata["high"] if isinstance(f.metadata["high"], str) else high
        if bound is None:
            raise ProtocolError("invalid_field", f"{ref}.{name} must be at least {_number(low)}, got {_number(value)}",
                                ref=ref, seq=seq)
        raise ProtocolError("invalid_field", f"{ref}.{name} must be in [{_number(low)}, {_number(bound)}]"
                            f"{f' = {_number(high)}' if isinstance(f.metadata['high'], str) and high is not None else ''}"
                            f", got {_number(value)}", ref=ref, seq=seq)


def _number(x):
    """A bound or a value as an error message shows it: up to 15 significant digits (86400.01, not
    86400; 120, not 120.0)."""
    return x if isinstance(x, str) or x is None else f"{x:.15g}"


def decode_client(data, max_bytes=None, limits=None):
    """A client message object from raw WebSocket data (bytes, or text holding JSON).

    Raises ProtocolError naming the problem, in ``CHECK_ORDER``: the size (``max_bytes``),
    malformed data, an unknown ``type``, missing, unknown or invalid fields (kinds, ranges: a
    range bound naming a limit is read from ``limits``, a {name: number} map), a ``one_of``
    group without exactly one member.
    """
    if max_bytes is not None and 4 * len(data) > max_bytes:  # (a character is 1 to 4 bytes of UTF-8)
        size = len(data) if isinstance(data, (bytes, bytearray, memoryview)) else len(data.encode("utf-8", "surrogatepass"))
        if size > max_bytes:
            raise ProtocolError("too_large", f"message of {size} bytes exceeds the limit of {max_bytes}")
    try:
        if isinstance(data, str):
            raw = json.loads(data)
        else:
            raw = msgpack.unpackb(data, raw=False, strict_map_key=False)  # keys are checked per field
    except (ValueError, msgpack.UnpackException, msgpack.ExtraData, TypeError, RecursionError) as exc:
        reason = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__  # msgpack's FormatError has none
        raise ProtocolError("malformed", f"not a msgpack (or JSON text) message ({reason})") from None
    if not isinstance(raw, dict) or not isinstance(raw.get("type"), str):
        raise ProtocolError("malformed", "a message must be a map with a string 'type' field")
    kind = raw["type"]
    number = raw.get("id" if kind == "pull" else "seq")  # a pull's errors carry its id
    seq = number if isinstance(number, int) and not isinstance(number, bool) and abs(number) <= INT_LIMIT else None  # (echoed only in range)
    cls = CLIENT_MESSAGES.get(kind)
    if cls is None:
        raise ProtocolError("unknown_type", f"unknown message type {kind[:64]!r}; expected one of "
                            f"{', '.join(CLIENT_MESSAGES)}", ref=kind[:64], seq=seq)
    known = {f.name: f for f in dataclasses.fields(cls)}
    extra = sorted(set(raw) - set(known) - {"type"}, key=str)
    if extra:
        raise ProtocolError("invalid_field", f"{kind}: unknown field(s) {', '.join(map(str, extra))[:200]}",
                            ref=kind, seq=seq)
    values = {}
    groups = {}
    for name, f in known.items():
        if f.metadata["one_of"]:
            groups.setdefault(f.metadata["one_of"], []).append(name)
        if name not in raw or raw[name] is None:
            if not f.metadata["optional"]:
                raise ProtocolError("invalid_field", f"{kind}.{name} is required", ref=kind, seq=seq)
            continue
        values[name] = value = _check(f.metadata["kind"], name, raw[name], kind, seq)
        if f.metadata["low"] is not None or f.metadata["high"] is not None:
            _in_range(f, name, value, kind, seq, limits)
        if f.metadata["choices"] and value not in f.metadata["choices"]:
            raise ProtocolError("invalid_field", f"{kind}.{name}: unknown {name} {value[:64]!r}; choose one of "
                                f"{', '.join(f.metadata['choices'])}", ref=kind, seq=seq)
    for members in groups.values():
        if sum(name in values for name in members) != 1:
            raise ProtocolError("invalid_field", f"{kind}: give exactly one of {' or '.join(members)}",
                                ref=kind, seq=seq)
    return cls(**values)
