// The page: picks a motion space, streams it from /v1/stream, renders and steers it.
// The server blends; this file wires the panel, the connection, the viewer and the overlay.
import { MODES, CODECS } from "../protocol.js";
import { api } from "./api.js";
import { cssGradient } from "./colormap.js";
import { StreamConnection } from "./connection.js";
import { JobsPanel } from "./jobs.js";
import { ParameterPanel, ParamSender, Steering, formatValue } from "./params.js";
import { StreamStats } from "./stats.js";
import { Viewer } from "./viewer.js";

const $ = (id) => document.getElementById(id);
const query = new URLSearchParams(location.search);

const state = {
  spaces: [],                 // GET /v1/spaces entries
  space: query.get("space") || null,
  codec: CODECS.includes(query.get("codec")) ? query.get("codec") : "q16",
  mode: MODES.includes(query.get("mode")) ? query.get("mode") : "hybrid",
  rate: Number(query.get("rate")) || 60,
  smoothing: query.has("smoothing") ? Number(query.get("smoothing")) : 0.25,  // seconds (server-side)
  heatmap: false,
  paused: false,
  targets: {},                // space -> {name: value} the user asked for
  topology: null,
  frame: null,                // newest frame received
  connection: "idle",
  notices: [],
  errors: [],
  resetPending: false,
};

const stats = new StreamStats();
const viewer = new Viewer($("view"), query.has("lite") ? { lite: query.get("lite") === "1" } : {});
let pendingDraw = null;

// ------------------------------------------------------------------ messages to the user

/** A message top right for `ms`; one with the same `key` (default: the text) replaces it. */
function say(text, kind = "info", ms = 4000, key = text) {
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

// ------------------------------------------------------------------ connection

const FRAME_WINDOW = 3;  // frames the server may have in flight before our ack (see connection.js)
const wsUrl = `${location.protocol === "https:" ? "wss:" : "ws:"}//${location.host}/v1/stream`;
const connection = new StreamConnection(wsUrl, () => state.space && {
  space: state.space, codec: state.codec, rate: state.rate, mode: state.mode, heatmap: state.heatmap,
  params: state.targets[state.space], smoothing: state.smoothing, window: FRAME_WINDOW,
}, {
  state: (s) => {
    state.connection = s;
    if (s === "open") {
      stats.reset();
      refreshSpaces();
    }
    renderStatus();
  },
  topology: onTopology,
  frame: (frame) => {
    if (!state.topology || state.topology.space !== state.space) return;  // an older hello's frames
    stats.frame(frame);
    state.frame = frame;
    if (frame.error_max !== undefined && frame.error_max !== null && $("heat-auto").checked) {
      autoMax = Math.max(frame.error_max, autoMax * 0.98);
      viewer.heatmap.scale = heatScale();
    }
    pendingDraw = frame;
    if (frame.finished && $("loop").checked && !state.resetPending && !state.paused) {
      state.resetPending = true;
      setTimeout(() => connection.send("reset"), 700);
    } else if (!frame.finished) {
      state.resetPending = false;
    }
  },
  notice: (notice) => {
    if (notice.code === "space_changed") connection.sayHello();  // the file was rebuilt: new topology
    state.notices.push(notice);
    if (state.notices.length > 20) state.notices.shift();
    say(notice.message, "warn", 2500, `notice:${notice.code}`);  // steering can clamp 20 times a second
  },
  error: (error) => {
    state.errors.push(error);
    if (state.errors.length > 20) state.errors.shift();
    console.warn(`morphspace stream: ${error.code}: ${error.message}`);
    say(`${error.code}: ${error.message}`, "error", 6000, `error:${error.code}`);
  },
});

const sender = new ParamSender((params) => stats.sent(connection.send("params", { params })));

function targets() {
  return state.targets[state.space] || {};
}

function setTarget(name, value) {
  targets()[name] = value;
  panel.show(name, value);
  sender.queue(name, value);
}

const panel = new ParameterPanel($("params"), setTarget);
const steering = new Steering({ getTarget: (name) => targets()[name], setTarget });
steering.attach(window, { onPause: togglePause, onReset: () => connection.send("reset") });

// ------------------------------------------------------------------ spaces

function describeSpace(space) {
  const sources = space.sources.map((s) => `${s.name} (${s.duration.toFixed(2)} s)`).join(", ");
  return `${space.n_vertices.toLocaleString()} vertices · ${space.cyclic ? "cyclic" : "one-shot clip"} · ` +
    `${space.layout ?? "no"} layout · hybrid ε ${(space.epsilon * 1000).toFixed(1)} mm · sources: ${sources}`;
}

function fillPicker() {
  const select = $("space");
  const names = state.spaces.map((s) => s.name);
  const current = [...select.options].map((o) => o.value);
  if (current.join("\n") !== names.join("\n")) {
    select.replaceChildren(...state.spaces.map((s) => {
      const option = new Option(s.playable ? s.name : `${s.name} (not playable)`, s.name);
      option.disabled = !s.playable;
      return option;
    }));
  }
  if (state.space) select.value = state.space;
}

const reported = new Set();
async function refreshSpaces() {
  try {
    const listing = await api.spaces();
    state.spaces = listing.spaces;
    for (const bad of listing.unreadable || []) {
      if (!reported.has(bad.name)) console.info(`morphspace: ${bad.name} is unreadable: ${bad.error}`);
      reported.add(bad.name);
    }
  } catch (err) {
    return false;
  }
  const playable = state.spaces.filter((s) => s.playable);
  if (!state.space || !playable.some((s) => s.name === state.space)) {
    const preferred = playable.find((s) => s.name === "locomotion") ?? playable[0];
    if (preferred) chooseSpace(preferred.name);
  } else if (connection.state === "idle") {
    chooseSpace(state.space);  // named in the URL
  }
  fillPicker();
  return true;
}

function chooseSpace(name) {
  const info = state.spaces.find((s) => s.name === name);
  state.space = name;
  if (!state.targets[name] && info) {
    state.targets[name] = Object.fromEntries(info.parameters.map((p) => [p.name, p.default]));
  }
  const url = new URL(location.href);
  url.searchParams.set("space", name);
  history.replaceState(null, "", url);
  if (info) $("space-info").textContent = describeSpace(info);
  sender.clear();
  stats.reset();
  if (connection.state === "idle") connection.start();
  else connection.sayHello();
}

$("space").addEventListener("change", (event) => {
  chooseSpace(event.target.value);
  event.target.blur();
});

function onTopology(topology) {
  state.topology = topology;
  state.frame = null;
  pendingDraw = null;
  stats.reset();
  if (topology.space !== state.space) return;  // an older hello's answer
  viewer.setTopology(topology);
  const defs = topology.parameters;
  const mine = targets();
  for (const def of defs) if (!(def.name in mine)) mine[def.name] = def.value;
  state.targets[state.space] = mine;
  panel.build(defs, mine);
  const hint = steering.configure(defs);
  $("steer-hint").textContent = hint ? `Keys: ${hint}. Space pauses, R resets.` : "";
  $("steer-keys").textContent = hint ? "arrows / WASD: steer" : "";
  state.mode = topology.mode;
  buildModes(topology.modes);
  const info = state.spaces.find((s) => s.name === topology.space);
  if (info) $("space-info").textContent = describeSpace(info);
  buildStatusRows(defs);
  if (state.paused) connection.send("pause");  // a new session (reconnect, new space) starts playing
}

// ------------------------------------------------------------------ blend mode, heatmap, trail

function buildModes(modes) {
  const box = $("modes");
  box.replaceChildren(...modes.map((mode) => {
    const label = document.createElement("label");
    label.innerHTML = `<input type="radio" name="mode" value="${mode}"> ${mode === "nonlinear" ? "non-linear" : mode}`;
    const input = label.querySelector("input");
    input.checked = mode === state.mode;
    input.addEventListener("change", () => {
      state.mode = mode;
      connection.send("mode", { mode });
    });
    return label;
  }));
}

let autoMax = 0;  // metres: a slowly decaying maximum of the frames' error_max (auto scale)

function heatScale() {
  if ($("heat-auto").checked) return Math.max(autoMax, 1e-4);
  const mm = Number($("heat-scale").value);
  return (Number.isFinite(mm) && mm > 0 ? mm : 20) / 1000;
}

function updateLegend() {
  const legend = $("legend");
  legend.hidden = !state.heatmap;
  legend.querySelector(".legend-bar").style.background = cssGradient();
  const mm = heatScale() * 1000;
  $("heat-scale").disabled = $("heat-auto").checked;
  $("legend-mid").textContent = `${(mm / 2).toPrecision(3)} mm`;
  $("legend-max").textContent = `≥ ${mm.toPrecision(3)} mm`;
}

$("heatmap").addEventListener("change", (event) => {
  state.heatmap = event.target.checked;
  viewer.setHeatmap(state.heatmap, heatScale());
  connection.send("heatmap", { on: state.heatmap });
  updateLegend();
});
for (const id of ["heat-scale", "heat-auto"]) {
  $(id).addEventListener("input", () => {
    autoMax = 0;
    viewer.setHeatmap(state.heatmap, heatScale());
    updateLegend();
  });
}

function updateTrail() {
  viewer.setTrail($("trail").checked, Number($("trail-every").value) || 8, Number($("trail-count").value) || 12);
}
for (const id of ["trail", "trail-every", "trail-count"]) $(id).addEventListener("change", updateTrail);

// ------------------------------------------------------------------ playback

function togglePause() {
  state.paused = !state.paused;
  connection.send(state.paused ? "pause" : "resume");
  $("pause").textContent = state.paused ? "Resume" : "Pause";
}

$("pause").addEventListener("click", togglePause);
$("reset").addEventListener("click", () => {
  connection.send("reset");
  viewer.clearPath();
  viewer.clearTrail();
});
$("clear-path").addEventListener("click", () => {
  viewer.clearPath();
  viewer.clearTrail();
});
$("follow").addEventListener("change", (event) => { viewer.follow = event.target.checked; });
$("codec").value = state.codec;
$("codec").addEventListener("change", (event) => {
  state.codec = event.target.value;
  connection.sayHello();
});
$("rate").value = String(state.rate);
$("rate").addEventListener("change", (event) => {
  state.rate = Number(event.target.value);
  connection.send("rate", { rate: state.rate });
});

// ------------------------------------------------------------------ status overlay

function buildStatusRows(defs) {
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

function renderStatus() {
  const pill = $("conn");
  const labels = { open: "live", connecting: "connecting", reconnecting: "reconnecting…", idle: "no stream" };
  pill.textContent = labels[state.connection] ?? state.connection;
  pill.className = `pill ${state.connection}`;
  $("status-space").textContent = state.space ? `${state.space} · ${state.codec}` : "no playable space";
  const s = stats.snapshot();
  $("stat-fps").textContent = state.paused ? `${s.fps.toFixed(0)} (paused)` : s.fps.toFixed(0);
  const lat = s.latency;
  $("stat-latency").textContent = lat.n ? `${ms(lat.last)} (median ${ms(lat.median)}, p95 ${ms(lat.p95)})` : "–";
  $("stat-dropped").textContent = `${s.dropped} / ${s.gaps} / ${Math.max(0, s.framesTotal - viewer.framesDrawn)}`;
  const frame = state.frame;
  $("stat-frame").textContent = frame ? `#${frame.seq} · ${frame.phase.toFixed(2)} · ${frame.mode}` : "–";
  const defs = state.topology?.parameters ?? [];
  for (const row of $("realised").querySelectorAll("tbody tr")) {
    const i = defs.findIndex((d) => d.name === row.dataset.name);
    if (i < 0) continue;
    const def = defs[i];
    row.querySelector(".target").textContent = formatValue(def, targets()[def.name]);
    row.querySelector(".requested").textContent = frame ? formatValue(def, frame.requested[i]) : "–";
    row.querySelector(".realised").textContent = frame ? formatValue(def, frame.realised[i]) : "–";
  }
  $("clamped").hidden = !(frame && frame.clamped);
  if (state.heatmap && $("heat-auto").checked) updateLegend();
  const readout = $("heat-readout");
  readout.hidden = !(state.heatmap && frame && frame.error_max !== undefined && frame.error_max !== null);
  if (!readout.hidden && state.topology) {
    const pct = (100 * frame.error_max) / state.topology.model_size;
    readout.textContent = `max distance from non-linear: ${(frame.error_max * 1000).toFixed(2)} mm (${pct.toFixed(2)}% of model size)`;
  }
}

// ------------------------------------------------------------------ loop

let lastTick = performance.now();
function animate(now) {
  const dt = Math.min(0.1, (now - lastTick) / 1000);
  lastTick = now;
  steering.tick(dt);
  if (pendingDraw) {
    viewer.showFrame(pendingDraw);
    pendingDraw = null;
  }
  viewer.render(dt);
  viewer.adapt(dt);
  requestAnimationFrame(animate);
}

// The state the overlay shows, for scripts and tests: window.morphspace.status().
window.morphspace = {
  state, stats, viewer, connection,
  status() {
    const frame = state.frame;
    const names = (state.topology?.parameters ?? []).map((p) => p.name);
    const pick = (values) => (frame ? Object.fromEntries(names.map((n, i) => [n, values[i]])) : null);
    return {
      connection: state.connection, reconnects: connection.reconnects, space: state.space, mode: state.mode,
      codec: state.codec, heatmap: state.heatmap, paused: state.paused, topologySpace: state.topology?.space ?? null,
      targets: { ...targets() }, requested: frame && pick(frame.requested), realised: frame && pick(frame.realised),
      frame: frame && { seq: frame.seq, ack: frame.ack, phase: frame.phase, mode: frame.mode, clamped: frame.clamped,
        root: frame.root, heading: frame.heading, errorMax: frame.error_max ?? null },
      stats: stats.snapshot(), framesDrawn: viewer.framesDrawn, errors: state.errors.map((e) => `${e.code}: ${e.message}`),
      spaces: state.spaces.map((s) => s.name), lastParamsSeq: connection.seq,
    };
  },
};

updateLegend();
setInterval(renderStatus, 200);
setInterval(() => { if (connection.open) refreshSpaces(); }, 10000);
new JobsPanel({ onSpaceReady: async (name, select) => {
  await refreshSpaces();
  if (!state.spaces.some((s) => s.name === name && s.playable)) return;
  if (select || !state.space) {
    chooseSpace(name);
    fillPicker();
    say(`New motion space ${name} is ready and selected.`, "info", 6000);
  } else {
    say(`New motion space ${name} is ready: pick it above.`, "info", 8000);
  }
}, say }).start();
requestAnimationFrame(animate);
refreshSpaces().then((ok) => {
  if (!ok) {
    say("Cannot reach the server's REST API; retrying…", "error");
    const retry = setInterval(async () => { if (await refreshSpaces()) clearInterval(retry); }, 1000);
  }
  if (!state.space) say("No playable motion space on this server yet: build one (Jobs panel).", "warn", 10000);
});
