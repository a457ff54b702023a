"""Plays a motion graph: one node at a time, transitions blended across, one-shots returning to a
cyclic node on their own, the root carried continuously through all of it.

``player = GraphPlayer(graph, node="walk", params={"speed": 1.3})``; ``player.request("jump",
{"jump_height": 0.45})`` plans a transition (``TransitionSearch``); ``frame = player.step(dt)``
per display frame. Across a transition both nodes play on (the source from where it is left, the
target from where it is entered, at the requested parameters), their root-local meshes and
their root steps are blended with a smooth-step weight, so the root's position and heading stay
continuous; a foot on the ground stays where it is (``FootPins``: its leg carries it back by its
drift, within the leg's reach, and catches up while the foot is in the air). A request to a node without an edge from the current one follows the shortest route
(each hop at the parameters that node last had). Requests made while a transition is blending
wait for it to end; one made in a one-shot redirects its return when an edge allows, or waits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from engine.graph.build import GraphError
from engine.graph.clock import NodeClock, foot_vertices, move, place
from engine.graph.compiled import feet_world
from engine.graph.feet import FootPins
from engine.graph.search import TransitionSearch

MODES = ("linear", "hybrid", "nonlinear")


def smooth_weight(u):
    """Blend weight of the target at fraction u of a transition: cubic smooth step."""
    u = min(max(u, 0.0), 1.0)
    return u * u * (3.0 - 2.0 * u)


@dataclass
class GraphFrame:
    """One played frame.

    time : float; node : str (the source during a transition); phase : float (of ``node``)
    target : str or None (during a transition or while one is planned); progress : float or None
    (0..1 across a blend); params : dict (``node``'s realised parameters)
    root_position : (3,) float; heading : float (rad); vertices : (n, 3) float32 world positions
    events : list of str (what happened during the step: "leave walk -> jump", "enter jump")
    """

    time: float
    node: str
    phase: float
    target: str | None
    progress: float | None
    params: dict
    root_position: np.ndarray
    heading: float
    vertices: np.ndarray
    events: list = field(default_factory=list)


@dataclass
class _Blend:
    plan: object
    clock: NodeClock
    elapsed: float = 0.0


class GraphPlayer:
    """Plays a MotionGraph under requests.

    Parameters
    ----------
    graph : MotionGraph
    node : str or None       start node (default: the first cyclic node)
    params : dict or None    its parameters (default: the middle of each range)
    mode : str               blend mode of the nodes' spaces
    search : TransitionSearch or None
    foot_lock : bool         hold the feet during a blend (``engine.graph.feet.FootPins``): a foot
                             on the ground stays put, its leg reaching for it, until it lifts
    contact : float          metres above the rest mesh's lowest point that count as on the ground
    record : bool            keep every request in ``requests`` (for a recording); a stream that
                             is never recorded says False, so a long session does not grow it
    tables : bool            blend through the spaces' phase tables (``NodeClock``): a stream
                             says True (a frame costs one interpolation at weights that recur)
    """

    def __init__(self, graph, *, node=None, params=None, mode="hybrid", search=None, foot_lock=True,
                 contact=0.01, record=True, tables=False):
        if mode not in MODES:
            raise ValueError(f"unknown blend mode {mode!r}; choose one of {', '.join(MODES)}")
        self.graph, self.mode = graph, mode
        self.search = search or TransitionSearch(graph)
        start = graph.node(node) if node else next((n for n in graph.nodes if n.cyclic), graph.nodes[0])
        self._params = {n.name: {} for n in graph.nodes}  # what each node was last asked for
        self._params[start.name] = dict(params or {})
        self.asked = 0           # bumped whenever a node's asked-for parameters change (params_of)
        weights, self._realised, clamped, message = start.solve(self._params[start.name])
        self.start_clamped = message if clamped else None  # the start parameters' clamp, if any
        self.node = start
        self.tables = bool(tables)
        self.clock = NodeClock(start.space, weights, 0.0, tables=self.tables)
        self.time, self.frames = 0.0, 0
        self.position, self.heading = np.zeros(3), 0.0
        self.pending = None      # a planned transition not started: (plan, seconds left)
        self.blend = None        # the transition being blended
        self.queued = None       # a request waiting for the current transition
        self.route = []          # nodes still to visit after the pending transition's target
        self.requests = []       # every request: {"frame", "node", "params", "budget"} (for replay)
        self.record = bool(record)
        self.left = None         # (plan, source weights) of the last transition started
        self.planned = None      # the plan (as request returns it) of the last queued request planned
        self._asked = False      # the pending plan and route serve a request (not a one-shot's return)
        self._buffer = None
        self._shown_params = None  # (realised parameters, node, {name: value}) of the frames
        self.foot_lock = bool(foot_lock)
        rest = np.asarray(start.space.container["rest"])
        self._feet = foot_vertices(rest)
        self._feet_index = np.concatenate(self._feet).astype(np.int64)  # both feet in one gather
        self._feet_bounds = np.cumsum([0] + [len(f) for f in self._feet]).astype(np.int64)
        self._ground = float(rest[:, 1].min()) + float(contact)  # below this: on the ground
        self.pins = FootPins(rest, self._feet, self._ground)
        self._cached = None      # (frames, root-local mesh, progress) of the current state
        self._moved = False      # the cached mesh's legs have been moved to hold the feet (shown)
        self._hold = None        # FootPins.prepare's answer for the cached mesh (None: no foot held)
        self._joints = None      # the legs' joints found on the cached mesh (LegRig.reach's ``known``)
        self._feet_before, self._feet_frame = None, None  # the feet in the world, at frame number
        self._dt = 0.0           # the last step's length (a blend planned to start within it is near)
        if not start.cyclic:
            self._plan_return()

    # requests ---------------------------------------------------------------------------------

    def request(self, node, params=None, *, budget=None):
        """Ask for ``node`` at ``params`` ({name: value}), within ``budget`` seconds if given.

        Returns a dict: ``status`` ("planned", "queued" or "set"), and when planned the
        transition (``leave_in``, ``enter_phase``, ``length``, ``latency``, ``dissimilarity``)
        and the ``route``; ``clamped`` / ``message`` when the parameters were out of reach.
        The latest request wins: it replaces a request still queued and a transition planned
        but not started (``dropped`` says which: "queued", "planned" or None). A queued request
        is planned when the blend or the one-shot it waits for ends; ``step``'s frame then has
        the event "plan queued NODE" and ``planned`` holds its plan (as this method returns it).
        """
        target = self.graph.node(node)
        if budget is not None and not (np.isfinite(budget) and budget > 0):
            raise GraphError(f"budget must be a positive number of seconds, got {budget}")
        weights, realised, clamped, message = target.solve(params)  # validates before anything changes
        waits = self.blend is not None or (not self.node.cyclic and not self._can_redirect(node))
        if waits:  # it will be planned from the node the blend (or the one-shot's return) enters
            self.graph.route(self.blend.plan.target if self.blend is not None else self.node.name, node)
        # what this request takes the place of: a queued request; or the rest of a requested plan
        # (a waiting request goes before a route's later hops; a new plan replaces the pending one)
        dropped = "queued" if self.queued is not None else (
            "planned" if self._asked and (self.route or (not waits and self.pending is not None)) else None)
        if self.record:
            self.requests.append({"frame": self.frames, "node": node, "params": dict(params or {}), "budget": budget})
        self._params[node] = dict(params or {})
        self.asked += 1
        note = {"clamped": clamped, "message": message, "dropped": dropped}
        if waits:
            self.queued = (node, budget)
            return {"status": "queued", **note}
        self.queued = None
        if node == self.node.name:
            self.pending, self.route, self._asked = None, [], False
            self.clock.set_weights(weights)
            self._cached = None
            self._realised = realised
            return {"status": "set", **note}
        answer = self._plan(node, budget, asked=True)
        self._asked = True
        return {**answer, **note}

    def set_params(self, params):
        """Change the parameters of the node the frames show (during a blend: its target) at
        once, the names not given keeping what that node was last asked for; no transition.

        Returns {"status": "set", "node", "clamped", "message"}.
        """
        node = self.graph.node(self.blend.plan.target) if self.blend is not None else self.node
        merged = {**self._params[node.name], **dict(params or {})}
        weights, realised, clamped, message = node.solve(merged)  # validates before anything changes
        if self.record:
            self.requests.append({"frame": self.frames, "node": node.name, "params": dict(params or {}),
                                  "budget": None, "set": True})
        self._params[node.name] = merged
        self.asked += 1
        if self.blend is not None:
            self.blend.clock.set_weights(weights)
        else:
            self.clock.set_weights(weights)
            self._realised = realised
        self._cached = None
        return {"status": "set", "node": node.name, "clamped": clamped, "message": message}

    def params_of(self, node):
        """{name: value} ``node`` was last asked for (names not asked: the middle of their range)."""
        return dict(self._params[self.graph.node(node).name])

    def set_mode(self, mode):
        """Blend the nodes' spaces in ``mode`` from the next frame on."""
        if mode not in MODES:
            raise ValueError(f"unknown blend mode {mode!r}; choose one of {', '.join(MODES)}")
        self.mode = mode
        self._cached = None

    def _can_redirect(self, node):
        return self.graph.node(node).cyclic and (self.node.name, node) in self.graph.edges

    def _plan(self, goal, budget=None, *, asked=False):
        """Plan the first hop towards ``goal``. From a one-shot, a transition the user ``asked``
        for along another edge than its return (stop -> walk: walk on instead of stopping) leaves
        as the search's latency weight says, also before ``min_exit`` where the seam is as good
        (``early``: a stop still walking, not a jump in the air); otherwise (its own return,
        asked for or not, the next hop of a route) the one-shot is performed: left no earlier
        than ``min_exit`` of its clip, at the best seam before its end."""
        here = self.node.name
        route = self.graph.route(here, goal)
        hop = self.graph.node(route[1])
        weights, _, _, _ = hop.solve(self._params[hop.name])
        finish_by = latency_weight = None
        early = False
        if not self.node.cyclic:  # a one-shot is left before its end
            finish_by = max((1.0 - self.clock.phase) * self.clock.duration, self.search.options.lengths[0])
            if asked and hop.name != self.node.meta.get("return_to"):  # another way out than its own
                early = True
            else:
                latency_weight = 0.0
        plan = self.search.search(here, self.clock.weights, self.clock.phase, hop.name, weights, budget=budget,
                                  latency_weight=latency_weight, finish_by=finish_by, early=early)
        self.pending = [plan, plan.leave_in]
        self.route = route[2:]
        return {"status": "planned", "route": route, "leave_in": plan.leave_in, "enter_phase": plan.enter_phase,
                "length": plan.length, "latency": plan.latency, "dissimilarity": plan.dissimilarity}

    def _plan_return(self):
        self._plan(self.node.meta["return_to"])

    # playing ----------------------------------------------------------------------------------

    def step(self, dt, *, placed=True, vertices=True):
        """Advance ``dt`` seconds; the frame there (``placed=False``: root-local, as ``frame``;
        ``vertices=False``: as ``frame``, without the vertices of a frame ``table_source`` gives)."""
        dt = float(dt)
        if not (dt >= 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a non-negative number of seconds, got {dt}")
        events = []
        self._dt = dt
        held = self.foot_lock and self.pins.holding()  # (the offsets change only where the feet are held)
        if self._locking(held) and self._feet_frame != self.frames:  # the feet before this step, for the lock
            self._feet_before, self._feet_frame = self._feet_at(), self.frames
            held = self.pins.holding()  # (a frame blended here plans its hold: it may shorten an offset)
        self._cached = None
        if self.pending is not None and self.blend is None and self.pending[1] <= 0.5 * dt:
            plan = self.pending[0]
            target = self.graph.node(plan.target)
            self.blend = _Blend(plan, NodeClock(target.space, plan.target_weights, plan.enter_phase,
                                                tables=self.tables))
            self.left = (plan, self.clock.weights.copy())
            self.pending = None
            events.append(f"leave {plan.source} -> {plan.target}")
        elif self.pending is not None and self.blend is None:
            self.pending[1] -= dt
        step = self.clock.advance(dt)
        if self.blend is not None:
            other = self.blend.clock.advance(dt)
            self.blend.elapsed += dt
            s = smooth_weight(self.blend.elapsed / self.blend.plan.length)
            step = tuple((1 - s) * x + s * y for x, y in zip(step, other))
        self.position, self.heading = move(self.position, self.heading, *step)
        self.time += dt
        self.frames += 1
        if self.foot_lock and (self.blend is not None or held):
            self._hold_feet(dt)
            held = self.pins.holding()
        if self._locking(held):  # only near a blend are the feet held: elsewhere they are not placed
            self._feet_before, self._feet_frame = self._feet_at(), self.frames
        if self.blend is not None and self.blend.elapsed >= self.blend.plan.length - 1e-9:
            events += self._enter()
        elif self.blend is None and self.pending is None and not self.node.cyclic and self.clock.finished:
            self._plan_return()  # the planned return could not be kept: leave now
        return self.frame(events, placed=placed, vertices=vertices)

    def table_source(self):
        """(phase-table blender, weights) when the current frame is one read of the playing
        space's phase table (a player with ``tables``, linear or hybrid, no transition blending, no
        foot held), else None: the frame's root-local vertices are then
        ``blender.blend(weights, frame.phase)``, as ``frame`` gives them."""
        if not self.tables or self.mode == "nonlinear" or self.blend is not None or self.pins.holding():
            return None
        return self.clock.space.frame_blender(self.mode), self.clock.weights

    def local_vertices(self):
        """(n, 3) float32 root-local vertices of the current frame (the player's buffer, overwritten
        by the next step)."""
        return self._shown()[0]

    def _locking(self, held):
        """The next step may blend, so the feet's places are needed (``held``: ``pins.holding()``)."""
        soon = self.pending is not None and self.pending[1] <= 0.5 * self._dt  # a blend may start next step
        return self.foot_lock and (self.blend is not None or soon or held)

    def _enter(self):
        plan = self.blend.plan
        self.node = self.graph.node(plan.target)
        self.clock = self.blend.clock
        self.blend = None
        self._cached = None
        _, self._realised, _, _ = self.node.solve(self._params[self.node.name])
        events = [f"enter {plan.target}"]
        if self.queued is not None:  # the latest request: before the rest of an earlier one's route
            node, budget = self.queued
            self.queued, self.route = None, []
            if node != self.node.name:
                self.planned = self._plan(node, budget, asked=True)
                self._asked = True
            else:  # the blend it waited for went there
                self.planned, self._asked = {"status": "set", "route": [node]}, False
            events.append(f"plan queued {node}")
        elif self.route:
            goal, self.route = self.route[-1], []
            self._plan(goal)
        else:
            self._asked = False
        if self.pending is None and not self.node.cyclic:
            self._plan_return()
            self._asked = False
        return events

    def _local(self):
        """(root-local mesh, progress or None) at the current state, blended once per frame."""
        if self._cached is not None and self._cached[0] == self.frames:
            return self._cached[1], self._cached[2]
        progress = None
        if self._buffer is None:
            self._buffer = np.empty((self.node.space.n_vertices, 3), dtype=np.float32)
        if self.mode == "nonlinear":  # float64 blends: weighted (or cast) into the float32 buffer
            mesh = self.clock.mesh(self.mode)
        else:  # float32 blends: written straight into the buffer (the same numbers as a copy)
            self.clock.mesh(self.mode, out=self._buffer)
            mesh = self._buffer
        if self.blend is not None:
            s = smooth_weight(self.blend.elapsed / self.blend.plan.length)
            np.multiply(mesh, 1.0 - s, out=self._buffer)
            self._buffer += np.float32(s) * np.asarray(self.blend.clock.mesh(self.mode), dtype=np.float32)
            progress = self.blend.elapsed / self.blend.plan.length
        elif self.mode == "nonlinear":
            self._buffer[:] = mesh
        mesh = self._buffer
        # the feet held: planned here, the legs moved once, when the frame is shown (_shown)
        self._joints = [None] * len(self.pins.rig.legs)  # found once a frame, for both plans of a hold
        self._hold = self.pins.prepare(mesh, self.heading, self._joints) if self.pins.holding() else None
        self._moved = False
        self._cached = (self.frames, mesh, progress)
        return mesh, progress

    def _shown(self):
        """(root-local mesh, progress): ``_local``'s with the held feet's legs moved."""
        mesh, progress = self._local()
        if self._hold is not None and not self._moved:
            self._moved = True
            self.pins.rig.move(mesh, *self._hold)
        return mesh, progress

    def _feet_at(self):
        """The feet's vertices in the world now, (F, 3) float32, stacked in ``FootPins.feet``'s
        order (held: moved by their offsets, as ``_shown`` moves them, without moving the legs;
        one compiled pass, ``engine.graph.compiled.feet_world``)."""
        mesh, _ = self._local()
        hold = None
        if self._hold is not None and not self._moved:
            local, shares, _ = self._hold
            hold = (local, shares)  # what LegRig.move writes into the feet's rows
        return feet_world(mesh, self._feet_index, self._feet_bounds, self.position, self.heading, hold)

    def _hold_feet(self, dt):
        """Hold the feet on the ground where they were, on the mesh just shown (``FootPins``)."""
        if self.blend is not None:  # any foot on the ground is held: the blend is what moves it
            planted = np.ones(len(self._feet), dtype=bool)
        else:  # after it, a held foot is let go when the motion lifts or swings it
            planted = self.pins.planted(self.node, self.clock.weights, self.clock.phase) >= 0.5
        change = self.pins.update(self._feet_before, self._feet_at(), planted, dt, blending=self.blend is not None)
        if any(change.ravel().tolist()):  # the frame shown: the motion's legs held at the new offsets
            if self._moved:  # already shown with its legs moved (not in step: it blends the frame first)
                self._cached = None
                self._local()  # blended again: the motion's legs, the hold planned at the new offsets
            else:
                mesh = self._local()[0]
                self._hold = self.pins.prepare(mesh, self.heading, self._joints) if self.pins.holding() else None

    def frame(self, events=None, *, placed=True, vertices=True):
        """The frame at the current state (nothing advances); ``placed=False``: its vertices are
        root-local (the player's buffer, overwritten by the next step: encode or copy them);
        ``vertices=False``: ``vertices`` is None where ``table_source`` gives them (not blended:
        ``local_vertices`` blends them if needed)."""
        if not vertices and not placed and self.table_source() is not None:
            mesh, progress = None, None
        else:
            mesh, progress = self._shown()
        target = None
        if progress is not None:
            target = self.blend.plan.target
        elif self.pending is not None:
            target = self.pending[0].target
        shown = self._shown_params
        if shown is None or shown[0] is not self._realised or shown[1] is not self.node:  # once per change
            names = dict(zip(self.node.parameters, np.asarray(self._realised, dtype=float).tolist()))
            shown = self._shown_params = (self._realised, self.node, names)
        params = dict(shown[2])
        return GraphFrame(time=self.time, node=self.node.name, phase=self.clock.phase, target=target,
                          progress=progress, params=params, root_position=self.position.copy(),
                          heading=float(self.heading),
                          vertices=place(mesh, self.position, self.heading) if placed and mesh is not None else mesh,
                          events=list(events or []))
