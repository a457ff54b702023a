"""A motion graph on ``/v1/stream``: ``GraphStream``, what a connection streaming a graph plays.

A hello naming ``graph`` (docs/protocol.md) makes the connection play a GraphPlayer
(engine/graph/player.py) instead of a space's Player. ``GraphStream`` wraps it with the state a
frame reports (the shown node's phase, parameters, weights; the root transform; the node, the
transition's target and its progress) and the messages a graph answers: ``action`` (go to a
node), ``params`` (the shown node's parameters, at once), ``mode``, ``reset``. Each connection's
player makes its own frames as it advances (not the session's phase-table path: a graph's state
moves between spaces), on the event loop like every other frame; it reads the nodes' spaces'
phase tables at weights that recur (``GraphPlayer(tables=True)``), so a node played at steady
parameters costs one interpolation a frame. The blending set-up of every node's space (the
non-linear solvers) is done in a thread by ``prepare`` before a hello or a mode switch is answered.

Errors are ProtocolErrors with the codes of docs/protocol.md: ``unknown_graph``,
``unknown_node``, ``invalid_params``, ``unsupported`` (messages a graph does not take).
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np

from engine.graph import GraphError, GraphPlayer, TransitionSearch
from server import protocol as P
from server.graphs import BrokenGraph, UnknownGraph
from server.registry import quantisation_box

# the client messages a graph stream does not take, and why
UNSUPPORTED = {
    "seek": "a graph's phase is the player's: send action to change what it plays",
    "heatmap": "heatmaps are for spaces (the distance from one space's non-linear blend)",
    "pull": "pulls are for spaces (a frame of one space at given parameters and time)",
}


def _bad_params(node, params, ref, seq):
    """ProtocolError ``invalid_params`` for names ``node`` does not have (None if all known)."""
    unknown = sorted(set(params or {}) - set(node.parameters))
    if not unknown:
        return None
    has = f"it has {', '.join(node.parameters)}" if node.parameters else "it has no parameters"
    return P.ProtocolError("invalid_params", f"{ref}: node {node.name!r} has no parameter(s) "
                                             f"{', '.join(unknown)}; {has}", ref, seq)


async def prepare(graph, mode):
    """Build every node's blender for ``mode`` (the non-linear solver factorises once) and the
    transition search's tables of the nodes (``engine.graph.terms``, once per graph, with blenders
    of their own) in a thread; the blending itself stays on the event loop (the blenders' scratch
    buffers are shared)."""
    def build():
        for node in graph.nodes:
            node.space.blender(mode)
        TransitionSearch(graph)
    await asyncio.to_thread(build)


def space_name(node):
    """The file stem of a node's space (its name under GET /v1/spaces when beside the graph)."""
    return Path(node.meta["space"]).name.removesuffix(".mspace")


class GraphStream:
    """One connection's graph performance.

    Parameters
    ----------
    graph : MotionGraph (opened by server.graphs.GraphRegistry, shared by connections)
    name : str            the graph's name on the server (its file stem)
    node : str or None    start node (default: the first cyclic node)
    params : dict or None start parameters; mode : str blend mode

    Attributes read by the stream session (as from engine.player.Player): ``space`` (the shown
    node's), ``mode``, ``time``, ``phase``, ``position``, ``heading``, ``finished``, ``weights``,
    ``requested``, ``realised``, ``clamped``; and ``node``, ``target``, ``progress``.
    """

    def __init__(self, graph, name, *, node=None, params=None, mode="hybrid", seq=0):
        self.graph, self.name = graph, name
        start = self._node(node, "hello", seq) if node else None
        self.start = start.name if start else next((n.name for n in graph.nodes if n.cyclic), graph.nodes[0].name)
        bad = _bad_params(graph.node(self.start), params, "hello", seq)
        if bad is not None:
            raise bad
        self.start_params = dict(params or {})
        self.mode = mode
        self._solved = {}  # (node, params) -> (requested, realised, clamped)
        self._shown = None  # ((player, node, player.asked), its state): the last _state answer
        self.notify = None  # callable(Notice): sends a notice the stream makes as it advances
        self.reset()

    # ------------------------------------------------------------ set-up

    @classmethod
    async def open(cls, graphs, hello):
        """The GraphStream a Hello naming a graph asks for (the graph opened in a thread)."""
        try:
            graph = await asyncio.to_thread(graphs.get, hello.graph)
        except (UnknownGraph, BrokenGraph) as exc:
            raise P.ProtocolError("unknown_graph", str(exc), "hello", hello.seq) from None
        if hello.heatmap:
            raise P.ProtocolError("unsupported", "hello: heatmap is for spaces, not graphs", "hello", hello.seq)
        await prepare(graph, hello.mode)  # before the player's first blend, which runs here on the loop
        return cls(graph, hello.graph, node=hello.node, params=hello.params, mode=hello.mode, seq=hello.seq)

    async def prepare(self, mode):
        await prepare(self.graph, mode)

    def reset(self):
        """Back to the start node at its start parameters, at the origin facing +Z, time 0."""
        try:
            self.player = GraphPlayer(self.graph, node=self.start, params=self.start_params, mode=self.mode,
                                      record=False,  # a stream is not recorded: its requests are not kept
                                      tables=True)   # one interpolation a frame at weights that recur
        except GraphError as exc:  # a start parameter that is not a number the node can take
            raise P.ProtocolError("invalid_params", f"hello: {exc}", "hello") from None
        self._frame = self.player.frame(placed=False)
        self._queued_seq = self._planned_seq = None  # the actions waiting, and being carried out

    def _node(self, name, ref, seq):
        try:
            return self.graph.node(name)
        except GraphError as exc:
            raise P.ProtocolError("unknown_node", str(exc), ref, seq) from None

    def bounds(self):
        """(2, 3) float32 q16 box covering every node's space."""
        boxes = np.stack([quantisation_box(node.space) for node in self.graph.nodes])
        return np.stack([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)]).astype(np.float32)

    def topology(self, *, codec, rate, limits, bounds):
        """The Topology message of this stream (the start node's space described as a space's is)."""
        player = self.player
        node = player.node
        space = node.space
        nodes = [{"name": n.name, "space": space_name(n), "cyclic": n.cyclic,
                  "return_to": n.meta.get("return_to"), "parameters": self._parameters(n)} for n in self.graph.nodes]
        return P.Topology(
            protocol=P.PROTOCOL_VERSION, space=space_name(node), n_vertices=int(space.n_vertices),
            n_faces=int(len(space.faces)), faces=np.ascontiguousarray(space.faces, dtype="<u4").tobytes(),
            codec=codec, bounds_min=bounds[0].tolist(), bounds_max=bounds[1].tolist(),
            quantisation_error=P.quantisation_error(bounds) if codec == "q16" else 0.0,
            parameters=self._parameters(node), sources=space.source_names, durations=space.durations().tolist(),
            cyclic=bool(space.cyclic), mode=self.mode, modes=list(P.MODES), rate=rate,
            model_size=float(space.model_size), limits=dict(limits), graph=self.name, nodes=nodes,
            edges=[{"from": a, "to": b} for a, b in self.graph.edges])

    def _parameters(self, node):
        pmap = node.space.parameter_map
        if pmap is None:
            return []
        asked = self.player.params_of(node.name)
        out = []
        for name, unit, (lo, hi) in zip(pmap.names, pmap.units, pmap.domain()):
            entry = {"name": name, "unit": unit, "min": float(lo), "max": float(hi), "default": float(lo + hi) / 2,
                     "value": float(asked.get(name, (lo + hi) / 2))}
            out.append({key: entry[key] for key in P.PARAMETER_KEYS})
        return out

    # ------------------------------------------------------------ messages

    def action(self, m):
        """Apply an Action message; returns the Notices to send: ``superseded`` for an earlier
        action it replaces (queued, or planned and not yet carried out), then its own
        (``planned``, ``queued``; clamping in the message)."""
        node = self._node(m.node, "action", m.seq)
        bad = _bad_params(node, m.params, "action", m.seq)
        if bad is not None:
            raise bad
        params = {**self.player.params_of(node.name), **(m.params or {})}
        try:
            answer = self.player.request(node.name, params, budget=m.budget)
        except GraphError as exc:  # no route there
            raise P.ProtocolError("unknown_node", f"action: {exc}", "action", m.seq) from None
        notices = []
        dropped = self._queued_seq if answer["dropped"] == "queued" else (
            self._planned_seq if answer["dropped"] == "planned" else None)
        if dropped is not None:
            notices.append(P.Notice(code="superseded", seq=dropped,
                                    message=f"dropped before it was carried out: action {m.seq} ({node.name}) replaces it"))
        if answer["status"] == "queued":
            code, text = "queued", (f"{node.name}: waits for the {'blend' if self.player.blend else self.player.node.name}"
                                    " to end, then is planned (a second notice)")
            self._queued_seq = m.seq
        else:
            code, text = "planned", _plan_text(answer, node.name)
            self._queued_seq, self._planned_seq = None, (m.seq if answer["status"] == "planned" else None)
        if answer.get("clamped"):
            text += f"; {answer['message']}"
        return notices + [P.Notice(code=code, message=text, seq=m.seq)]

    def set_params(self, m):
        """Apply a Params message to the shown node; returns a Notice when the request was clamped."""
        player = self.player
        node = self.graph.node(player.blend.plan.target) if player.blend is not None else player.node
        bad = _bad_params(node, m.params, "params", m.seq)
        if bad is not None:
            raise bad
        answer = player.set_params(m.params)
        if answer["clamped"]:
            return P.Notice(code="clamped", message=answer["message"], seq=m.seq)
        return None

    def set_mode(self, mode):
        self.mode = mode
        self.player.set_mode(mode)

    def refuse(self, m):
        """The ProtocolError for a message a graph stream does not take."""
        return P.ProtocolError("unsupported", f"{m.type} on a graph stream: {UNSUPPORTED[m.type]}", m.type,
                               getattr(m, "seq", getattr(m, "id", None)))

    # ------------------------------------------------------------ frames

    def advance(self, dt):
        """Step the performance by ``dt`` seconds; a queued action planned meanwhile gets its
        ``planned`` notice (through ``notify``)."""
        self._frame = self.player.step(dt, placed=False, vertices=False)
        if self._queued_seq is not None and any(e.startswith("plan queued") for e in self._frame.events):
            answer, seq = self.player.planned, self._queued_seq
            self._queued_seq = None
            self._planned_seq = seq if answer["status"] == "planned" else None
            if self.notify is not None:
                text = (_plan_text(answer, answer["route"][-1]) if answer["status"] == "planned" else
                        f"{answer['route'][-1]}: entered by the transition it waited for, parameters set")
                self.notify(P.Notice(code="planned", message=text, seq=seq))

    def vertices(self):
        """(n, 3) float32 root-local vertices of the current frame (the player's buffer; a frame
        ``table_source`` gives is blended here, on first asking)."""
        if self._frame.vertices is None:
            return self.player.local_vertices()
        return self._frame.vertices

    def table_source(self):
        """``GraphPlayer.table_source``: (phase-table blender, weights) when the frame is one read
        of a phase table at ``phase`` (the scheduler then reads it with others'), else None."""
        return self.player.table_source()

    def _state(self):
        """(requested, realised, clamped) of the shown node at what it was last asked for."""
        player = self.player
        node = player.node
        shown = (player, node.name, player.asked)
        if self._shown is not None and self._shown[0] == shown:  # read three times a frame
            return self._shown[1]
        asked = player.params_of(node.name)
        key = (node.name, tuple(sorted(asked.items())))
        state = self._solved.get(key)
        if state is None:
            pmap = node.space.parameter_map
            if pmap is None:
                state = ([], [], False)
            else:
                requested = [float(asked.get(n, (lo + hi) / 2)) for n, (lo, hi) in zip(pmap.names, pmap.domain())]
                _, realised, clamped, _ = node.solve(asked)
                state = (requested, np.asarray(realised, dtype=float).tolist(), clamped)
            if len(self._solved) > 256:
                self._solved.clear()
            self._solved[key] = state
        self._shown = (shown, state)
        return state

    @property
    def space(self):
        return self.player.node.space

    @property
    def time(self):
        return self.player.time

    @property
    def phase(self):
        return self._frame.phase

    @property
    def position(self):
        return self._frame.root_position

    @property
    def heading(self):
        return self._frame.heading

    @property
    def finished(self):
        return bool(self.player.clock.finished)

    @property
    def weights(self):
        return self.player.clock.weights

    @property
    def state_key(self):
        """Objects that stay the same (``is``) while ``requested``, ``realised``, ``clamped``,
        ``weights`` and ``mode`` do (``Player.state_key``'s contract)."""
        return self._state(), self.player.clock.weights, self.mode, None

    @property
    def requested(self):
        return self._state()[0]

    @property
    def realised(self):
        return self._state()[1]

    @property
    def clamped(self):
        return self._state()[2]

    @property
    def node(self):
        return self._frame.node

    @property
    def target(self):
        return self._frame.target

    @property
    def progress(self):
        return None if self._frame.progress is None else float(min(max(self._frame.progress, 0.0), 1.0))


def _plan_text(answer, node):
    """A planned (or set) action's notice text."""
    if answer["status"] != "planned":
        return f"{node}: already there, parameters set"
    return (f"{' -> '.join(answer['route'])}: leaves in {answer['leave_in']:.2f} s, blends {answer['length']:.2f} s, "
            f"enters {answer['route'][1]} at phase {answer['enter_phase']:.2f}")


# ---------------------------------------------------------------- the stream's handlers
# ``async def on_x(session, message)`` as server/stream/messages.py's: the session's HANDLERS
# send a hello naming a graph, and every message on a graph stream, here.

async def on_hello(session, m):
    """A hello naming ``graph``: the connection plays it from now on."""
    stream = await GraphStream.open(session.graphs, m)
    loop = asyncio.get_running_loop()
    stream.notify = lambda notice: loop.create_task(session.send(notice))
    session.ready = False  # no frames until the new topology has gone out
    session.player = session.graph = stream
    session.space_name, session.rate = f"graph {m.graph}", m.rate
    session.codec, session.window, session.heatmap = m.codec, m.window, False
    session.bounds = stream.bounds()
    session.paused, session.last_step = False, None
    session.quantiser = P.Quantiser(session.bounds, stream.space.n_vertices) if m.codec == "q16" else None
    await session.send(stream.topology(codec=m.codec, rate=m.rate, limits=session.limits, bounds=session.bounds))
    if stream.start_params:  # start parameters out of reach: said before the first frame, as for params
        node = stream.player.node
        _, _, clamped, message = node.solve(stream.player.params_of(node.name))
        if clamped:
            await session.send(P.Notice(code="clamped", message=message, seq=m.seq))
    session.seq = session.acked_frame = session.ack = session.dropped = 0  # afresh: as on a new connection
    session.waiting_ack = False
    session.stalled_since = None
    session.next_due = asyncio.get_running_loop().time()
    session.ready = True
    session.poke(m.seq)


async def on_action(session, m):
    if session.graph is None:
        raise P.ProtocolError("unsupported", f"action on a space stream ({session.space_name}): hello with a graph "
                                             "to send actions", "action", m.seq)
    for notice in session.graph.action(m):  # in order, before the frame that acknowledges the action
        await session.send(notice)
    session.poke(m.seq)


async def on_params(session, m):
    notice = session.graph.set_params(m)
    if notice is not None:  # before the frame that acknowledges the message
        await session.send(notice)
    session.poke(m.seq)


async def on_mode(session, m):
    await session.graph.prepare(m.mode)
    session.graph.set_mode(m.mode)
    session.poke(m.seq)


async def on_reset(session, m):
    session.graph.reset()
    session.last_step = None
    session.poke(m.seq)


async def on_unsupported(session, m):
    raise session.graph.refuse(m)


# message type -> handler on a graph stream (the others: server/stream/messages.py's, as for a space)
HANDLERS = {P.Params.type: on_params, P.Mode.type: on_mode, P.Reset.type: on_reset, P.Action.type: on_action,
            P.Seek.type: on_unsupported, P.Heatmap.type: on_unsupported, P.Pull.type: on_unsupported}
