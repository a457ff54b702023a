"""Scripted and recorded graph performances, replayed to the same frames byte for byte.

A performance is a start (node, parameters), a clock (frames per second, number of steps, blend
mode) and requests stamped with the frame they were made at. ``perform`` plays it with a
``GraphPlayer`` and hashes every frame's float32 vertices (SHA-256), so a replay can show it made
the identical frames. ``recording`` turns a played performance into a JSON-ready dict
(docs/file-formats.md, "Graph recordings"); ``read_recording`` checks one against the graph.
"""

from __future__ import annotations

import hashlib

import numpy as np

from engine.graph.build import GraphError
from engine.graph.player import MODES, GraphPlayer

RECORDING_FORMAT = "morphspace-graph-recording"
RECORDING_VERSION = 1


def perform(graph, *, start, params, fps, steps, mode="hybrid", requests=(), on_frame=None, player=None, dts=None):
    """Play ``steps`` frames after the first at ``fps``; ``requests`` (dicts with ``frame``,
    ``node``, ``params``, ``budget``) are made once the player has taken ``frame`` steps (frame
    n is n / fps seconds in), as ``GraphPlayer.requests`` records them (one with ``set`` true is
    a ``GraphPlayer.set_params``). ``dts``: the seconds of every step instead of 1 / ``fps`` (a
    browser recording's ``times``, differenced).

    Returns
    -------
    player : GraphPlayer        (its ``requests`` is what was asked, with the frames)
    digest : str                SHA-256 of every frame's float32 vertex bytes, in order
    answers : list of dict      what each request answered (``GraphPlayer.request``)
    """
    if not (np.isfinite(fps) and fps > 0) or steps < 0:
        raise GraphError(f"fps must be positive and steps non-negative, got {fps}, {steps}")
    player = player or GraphPlayer(graph, node=start, params=params, mode=mode)
    pending = sorted(requests, key=lambda r: r["frame"])
    if dts is not None and len(dts) != steps:
        raise GraphError(f"{len(dts)} step times for {steps} steps")
    digest, answers = hashlib.sha256(), []
    for k in range(steps + 1):
        while pending and pending[0]["frame"] <= player.frames:  # frame n: after n steps
            r = pending.pop(0)
            if r.get("set"):  # GraphPlayer.set_params: the shown node's parameters, no transition
                answers.append({"frame": player.frames, **player.set_params(r.get("params") or {})})
            else:
                answers.append({"frame": player.frames, "node": r["node"],
                                **player.request(r["node"], r.get("params") or {}, budget=r.get("budget"))})
        frame = (player.step(1.0 / fps if dts is None else dts[k - 1]) if k else player.frame())
        digest.update(np.ascontiguousarray(frame.vertices, dtype="<f4").tobytes())
        if on_frame is not None:
            on_frame(k, frame)
    return player, digest.hexdigest(), answers


def recording(graph, player, *, start, params, fps, steps, mode, digest):
    """A JSON-ready record of a performance played by ``perform``."""
    return {"format": RECORDING_FORMAT, "version": RECORDING_VERSION, "graph": graph.name,
            "graph_checksum": graph.checksum, "start": start, "params": dict(params or {}), "fps": float(fps),
            "steps": int(steps), "mode": mode, "requests": list(player.requests), "frames_sha256": digest}


def read_recording(document, graph):
    """Check a recording (a parsed JSON dict) against ``graph``; returns it. GraphError says what is wrong."""
    if not isinstance(document, dict) or document.get("format") != RECORDING_FORMAT:
        raise GraphError(f"not a {RECORDING_FORMAT} (its format is "
                         f"{document.get('format') if isinstance(document, dict) else type(document).__name__!r})")
    if document.get("version") != RECORDING_VERSION:
        raise GraphError(f"recording version {document.get('version')}; this morphspace reads {RECORDING_VERSION}")
    if document.get("graph_checksum") != graph.checksum:
        raise GraphError(f"the recording was made with graph {document.get('graph')!r} "
                         f"({document.get('graph_checksum')}), not this one ({graph.name!r}, {graph.checksum})")
    if document.get("mode") not in MODES:
        raise GraphError(f"recording: unknown blend mode {document.get('mode')!r}")
    fps, steps = document.get("fps"), document.get("steps")
    if not isinstance(fps, (int, float)) or not isinstance(steps, int) or fps <= 0 or steps < 0:
        raise GraphError(f"recording: fps must be positive and steps a non-negative integer, got {fps}, {steps}")
    requests = document.get("requests")
    if not isinstance(requests, list) or not all(
            isinstance(r, dict) and isinstance(r.get("frame"), int) and isinstance(r.get("node"), str)
            and isinstance(r.get("params", {}), dict) for r in requests):
        raise GraphError("recording: requests must be a list of {frame, node, params, budget}")
    frames = [r["frame"] for r in requests]
    late = next((k for k in range(1, len(frames)) if frames[k] < frames[k - 1]), None)
    if late is not None:   # a replay does not reorder what it replays
        raise GraphError(f"recording: requests must be in frame order; request {late} (frame {frames[late]}) "
                         f"comes after one at frame {frames[late - 1]}")
    graph.node(document.get("start"))
    return document
