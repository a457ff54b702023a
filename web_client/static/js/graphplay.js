// A motion graph on the page: what the page sends and shows while a graph streams. The page's
// space is "graph:NAME" then (state.space); the sliders are the union of the nodes' parameters
// (one per name); actions come from keys (Space: jump, R: reach, 1-9: the nodes in order) and
// clicks on the diagram (graph.js), each asking for its node at that node's slider values.
export const GRAPH = "graph:";

/** The graph's name in a page space key ("graph:NAME"), or null for a motion space. */
export const graphName = (key) => (key && key.startsWith(GRAPH) ? key.slice(GRAPH.length) : null);

/** The page space key a topology answers: "graph:NAME" for a graph, else the space's name. */
export const keyOf = (topology) => (topology ? (topology.graph ? GRAPH + topology.graph : topology.space) : null);

/** The union of a graph's parameters (one slider per name, across nodes; `nodes`: which have it). */
export function graphDefs(graph) {
  const defs = new Map();
  for (const node of graph.nodes) {
    for (const p of node.parameters) {
      if (!defs.has(p.name)) defs.set(p.name, { ...p, nodes: [node.name] });
      else defs.get(p.name).nodes.push(node.name);
    }
  }
  return [...defs.values()];
}

export class GraphPlay {
  /**
   * state: the page state (space, graphs, topology, frame, action); connection: StreamConnection;
   * view: GraphView; targets(): the page's {name: value}; say(text, kind, ms, key); statusRows(defs):
   * rebuild the status table; sent(seq): a params message went out; line: the element saying where
   * the character is.
   */
  constructor(state, connection, { view, targets, say, statusRows, sent, line }) {
    Object.assign(this, { state, connection, view, targets, say, statusRows, sent, line });
    this.shownOn = null;  // the node the status rows describe
  }

  /** The hello's fields: a space's, or a graph's (its start node at the sliders' values). */
  helloFields(common) {
    const state = this.state;
    const name = graphName(state.space);
    if (!name) return { ...common, space: state.space, heatmap: state.heatmap, params: state.targets[state.space] };
    const info = state.graphs.find((g) => g.name === name);
    const start = info?.nodes.find((n) => n.name === info.start);
    return { ...common, graph: name, params: start ? this.paramsOf(start) : undefined };
  }

  /** A new topology: draw its graph (or clear the diagram for a space). */
  topology(topology) {
    this.view.build(topology);
    this.shownOn = null;
    this.state.action = null;
    this.line.textContent = "";
  }

  /** The sliders' values of a node's parameters ({name: value}; undefined when none is set). */
  paramsOf(node) {
    const mine = this.targets();
    const entries = node.parameters.filter((p) => Number.isFinite(mine[p.name])).map((p) => [p.name, mine[p.name]]);
    return entries.length ? Object.fromEntries(entries) : undefined;
  }

  nodeInfo(name) {
    return this.state.topology?.nodes?.find((n) => n.name === name) ?? null;
  }

  /** The node whose parameters a `params` message changes: the one shown, or a blend's target. */
  shownNode() {
    const frame = this.state.frame;
    if (!frame) return this.nodeInfo(this.state.topology?.nodes?.[0]?.name);
    return this.nodeInfo(frame.progress !== null && frame.progress !== undefined ? frame.target : frame.node);
  }

  /** Ask for a node at its sliders' values (an action); false when the graph has no such node. */
  act(name) {
    const node = this.nodeInfo(name);
    if (!node || !this.connection.open) return false;
    const seq = this.connection.send("action", { node: name, params: this.paramsOf(node) });
    this.state.action = { node: name, seq, sentAt: performance.now(), entered: null };
    this.say(`action: ${name}`, "info", 1500, "action");
    return true;
  }

  /** The node a key asks for: Space a jump, R a reach, 1-9 the nodes in order (or null). */
  actionKey(event) {
    const nodes = this.state.topology?.nodes ?? [];
    const named = (word) => nodes.find((n) => n.name === word) ?? nodes.find((n) => n.name.includes(word));
    if (event.code === "Space") return named("jump")?.name ?? null;
    if (event.code === "KeyR") return named("reach")?.name ?? null;
    const digit = /^Digit([1-9])$/.exec(event.code);
    return digit ? nodes[Number(digit[1]) - 1]?.name ?? null : null;
  }

  /** A streamed frame: the diagram, the last action's time to entry, the status rows' node. */
  frame(frame) {
    this.view.update(frame);
    const action = this.state.action;
    const blending = frame.progress !== null && frame.progress !== undefined;
    if (action && action.entered === null && frame.ack >= action.seq && frame.node === action.node && !blending) {
      action.entered = (performance.now() - action.sentAt) / 1000;
    }
    if (frame.node !== this.shownOn) {  // the frame's numbers are this node's now
      this.shownOn = frame.node;
      const node = this.nodeInfo(frame.node);
      this.state.topology.parameters = node?.parameters ?? [];
      this.statusRows(this.state.topology.parameters);
      // sliders moved while another node played: this node takes their values now
      const wanted = node ? this.paramsOf(node) : undefined;
      if (wanted && node.parameters.some((p, i) => Math.abs((frame.requested[i] ?? NaN) - wanted[p.name]) > 1e-9)) {
        this.sent(this.connection.send("params", { params: wanted }));
      }
    }
    const where = blending ? `${frame.node} → ${frame.target} ${(100 * frame.progress).toFixed(0)}%`
      : frame.target ? `${frame.node} (then ${frame.target})` : frame.node;
    const entered = action && action.entered !== null
      ? ` · ${action.node} entered ${action.entered.toFixed(2)} s after its key` : "";
    this.line.textContent = `${where}${entered}`;
  }
}
