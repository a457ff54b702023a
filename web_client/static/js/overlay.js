// The overlay over the 3D view: the status box (connection, frame rate, latency, drops, the
// parameter table) and the messages top right.
import { graphName } from "./graphplay.js";
import { formatValue } from "./params.js";

const $ = (id) => document.getElementById(id);

/** A message top right for `ms`; one with the same `key` (default: the text) replaces it. */
export function say(text, kind = "info", ms = 4000, key = text) {
  const box = $("messages");
  for (const old of [...box.children]) if (old.dataset.key === key) old.remove();
  const div = document.createElement("div");
  div.className = `message ${kind}`;
  div.dataset.key = key;
  div.textContent = text;
  box.prepend(div);
  while (box.children.length > 4) box.lastChild.remove();
  setTimeout(() => div.remove(), ms);
}

export function buildStatusRows(defs) {
  const body = $("realised").querySelector("tbody");
  body.replaceChildren(...defs.map((def) => {
    const row = document.createElement("tr");
    row.dataset.name = def.name;
    row.innerHTML = "<td></td><td class='target'></td><td class='requested'></td><td class='realised'></td>";
    row.cells[0].textContent = `${def.name.replace(/_/g, " ")} (${def.unit})`;
    return row;
  }));
}

function ms(value) {
  return value === null || value === undefined ? "–" : `${value.toFixed(0)} ms`;
}

const LABELS = { open: "live", connecting: "connecting", reconnecting: "reconnecting…", idle: "no stream" };

/** Refresh the status box from the page state, the stream statistics and the frames drawn. */
export function renderStatus(state, stats, framesDrawn, targets) {
  const pill = $("conn");
  pill.textContent = LABELS[state.connection] ?? state.connection;
  pill.className = `pill ${state.connection}`;
  // a graph as the picker lists it ("demo (graph)"), not by the picker's value ("graph:demo")
  const graph = graphName(state.space);
  const shown = graph ? `${graph} (graph)` : state.space;
  $("status-space").textContent = state.space ? `${shown} · ${state.codec}` : "no playable space";
  const s = stats.snapshot();
  $("stat-fps").textContent = state.paused ? `${s.fps.toFixed(0)} (paused)` : s.fps.toFixed(0);
  const lat = s.latency;
  $("stat-latency").textContent = lat.n ? `${ms(lat.last)} (median ${ms(lat.median)}, p95 ${ms(lat.p95)})` : "–";
  $("stat-dropped").textContent = `${s.dropped} / ${s.gaps} / ${Math.max(0, s.framesTotal - framesDrawn)}`;
  const frame = state.frame;
  $("stat-frame").textContent = frame ? `#${frame.seq} · ${frame.phase.toFixed(2)} · ${frame.mode}` : "–";
  const defs = state.topology?.parameters ?? [];
  const line = [];
  for (const row of $("realised").querySelectorAll("tbody tr")) {
    const i = defs.findIndex((d) => d.name === row.dataset.name);
    if (i < 0) continue;
    const def = defs[i];
    row.querySelector(".target").textContent = formatValue(def, targets[def.name]);
    row.querySelector(".requested").textContent = frame ? formatValue(def, frame.requested[i]) : "–";
    row.querySelector(".realised").textContent = frame ? formatValue(def, frame.realised[i]) : "–";
    line.push(`${def.name.replace(/_/g, " ")} ${frame ? formatValue(def, frame.realised[i]) : "–"} ${def.unit}`);
  }
  // the compact box's one line: what the character realises, and how fast frames come
  $("status-line").textContent = `${line.join(" · ")}${line.length ? " · " : ""}${s.fps.toFixed(0)} fps`;
  $("clamped").hidden = !(frame && frame.clamped);
  const readout = $("heat-readout");
  readout.hidden = !(state.heatmap && frame && frame.error_max !== undefined && frame.error_max !== null);
  if (!readout.hidden && state.topology) {
    const pct = (100 * frame.error_max) / state.topology.model_size;
    readout.textContent = `max distance from non-linear: ${(frame.error_max * 1000).toFixed(2)} mm (${pct.toFixed(2)}% of model size)`;
  }
}
