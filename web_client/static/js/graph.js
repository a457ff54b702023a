// The motion graph a stream plays, drawn as SVG: nodes (spaces) on a ring, edges (the allowed
// transitions) as arrows, the node shown filled, the transition's target outlined, and a dot
// travelling the edge as the blend progresses. Clicking a node asks for it (an action).
const SVG = "http://www.w3.org/2000/svg";
const SIZE = 240;         // the diagram's viewBox is SIZE x SIZE
const RADIUS = 82;        // of the ring the nodes sit on
const NODE_RADIUS = 24;

function element(name, attributes = {}, parent = null) {
  const node = document.createElementNS(SVG, name);
  for (const [key, value] of Object.entries(attributes)) node.setAttribute(key, String(value));
  if (parent) parent.append(node);
  return node;
}

export class GraphView {
  /** container: an element to draw into; onNode(name): a node was clicked. */
  constructor(container, onNode) {
    this.container = container;
    this.onNode = onNode;
    this.svg = null;
    this.nodes = new Map();   // name -> <g>
    this.edges = new Map();   // "a>b" -> {line, from, to}
    this.places = new Map();  // name -> [x, y]
    this.dot = null;
    this.shown = { node: null, target: null, progress: null };
  }

  /** Draw the graph of a topology (its `nodes` and `edges`); clears the diagram for a space. */
  build(topology) {
    this.container.replaceChildren();
    this.nodes.clear();
    this.edges.clear();
    this.places.clear();
    this.shown = { node: null, target: null, progress: null };
    if (!topology?.graph) return;
    const svg = element("svg", { viewBox: `0 0 ${SIZE} ${SIZE}`, role: "img",
      "aria-label": `motion graph ${topology.graph}` });
    const defs = element("defs", {}, svg);
    const marker = element("marker", { id: "graph-arrow", viewBox: "0 0 10 10", refX: 9, refY: 5, markerWidth: 7,
      markerHeight: 7, orient: "auto-start-reverse" }, defs);
    element("path", { d: "M0,0 L10,5 L0,10 z", class: "arrow" }, marker);
    const count = topology.nodes.length;
    topology.nodes.forEach((node, i) => {
      const angle = -Math.PI / 2 + (2 * Math.PI * i) / count;
      this.places.set(node.name, [SIZE / 2 + RADIUS * Math.cos(angle), SIZE / 2 + RADIUS * Math.sin(angle)]);
    });
    const pairs = new Set(topology.edges.map((e) => `${e.from}>${e.to}`));
    const edgeLayer = element("g", { class: "edges" }, svg);
    for (const { from, to } of topology.edges) {
      const [x0, y0] = this.places.get(from);
      const [x1, y1] = this.places.get(to);
      const length = Math.hypot(x1 - x0, y1 - y0) || 1;
      const [ux, uy] = [(x1 - x0) / length, (y1 - y0) / length];
      const side = pairs.has(`${to}>${from}`) ? 5 : 0;  // both ways: two arrows side by side
      const [ox, oy] = [-uy * side, ux * side];
      const ends = [x0 + ux * NODE_RADIUS + ox, y0 + uy * NODE_RADIUS + oy, x1 - ux * (NODE_RADIUS + 2) + ox,
        y1 - uy * (NODE_RADIUS + 2) + oy];
      const line = element("line", { x1: ends[0], y1: ends[1], x2: ends[2], y2: ends[3], class: "edge",
        "marker-end": "url(#graph-arrow)", "data-edge": `${from}>${to}` }, edgeLayer);
      this.edges.set(`${from}>${to}`, { line, ends });
    }
    const nodeLayer = element("g", { class: "nodes" }, svg);
    for (const node of topology.nodes) {
      const [x, y] = this.places.get(node.name);
      const group = element("g", { class: `node ${node.cyclic ? "cyclic" : "oneshot"}`, "data-node": node.name,
        tabindex: 0, role: "button", "aria-label": `go to ${node.name}` }, nodeLayer);
      element("circle", { cx: x, cy: y, r: NODE_RADIUS }, group);
      const label = element("text", { x, y: y + 4, "text-anchor": "middle" }, group);
      label.textContent = node.name;
      const title = element("title", {}, group);
      title.textContent = `${node.name}: ${node.cyclic ? "cyclic" : `one-shot, returns to ${node.return_to}`}` +
        (node.parameters.length ? ` (${node.parameters.map((p) => p.name).join(", ")})` : "");
      group.addEventListener("click", () => this.onNode(node.name));
      group.addEventListener("keydown", (event) => {
        if (event.key === "Enter") this.onNode(node.name);
      });
      this.nodes.set(node.name, group);
    }
    this.dot = element("circle", { r: 5, class: "progress-dot", visibility: "hidden" }, svg);
    this.container.append(svg);
    this.svg = svg;
  }

  /** Show a frame's node, target and progress. */
  update(frame) {
    if (!this.svg) return;
    const { node, target } = frame;
    const progress = frame.progress ?? null;
    if (node === this.shown.node && target === this.shown.target && progress === this.shown.progress) return;
    this.shown = { node, target, progress };
    for (const [name, group] of this.nodes) {
      group.classList.toggle("active", name === node);
      group.classList.toggle("target", name === target);
    }
    for (const [key, edge] of this.edges) {
      const live = key === `${node}>${target}`;
      edge.line.classList.toggle("planned", live && progress === null);
      edge.line.classList.toggle("blending", live && progress !== null);
    }
    const edge = this.edges.get(`${node}>${target}`);
    if (edge && progress !== null) {
      const [x0, y0, x1, y1] = edge.ends;
      this.dot.setAttribute("cx", String(x0 + (x1 - x0) * progress));
      this.dot.setAttribute("cy", String(y0 + (y1 - y0) * progress));
      this.dot.setAttribute("visibility", "visible");
    } else {
      this.dot.setAttribute("visibility", "hidden");
    }
  }
}
