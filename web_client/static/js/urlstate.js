// The view's state in the page URL, so a reload or a shared link opens the same view:
// ?space=locomotion&mode=linear&heatmap=1&scale=auto&camera=side&p.speed=2.1&p.turn_rate=-20
// (plus codec, rate, smoothing, lite and trail when set); ?graph=demo for a motion graph (the
// page's space is then "graph:demo"). Written with history.replaceState,
// at most every 250 ms; read once at start.
import { MODES, CODECS } from "../protocol.js";
import { PRESETS } from "./camera.js";

const WRITE_MS = 250;
const MAX_RATE = 120;       // frames/s: the server's default max_fps
const MAX_SMOOTHING = 10;   // seconds: the protocol's range (0 to 10)

/** What the URL asks for: {space, mode, codec, rate, smoothing, heatmap, scale, camera, trail, params}. */
export function readUrl(search = location.search) {
  const query = new URLSearchParams(search);
  const number = (key) => (query.has(key) && Number.isFinite(Number(query.get(key))) ? Number(query.get(key)) : null);
  // a value the server would refuse falls back to the default (a refused hello would leave the page dead)
  const within = (value, low, high) => (value !== null && value >= low && value <= high ? value : null);
  const params = {};
  for (const [key, value] of query) {
    if (key.startsWith("p.") && value !== "" && Number.isFinite(Number(value))) params[key.slice(2)] = Number(value);
  }
  const scale = query.get("scale");
  return {
    space: query.get("graph") ? `graph:${query.get("graph")}` : query.get("space") || null,
    mode: MODES.includes(query.get("mode")) ? query.get("mode") : null,
    codec: CODECS.includes(query.get("codec")) ? query.get("codec") : null,
    rate: within(number("rate"), 0.5, MAX_RATE),
    smoothing: within(number("smoothing"), 0, MAX_SMOOTHING),
    heatmap: query.get("heatmap") === "1",
    scale: scale === "auto" ? "auto" : within(number("scale"), 1e-3, 1e6),
    camera: PRESETS.includes(query.get("camera")) ? query.get("camera") : null,
    trail: query.get("trail") === "1",
    params,
    lite: query.has("lite") ? query.get("lite") === "1" : null,
  };
}

/** The URL for a view: {space, mode, heatmap, scale, camera, trail, params, extra: {key: value}}. */
export function viewUrl(view, base = location.href) {
  const url = new URL(base);
  const query = url.searchParams;
  for (const key of [...query.keys()]) if (key.startsWith("p.")) query.delete(key);
  const set = (key, value) => (value === null || value === undefined || value === false ? query.delete(key) : query.set(key, value));
  const graph = view.space && view.space.startsWith("graph:") ? view.space.slice(6) : null;
  set("space", graph ? null : view.space);
  set("graph", graph);
  set("mode", view.mode);
  set("heatmap", view.heatmap ? "1" : null);
  set("scale", view.heatmap ? view.scale : null);
  set("camera", view.camera);
  set("trail", view.trail ? "1" : null);
  for (const [name, value] of Object.entries(view.params || {})) {
    if (Number.isFinite(value)) query.set(`p.${name}`, String(Number(value.toPrecision(5))));
  }
  return url.toString();
}

/** Keeps location in step with the view (replaceState, throttled). */
export class UrlWriter {
  constructor(getView) {
    this.getView = getView;
    this.timer = null;
  }

  changed() {
    if (this.timer !== null) return;
    this.timer = setTimeout(() => this.flush(), WRITE_MS);
  }

  flush() {
    clearTimeout(this.timer);
    this.timer = null;
    const view = this.getView();
    if (!view.space) return;
    const next = viewUrl(view);
    if (next !== location.href) history.replaceState(null, "", next);
  }
}
