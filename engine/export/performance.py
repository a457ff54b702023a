"""A recorded motion-graph performance as exportable frames: the graph player's frames, replayed.

``frames = play_performance(graph, recording)`` replays a graph recording (docs/file-formats.md,
"Graph recordings"; ``morphspace play GRAPH --record`` or the browser's Record button writes one)
with a ``GraphPlayer`` as ``engine.graph.recording.perform`` does, and keeps every frame as the
clip exporters take it (``ClipFrames``): the root-local mesh, the root position and heading in the
world (moving and turning across transitions), one mesh topology (every node's space shares it).
The vertices hashed frame after frame give the recording's ``frames_sha256`` when the replay made
the very frames recorded (``digest``).

A recording may carry ``times``: the time of every frame, ``steps + 1`` non-decreasing seconds
starting at 0 (a stream's frames, stepped by its clock rather than by exactly 1 / fps). The
player then steps by their differences instead of 1 / fps. A frame at the same time as the one
before (a step of 0 s: a stream's extra frame answering a message) replaces that one in the
export, whose animation times must increase.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

from engine.export.clip import MAX_FRAMES, ClipError, ClipFrames
from engine.graph.build import GraphError
from engine.graph.player import GraphPlayer
from engine.graph.recording import read_recording


def check_performance(graph, document):
    """The recording ``document`` (a parsed JSON dict) checked against ``graph``: every request's
    node and parameter names known, frames within the performance, times if given well formed.

    Returns the clock: (dt per step as a list of floats, number of frames).
    Raises ClipError naming the problem.
    """
    try:
        read_recording(document, graph)
    except GraphError as exc:
        raise ClipError(str(exc)) from None
    steps = document["steps"]
    if steps + 1 > MAX_FRAMES:
        raise ClipError(f"recording: {steps + 1} frames; at most {MAX_FRAMES} per export")
    known = {node.name: node for node in graph.nodes}
    _check_params(known[document["start"]], document.get("params") or {}, "params")
    for i, request in enumerate(document["requests"]):
        where = f"requests[{i}]"
        if request["node"] not in known:
            raise ClipError(f"{where}: unknown node {request['node']!r}; graph {graph.name!r} has "
                            f"{', '.join(known)}")
        if not 0 <= request["frame"] <= steps:
            raise ClipError(f"{where}: frame {request['frame']} is outside the performance (0 to {steps})")
        budget = request.get("budget")
        if budget is not None and (isinstance(budget, bool) or not isinstance(budget, (int, float))
                                   or not (math.isfinite(budget) and budget > 0)):
            raise ClipError(f"{where}: budget must be a positive number of seconds or null, got {budget!r}")
        _check_params(known[request["node"]], request.get("params") or {}, where)
    return step_times(document)


def step_times(document):
    """The clock of a recording: (seconds of every step, number of frames). 1 / ``fps`` each, or
    the differences of its ``times`` (a browser recording). Raises ClipError naming a bad ``times``."""
    steps, fps = document["steps"], float(document["fps"])
    times = document.get("times")
    if times is None:
        return [1.0 / fps] * steps, steps + 1
    if not (isinstance(times, list) and len(times) == steps + 1):
        raise ClipError(f"recording: times must be a list of steps + 1 = {steps + 1} numbers, got "
                        f"{len(times) if isinstance(times, list) else type(times).__name__}")
    if not all(isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t) for t in times):
        raise ClipError("recording: times must be finite numbers of seconds")
    if times[0] != 0:
        raise ClipError(f"recording: times must start at 0, got {times[0]}")
    dts = [float(b) - float(a) for a, b in zip(times, times[1:])]
    if any(dt < 0 for dt in dts):
        k = next(k for k, dt in enumerate(dts) if dt < 0)
        raise ClipError(f"recording: times must not decrease (frame {k + 1}: {times[k + 1]} after {times[k]})")
    return dts, steps + 1


def _check_params(node, params, where):
    if not isinstance(params, dict):
        raise ClipError(f"{where}: params must be an object {{name: value}}")
    for name, value in params.items():
        if name not in node.parameters:
            has = f"it has {', '.join(node.parameters)}" if node.parameters else "it has no parameters"
            raise ClipError(f"{where}: node {node.name!r} has no parameter {name!r}; {has}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ClipError(f"{where}: {node.name}.{name} must be a finite number, got {value!r}")


def play_performance(graph, document, progress=None):
    """Replay the recording ``document`` on ``graph``; returns (ClipFrames, digest).

    ClipFrames: ``space`` is the graph's name, ``nodes`` the node each frame shows, ``names`` every
    node's parameters as ``node.name`` and ``params`` their realised values (NaN where the frame
    shows another node); ``notes`` what the requests answered when clamped. ``digest``: SHA-256
    of every frame's float32 world vertices (before dropping frames at a repeated time), as
    ``engine.graph.recording.perform`` makes it. ``progress(done, total)`` as frames are made.
    """
    dts, n = check_performance(graph, document)
    fps = float(document["fps"])
    player = GraphPlayer(graph, node=document["start"], params=document.get("params") or {},
                         mode=document["mode"], record=False)
    pending = sorted(document["requests"], key=lambda r: r["frame"])
    names = [f"{node.name}.{p}" for node in graph.nodes for p in node.parameters]
    column = {name: i for i, name in enumerate(names)}
    local = np.empty((n, graph.nodes[0].space.n_vertices, 3), dtype=np.float32)
    times, heading = np.empty(n), np.empty(n)
    root, params = np.empty((n, 3)), np.full((n, len(names)), np.nan)
    nodes, notes, digest = [], [], hashlib.sha256()
    if player.start_clamped:  # the start's parameters out of reach: said, as any request's are
        notes.append(f"frame 0: {player.start_clamped}")
    for k in range(n):
        while pending and pending[0]["frame"] <= player.frames:
            r = pending.pop(0)
            try:
                if r.get("set"):
                    answer = player.set_params(r.get("params") or {})
                else:
                    answer = player.request(r["node"], r.get("params") or {}, budget=r.get("budget"))
            except GraphError as exc:
                raise ClipError(f"request at frame {r['frame']} ({r['node']}): {exc}") from None
            if answer.get("clamped"):
                notes.append(f"frame {player.frames}: {answer['message']}")
        frame = player.step(dts[k - 1]) if k else player.frame()
        digest.update(np.ascontiguousarray(frame.vertices, dtype="<f4").tobytes())
        local[k] = player.frame(placed=False).vertices
        times[k], heading[k], root[k] = player.time, frame.heading, frame.root_position
        nodes.append(frame.node)
        for name, value in frame.params.items():
            params[k, column[f"{frame.node}.{name}"]] = value
        if progress is not None and (k % 16 == 15 or k == n - 1):
            progress(k + 1, n)
    keep = np.append(np.diff(times) > 0, True)  # of frames at one time, the last
    frames = ClipFrames(times=times[keep], local=local[keep], root_position=root[keep], heading=heading[keep],
                        faces=np.asarray(graph.nodes[0].space.faces, dtype=np.int64), params=params[keep],
                        names=names, rate=fps, space=graph.name, notes=notes,
                        nodes=[node for node, kept in zip(nodes, keep) if kept])
    return frames, digest.hexdigest()


def scripted_recording(graph, *, start=None, params=None, requests=(), fps=60.0, seconds=None, mode="hybrid"):
    """A recording document of a scripted performance (``--at T NODE name=value`` requests as
    dicts with ``time`` (s), ``node``, ``params``, ``budget``), as ``morphspace play`` makes it;
    ``seconds`` default: 4 s after the last request. Its ``frames_sha256`` is null (not played)."""
    if not (math.isfinite(fps) and fps > 0):
        raise ClipError(f"fps must be a positive number, got {fps}")
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise ClipError(f"seconds must be a positive number, got {seconds}")
    try:
        start = graph.node(start).name if start else next(n.name for n in graph.nodes if n.cyclic)
    except GraphError as exc:
        raise ClipError(str(exc)) from None
    entries = []
    for r in requests:
        if not (math.isfinite(r["time"]) and r["time"] >= 0):
            raise ClipError(f"request time must be a non-negative number of seconds, got {r['time']}")
        entries.append({"frame": int(round(r["time"] * fps)), "node": r["node"], "params": dict(r.get("params") or {}),
                        "budget": r.get("budget")})
    last = max((r["time"] for r in requests), default=0.0)
    steps = int(round((seconds if seconds is not None else last + 4.0) * fps))
    return {"format": "morphspace-graph-recording", "version": 1, "graph": graph.name,
            "graph_checksum": graph.checksum, "start": start, "params": dict(params or {}), "fps": float(fps),
            "steps": steps, "mode": mode, "requests": entries, "frames_sha256": None}
