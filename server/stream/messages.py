"""What each client message does to its connection: ``HANDLERS``, message type -> handler.

A handler is ``async def on_x(session, message)``: ``session`` is the connection's StreamSession
(server/stream/session.py), ``message`` the decoded message (a server/protocol.py dataclass). It
raises ``protocol.ProtocolError`` (or ValueError, answered ``invalid_field``) for a request it
refuses; the session answers with an error message and keeps the connection. A handler that
changes what the client sees ends with ``session.poke(message.seq)``: the next frame goes out at
once and acknowledges the message.

Adding a message kind: its dataclass in server/protocol.py, a handler here (or in a module of its
own), and one entry in ``HANDLERS``; messages not in ``BEFORE_HELLO`` are refused with
``not_ready`` until a hello has been applied.
"""

from __future__ import annotations

import asyncio

import numpy as np

from engine.player import Player
from server import graph_stream
from server import protocol as P
from server.registry import BrokenSpace, UnknownSpace


async def on_hello(session, m):
    if m.graph is not None:  # a motion graph: server/graph_stream.py
        return await graph_stream.on_hello(session, m)
    if m.node is not None:
        raise P.ProtocolError("invalid_field", f"hello.node names a graph's node; this hello streams the space "
                                               f"{m.space}, not a graph", "hello", m.seq)
    try:
        space = await asyncio.to_thread(session.registry.get, m.space)
    except UnknownSpace as exc:
        raise P.ProtocolError("unknown_space", str(exc), "hello", m.seq) from None
    except BrokenSpace as exc:
        raise P.ProtocolError("unknown_space", str(exc), "hello", m.seq) from None
    if space.parameter_map is None:
        raise P.ProtocolError("not_playable", f"{m.space} has no parameter map; rebuild it from a spec "
                                              "with a [parameters] section", "hello", m.seq)
    await asyncio.to_thread(space.blender, m.mode)
    if m.heatmap:
        await asyncio.to_thread(space.blender, "nonlinear")
    player = Player(space, mode=m.mode, smoothing=m.smoothing)
    if m.params:
        unknown = sorted(set(m.params) - set(player.names))
        if unknown:
            raise P.ProtocolError("invalid_params", f"hello: unknown parameter(s) {', '.join(unknown)}; "
                                                    f"{m.space} has {', '.join(player.names)}", "hello", m.seq)
        solution = player.set_params(m.params, immediate=True)
    else:
        solution = None
    session.ready = False  # no frames until the new topology has gone out
    session.player, session.space_name, session.rate = player, m.space, m.rate
    session.graph = None
    session.codec, session.window, session.heatmap = m.codec, m.window, m.heatmap
    description = session.registry.describe(m.space)
    session.bounds = np.asarray(description["bounds"], dtype=np.float32)
    session.paused, session.last_step = False, None
    session.quantiser = P.Quantiser(session.bounds, space.n_vertices) if m.codec == "q16" else None
    current = dict(zip(player.names, player.asked.tolist()))  # the request as asked (docs/protocol.md)
    parameters = [{key: dict(p, value=current[p["name"]])[key] for key in P.PARAMETER_KEYS}
                  for p in description["parameters"]]
    await session.send(P.Topology(
        protocol=P.PROTOCOL_VERSION, space=m.space, n_vertices=int(space.n_vertices),
        n_faces=int(len(space.faces)), faces=np.ascontiguousarray(space.faces, dtype="<u4").tobytes(),
        codec=m.codec, bounds_min=session.bounds[0].tolist(), bounds_max=session.bounds[1].tolist(),
        quantisation_error=P.quantisation_error(session.bounds) if m.codec == "q16" else 0.0,
        parameters=parameters, sources=space.source_names, durations=space.durations().tolist(),
        cyclic=bool(space.cyclic), mode=m.mode, modes=list(P.MODES), rate=session.rate,
        model_size=float(space.model_size),
        limits=dict(session.limits)))
    if solution is not None and solution.clamped:  # before the first frame, as a params message's
        await session.send(P.Notice(code="clamped", message=solution.message, seq=m.seq))
    session.seq = session.acked_frame = session.ack = session.dropped = 0  # afresh: acks count from this hello's seq
    session.waiting_ack = False
    session.stalled_since = None
    session.next_due = asyncio.get_running_loop().time()
    session.ready = True
    session.poke(m.seq)


async def on_ack(session, m):
    session.acked_frame = max(session.acked_frame, min(m.frame, session.seq))
    if session.waiting_ack and session.seq - session.acked_frame < session.window:
        session.waiting_ack = False
        session.after_frame()


async def on_params(session, m):
    names = session.player.names
    unknown = sorted(set(m.params) - set(names))
    if unknown:
        raise P.ProtocolError("invalid_params", f"{m.type}: unknown parameter(s) {', '.join(unknown)}; "
                                                f"{session.space_name} has {', '.join(names)}", m.type, m.seq)
    solution = session.player.set_params(m.params, immediate=m.immediate)
    if solution.clamped:  # sent before the frame that acknowledges the message
        await session.send(P.Notice(code="clamped", message=solution.message, seq=m.seq))
    session.poke(m.seq)


async def on_mode(session, m):
    await session.prepare_mode(m.mode)
    session.player.set_mode(m.mode)
    session.poke(m.seq)


async def on_rate(session, m):
    session.rate = m.rate
    session.next_due = asyncio.get_running_loop().time()
    session.last_step = None
    session.poke(m.seq)


async def on_pause(session, m):
    session.paused = True
    session.poke(m.seq)


async def on_resume(session, m):
    session.paused = False
    session.last_step = session.stalled_since = None
    session.next_due = asyncio.get_running_loop().time()  # the pause dropped no ticks: the grid from now
    session.poke(m.seq)


async def on_seek(session, m):
    session.player.seek(m.phase)
    session.last_step = None  # the next frame shows exactly this phase; the clock runs on from it
    session.poke(m.seq)


async def on_reset(session, m):
    session.player.reset()
    session.last_step = None
    session.poke(m.seq)


async def on_heatmap(session, m):
    if m.on:
        await session.prepare_mode("nonlinear")  # pulls blend it on the loop
        session.heatmap_last = None
    session.heatmap = m.on
    session.poke(m.seq)


async def on_pull(session, m):
    mode = m.mode or session.player.mode
    await session.prepare_mode(mode)
    player = session.player
    names = player.names
    unknown = sorted(set(m.params or {}) - set(names))
    if unknown:
        raise P.ProtocolError("invalid_params", f"pull: unknown parameter(s) {', '.join(unknown)}; "
                                                f"{session.space_name} has {', '.join(names)}", "pull", m.id)
    request = player.asked  # what was asked for, not where the clamp put it (as params do)
    for name, value in (m.params or {}).items():
        request[names.index(name)] = value
    solution = player.map.solve(request)
    w = solution.weights
    space = player.space
    if m.time is not None:
        root, heading, phase = player.track.after(w, m.time)
        seconds = m.time
    else:
        phase = m.phase % 1.0 if space.cyclic and m.phase < 1.0 else m.phase
        root, heading, _ = player.track.after(w, phase * player.track.duration(w))
        seconds = phase * player.track.duration(w)
    vertices = space.blender(mode).blend(w, phase)
    await session.send_pulled(time_=seconds, phase=phase, mode=mode, requested=request, realised=solution.realised,
                              clamped=solution.clamped, weights=w, root=root, heading=heading,
                              vertices=vertices, pull_id=m.id, space=space)


# message type -> handler: every client message of server/protocol.py (a test checks)
HANDLERS = {
    P.Hello.type: on_hello,
    P.Ack.type: on_ack,
    P.Params.type: on_params,
    P.Mode.type: on_mode,
    P.Rate.type: on_rate,
    P.Pause.type: on_pause,
    P.Resume.type: on_resume,
    P.Seek.type: on_seek,
    P.Reset.type: on_reset,
    P.Heatmap.type: on_heatmap,
    P.Pull.type: on_pull,
    P.Action.type: graph_stream.on_action,  # answered unsupported on a space stream
}
BEFORE_HELLO = frozenset({P.Hello.type, P.Ack.type})  # the others answer not_ready until a hello
