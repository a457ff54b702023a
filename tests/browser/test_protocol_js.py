"""web_client/static/protocol.js is generated from server/protocol.py and the page builds its
messages from it: the committed file must match, and every message the JavaScript sends must be
one the server defines."""

from __future__ import annotations

import re
from pathlib import Path

from server import protocol as P
from server import protocol_docs as D

STATIC = Path(__file__).resolve().parents[2] / "web_client" / "static"


def test_committed_protocol_js_matches_the_server_definitions():
    committed = (STATIC / "protocol.js").read_text()
    assert committed == D.javascript(), (
        "web_client/static/protocol.js is stale: run "
        "`.venv/bin/python -m server.protocol_docs --js > web_client/static/protocol.js`")


def test_the_page_sends_only_messages_the_server_defines():
    sources = {path.name: path.read_text() for path in (STATIC / "js").glob("*.js")}
    sent = set()
    for text in sources.values():
        sent |= set(re.findall(r"""(?:connection\.send|this\.send|clientMessage)\(\s*["'](\w+)["']""", text))
        # sends with a computed type, e.g. send(paused ? "pause" : "resume")
        for expression in re.findall(r"""connection\.send\(([^,)]*\?[^,)]*)""", text):
            sent |= set(re.findall(r"""["'](\w+)["']""", expression))
    assert {"hello", "params", "mode", "heatmap", "ack", "reset", "pause", "resume", "rate"} <= sent
    unknown = sent - set(P.CLIENT_MESSAGES)
    assert not unknown, f"the page sends message types the server does not define: {unknown}"


def test_messages_are_built_from_the_generated_table():
    text = (STATIC / "js" / "messages.js").read_text()
    assert 'from "../protocol.js"' in text and "CLIENT_MESSAGES[type]" in text
