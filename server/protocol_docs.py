"""docs/protocol.md's tables and web_client/static/protocol.js, rendered from the message
definitions in server/protocol.py (tests compare them with the committed files).

    python -m server.protocol_docs --markdown   # the doc's tables: errors and their order, close codes, messages
    python -m server.protocol_docs --js         # web_client/static/protocol.js
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import sys

from server.protocol import (CHECK_ORDER, CLIENT_MESSAGES, CLOSE_CODES, CODECS, ERROR_CODES, KINDS, MODES,
                             PROTOCOL_VERSION, SERVER_MESSAGES, fields_of)


def _number(x):
    return x if isinstance(x, str) or x is None else f"{x:g}"


def _range_text(metadata):
    low, high = metadata.get("low"), metadata.get("high")
    if metadata.get("choices"):
        return ": " + ", ".join(f"'{c}'" for c in metadata["choices"])
    if low is None and high is None:
        return ""
    if high is None:
        return f", >= {_number(low)}"
    return f", {_number(low)} to {f'`limits.{high}`' if isinstance(high, str) else _number(high)}"


def markdown_table(message):
    """The field table of one message as docs/protocol.md shows it (a test compares them)."""
    fields = {f.name: f for f in dataclasses.fields(message)}
    groups = {}
    for f in fields.values():
        if f.metadata["one_of"]:
            groups.setdefault(f.metadata["one_of"], []).append(f"`{f.name}`")
    rows = ["| field | kind | required | meaning |", "|---|---|---|---|"]
    for name, kind, optional, doc in fields_of(message):
        f = fields.get(name)
        metadata = f.metadata if f is not None else {}
        default = f.default if f is not None else None
        if metadata.get("one_of"):
            required = "exactly one of " + ", ".join(groups[metadata["one_of"]])
        else:
            required = "yes" if not optional else ("no" if default is None else f"no (default `{json.dumps(default)}`)")
        rows.append(f"| `{name}` | {KINDS[kind]}{_range_text(metadata)} | {required} | {doc.replace('|', '/')} |")
    return "\n".join(rows)


def markdown_section(message):
    """A message's section of docs/protocol.md: heading, docstring and field table."""
    doc = inspect.cleandoc(message.__doc__).replace("``", "`")
    return f"### `{message.type}`\n\n{doc}\n\n{markdown_table(message)}"


def markdown_errors():
    """The error code table and the order of the checks, as docs/protocol.md shows them."""
    rows = ["| code | meaning |", "|---|---|"] + [f"| `{code}` | {text} |" for code, text in ERROR_CODES.items()]
    order = [f"{i}. {text}: `{code}`" for i, (code, text) in enumerate(CHECK_ORDER, 1)]
    return "\n".join(rows) + "\n\nA client message's checks run in this order; the first that fails answers:\n\n" + \
        "\n".join(order)


def markdown_close_codes():
    """The table of WebSocket close codes the server sends, as docs/protocol.md shows it."""
    return "\n".join(["| close code | when |", "|---|---|"] + [f"| {code} | {text} |" for code, text in CLOSE_CODES.items()])


# ---------------------------------------------------------------- JavaScript table

def javascript():
    """web_client/static/protocol.js: the message table the browser client builds its messages from."""
    def table(messages):
        return {t: [name for name, *_ in fields_of(cls)] for t, cls in messages.items()}
    lines = [
        "// Generated from server/protocol.py by `python -m server.protocol_docs --js`; do not edit.",
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
        print(f"{markdown_errors()}\n\n{markdown_close_codes()}\n")
        for table in (CLIENT_MESSAGES, SERVER_MESSAGES):
            for message in table.values():
                print(f"{markdown_section(message)}\n")
    else:
        print("usage: python -m server.protocol_docs --js | --markdown", file=sys.stderr)
        sys.exit(2)
