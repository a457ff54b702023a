// The page: picks a motion space, streams it from /v1/stream, renders and steers it.
// The server blends; this file wires the panel, the connection, the viewer and the overlay.
import { api } from "./api.js";
import { PRESETS } from "./camera.js";
import { StreamConnection } from "./connection.js";
import { closeDialog, dialogOpen, setUpDialogs } from "./dialogs.js";
import { Comparison, setUpDownloads, shareLink, showHelp } from "./extras.js";
import { HeatmapControls } from "./heatmap.js";
import { JobsPanel } from "./jobs.js";
import { setUpDrawer, setUpStatusBox, setUpStick } from "./layout.js";
import { buildStatusRows, renderStatus, say } from "./overlay.js";
import { ParameterPanel, ParamSender, Steering } from "./params.js";
import { StreamStats } from "./stats.js";
import { Recorder } from "./recording.js";
import { readUrl, UrlWriter, viewUrl } from "./urlstate.js";
import { Viewer } from "./viewer.js";

const $ = (id) => document.getElementById(id);
const fromUrl = readUrl();

const state = {
  spaces: [],                 // GET /v1/spaces entries
  space: fromUrl.space,
  codec: fromUrl.codec ?? "q16",
  mode: fromUrl.mode ?? "hybrid",
  rate: fromUrl.rate || 60,
  smoothing: fromUrl.smoothing ?? 0.25,  // seconds (server-side)
  heatmap: fromUrl.heatmap,
  paused: false,
  targets: {},                // space -> {name: value} the user asked for
  urlParams: fromUrl.space ? fromUrl.params : {},  // the URL's parameter values, for its space
  camera: fromUrl.camera,     // a preset the user chose (else each space's default)
  topology: null,
  frame: null,                // newest frame received
  connection: "idle",
  notices: [],
  errors: [],
  resetPending: false,
  replays: 0,                 // one-shot clips replayed ("Replay clips when they end")
};

const stats = new StreamStats();
const viewer = new Viewer($("view"), fromUrl.lite === null ? {} : { lite: fromUrl.lite });
const comparison = new Comparison(null, viewer);
const url = new UrlWriter(() => ({
  space: state.space, mode: state.mode, heatmap: state.heatmap, camera: state.camera, trail: $("trail").checked,
  scale: heat.urlScale(), params: targets(),
}));
let pendingDraw = null;

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
    renderStatus(state, stats, viewer.framesDrawn, targets());
  },
  topology: onTopology,
  frame: (frame) => {
    if (!state.topology || state.topology.space !== state.space) return;  // an older hello's frames
    stats.frame(frame);
    state.frame = frame;
    heat.frame(frame);
    pendingDraw = frame;
    if (frame.finished && $("loop").checked && !state.resetPending && !state.paused) {
      state.resetPending = true;
      setTimeout(() => {
        if (!state.resetPending || state.paused) return;
        viewer.keepTrailOnce = true;  // the finished run's trail stays while the clip plays again
        state.replays += 1;
        connection.send("reset");
      }, 700);
    } else if (!frame.finished) {
      state.resetPending = false;
    }
  },
  pulled: (frame) => {
    stats.pulled(frame);
    comparison.pulled(frame);
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
comparison.connection = connection;

const sender = new ParamSender((params) => stats.sent(connection.send("params", { params })));

function targets() {
  return state.targets[state.space] || {};
}

function setTarget(name, value) {
  targets()[name] = value;
  panel.show(name, value);
  sender.queue(name, value);
  url.changed();
  recorder.changed(state.space, targets());
}

const panel = new ParameterPanel($("params"), (name, value) => {
  steering.sliderMoved(name);  // a turn set on its slider holds
  setTarget(name, value);
});
const steering = new Steering({ getTarget: (name) => targets()[name], setTarget });
steering.attach(window, { onPause: togglePause, onReset: userReset, onKey });

/** Page keys that are not parameters: ? help, C camera preset. Returns true when handled. */
function onKey(event) {
  if (event.key === "?") {
    if (dialogOpen()) closeDialog();
    else showHelp(steering, state.space);
    return true;
  }
  if (event.code === "KeyC" && !dialogOpen()) {
    setCamera(PRESETS[(PRESETS.indexOf(viewer.rig.preset) + 1) % PRESETS.length], true);
    say(`camera: ${viewer.rig.preset}`, "info", 1500, "camera");
    return true;
  }
  return false;
}

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
    const fromLink = name === fromUrl.space ? state.urlParams : {};
    state.targets[name] = Object.fromEntries(info.parameters.map((p) => {
      const asked = fromLink[p.name];
      return [p.name, Number.isFinite(asked) ? Math.min(p.max, Math.max(p.min, asked)) : p.default];
    }));
  }
  if (info) $("space-info").textContent = describeSpace(info);
  sender.clear();
  stats.reset();
  url.changed();
  if (connection.state === "idle") connection.start();
  else connection.sayHello();
}

$("space").addEventListener("change", (event) => {
  chooseSpace(event.target.value);
  event.target.blur();  // the arrow keys steer again (Tab comes back to the picker)
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
  $("steer-hint").textContent = hint ? `Keys: ${hint}. Space pauses, R resets, ? lists every key.` : "";
  const names = steering.keys().length ? [steering.forward, steering.turn].filter(Boolean).map((d) => d.name.replace(/_/g, " ")) : [];
  $("steer-keys").textContent = steering.centre ? "arrows / WASD: steer" : names.length ? `arrows / WASD: ${names.join(", ")}` : "";
  state.mode = topology.mode;
  buildModes(topology.modes);
  const info = state.spaces.find((s) => s.name === topology.space);
  if (info) $("space-info").textContent = describeSpace(info);
  buildStatusRows(defs);
  // each space's camera: chase for cyclic motion (walks), front for clips (jumps, reaches),
  // unless the user picked one
  if (!state.camera) setCamera(info && !info.cyclic ? "front" : "chase", false);
  if (state.paused) connection.send("pause");  // a new session (reconnect, new space) starts playing
  url.changed();
}

// ------------------------------------------------------------------ camera

function setCamera(preset, chosen) {
  viewer.setCameraPreset(preset);
  $("camera").value = preset;
  if (chosen) state.camera = preset;
  url.changed();
}

$("camera").addEventListener("change", (event) => setCamera(event.target.value, true));
viewer.rig.onChange = (preset) => setCamera(preset, true);  // dragged: free
if (state.camera) setCamera(state.camera, true);
$("follow").addEventListener("change", (event) => { viewer.rig.follow = event.target.checked; });

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
      url.changed();
      updateCompareLabels();
    });
    return label;
  }));
  updateCompareLabels();
}

const heat = new HeatmapControls(state, viewer, connection, url, fromUrl.scale);

function updateTrail() {
  viewer.setTrail($("trail").checked, Number($("trail-every").value) || 8, Number($("trail-count").value) || 12);
  url.changed();
}
$("trail").checked = fromUrl.trail;
for (const id of ["trail", "trail-every", "trail-count"]) $(id).addEventListener("change", updateTrail);
updateTrail();

// ------------------------------------------------------------------ playback

function togglePause() {
  state.paused = !state.paused;
  connection.send(state.paused ? "pause" : "resume");
  $("pause").textContent = state.paused ? "Resume" : "Pause";
}

function userReset() {
  state.resetPending = false;
  connection.send("reset");
  viewer.clearPath();
  viewer.clearTrail();
}

$("pause").addEventListener("click", togglePause);
$("reset").addEventListener("click", userReset);
$("clear-path").addEventListener("click", () => {
  viewer.clearPath();
  viewer.clearTrail();
});
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

// ------------------------------------------------------------------ toolbar: compare, share, help

function updateCompareLabels() {
  const name = (mode) => (mode === "nonlinear" ? "non-linear" : mode);
  $("compare-labels").hidden = !comparison.on;
  $("compare-left").textContent = name(state.mode);
  $("compare-right").textContent = name(comparison.mode);
}

$("compare").addEventListener("click", () => {
  comparison.set(!comparison.on);
  $("compare").setAttribute("aria-pressed", String(comparison.on));
  updateCompareLabels();
});
$("compare-mode").addEventListener("change", (event) => {
  comparison.mode = event.target.value;
  updateCompareLabels();
});
$("share").addEventListener("click", () => {
  url.flush();
  shareLink(viewUrl({ space: state.space, mode: state.mode, heatmap: state.heatmap, camera: viewer.rig.preset,
    trail: $("trail").checked, scale: heat.urlScale(), params: targets() }));
});
$("help-button").addEventListener("click", () => showHelp(steering, state.space));
setUpDialogs(["help-dialog", "share-dialog", "pictures-dialog"]);
const drawer = setUpDrawer();
setUpStatusBox();
setUpStick(steering, null);
const recorder = new Recorder(() => {
  const info = state.spaces.find((s) => s.name === state.space);
  return info && state.topology?.space === state.space ? { space: state.space, info, targets: targets(), mode: state.mode } : null;
}, say);
setUpDownloads(() => state.frame && state.topology && state.topology.space === state.space
  ? { space: state.space, defs: state.topology.parameters, frame: state.frame } : null);

// ------------------------------------------------------------------ loop

let lastTick = performance.now();
function animate(now) {
  const dt = Math.min(0.1, (now - lastTick) / 1000);
  lastTick = now;
  steering.tick(dt);
  if (pendingDraw) {
    viewer.showFrame(pendingDraw);
    comparison.drawn(pendingDraw, state.topology.parameters);
    pendingDraw = null;
  }
  viewer.render(dt);
  viewer.adapt(dt);
  requestAnimationFrame(animate);
}

// The state the overlay shows, for scripts and tests: window.morphspace.status().
window.morphspace = {
  state, stats, viewer, connection, drawer, comparison,
  status() {
    const frame = state.frame;
    const names = (state.topology?.parameters ?? []).map((p) => p.name);
    const pick = (values) => (frame ? Object.fromEntries(names.map((n, i) => [n, values[i]])) : null);
    return {
      connection: state.connection, reconnects: connection.reconnects, space: state.space, mode: state.mode,
      codec: state.codec, heatmap: state.heatmap, paused: state.paused, topologySpace: state.topology?.space ?? null,
      targets: { ...targets() }, requested: frame && pick(frame.requested), realised: frame && pick(frame.realised),
      frame: frame && { seq: frame.seq, ack: frame.ack, phase: frame.phase, mode: frame.mode, clamped: frame.clamped,
        root: frame.root, heading: frame.heading, errorMax: frame.error_max ?? null, time: frame.time,
        finished: frame.finished },
      stats: stats.snapshot(), framesDrawn: viewer.framesDrawn, errors: state.errors.map((e) => `${e.code}: ${e.message}`),
      spaces: state.spaces.map((s) => s.name), lastParamsSeq: connection.seq, replays: state.replays,
      camera: frame ? viewer.rig.describe(frame.root, frame.heading) : { preset: viewer.rig.preset },
      heatScale: viewer.heatmap.scale, compared: comparison.shown, drawnSeq: viewer.lastFrame?.seq ?? null,
    };
  },
};

setInterval(() => {
  renderStatus(state, stats, viewer.framesDrawn, targets());
  heat.tick();
}, 200);
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
