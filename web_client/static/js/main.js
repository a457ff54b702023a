// The page: picks a motion space (or a motion graph), streams it from /v1/stream, renders and
// steers it. The server blends; this file wires the panel, the connection, the viewer and the
// overlay. A graph is picked as "graph:NAME" (state.space); its actions come from keys (Space:
// jump, R: reach, 1-9: the nodes in order) and clicks on the diagram (graph.js).
import { api } from "./api.js";
import { PRESETS } from "./camera.js";
import { StreamConnection } from "./connection.js";
import { closeDialog, dialogOpen, setUpDialogs } from "./dialogs.js";
import { Comparison, setUpDownloads, shareLink, showHelp } from "./extras.js";
import { GraphView } from "./graph.js";
import { GRAPH, GraphPlay, graphDefs, graphName, keyOf } from "./graphplay.js";
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
  graphs: [],                 // GET /v1/graphs entries
  unreadable: [],             // both listings' unreadable entries: {name, error}
  action: null,               // the last action asked on a graph: {node, seq, sentAt, entered (s) or null}
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
const connection = new StreamConnection(wsUrl, () => state.space && graph.helloFields({
  codec: state.codec, rate: state.rate, mode: state.mode, smoothing: state.smoothing, window: FRAME_WINDOW }), {
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
    if (!state.topology || keyOf(state.topology) !== state.space) return;  // an older hello's frames
    stats.frame(frame);
    state.frame = frame;
    heat.frame(frame);
    pendingDraw = frame;
    if (state.topology.graph) {
      graph.frame(frame);
      recorder.frame(frame);
    } else if (frame.finished && $("loop").checked && !state.resetPending && !state.paused) {
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
    // steering can clamp 20 times a second; a graph's plans (planned, queued) are news, not warnings
    say(notice.message, notice.code === "clamped" ? "warn" : "info", 2500, `notice:${notice.code}`);
  },
  error: (error) => {
    state.errors.push(error);
    if (state.errors.length > 20) state.errors.shift();
    console.warn(`morphspace stream: ${error.code}: ${error.message}`);
    recorder.error(error);
    say(`${error.code}: ${error.message}`, "error", 6000, `error:${error.code}`);
  },
});
comparison.connection = connection;

const sender = new ParamSender((params) => {
  // on a graph, only the shown node's parameters go out (the others wait for its actions)
  const names = state.topology?.graph ? graph.shownNode()?.parameters.map((p) => p.name) ?? [] : null;
  const sent = names ? Object.fromEntries(Object.entries(params).filter(([name]) => names.includes(name))) : params;
  if (Object.keys(sent).length) stats.sent(connection.send("params", { params: sent }));
});

function targets() {
  return state.targets[state.space] || {};
}

function setTarget(name, value) {
  targets()[name] = value;
  panel.show(name, value);
  sender.queue(name, value);
  url.changed();
  if (!state.topology?.graph) recorder.changed(state.space, targets());
}

// ------------------------------------------------------------------ motion graphs

const graph = new GraphPlay(state, connection, {
  view: new GraphView($("graph-view"), (node) => graph.act(node)),
  targets, say, statusRows: buildStatusRows, sent: (seq) => stats.sent(seq), line: $("graph-state"),
});

const panel = new ParameterPanel($("params"), (name, value) => {
  steering.sliderMoved(name);  // a turn set on its slider holds
  setTarget(name, value);
});
const steering = new Steering({ getTarget: (name) => targets()[name], setTarget });
steering.attach(window, { onPause: togglePause, onReset: userReset, onKey });

/** Page keys that are not parameters: ? help, C camera preset, a graph's actions. Returns true when handled. */
function onKey(event) {
  if (event.key === "?") {
    if (dialogOpen()) closeDialog();
    else help();
    return true;
  }
  if (state.topology?.graph && !dialogOpen() && !event.repeat) {
    const node = graph.actionKey(event);
    if (node) return graph.act(node);
    if (event.code === "KeyP") {
      togglePause();
      return true;
    }
    if (event.code === "Space" || event.code === "KeyR") return true;  // no such node: nothing
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

function describeGraph(graph) {
  return `motion graph · ${graph.nodes.length} nodes (${graph.nodes.map((n) => n.name).join(", ")}) · ` +
    `${graph.edges.length} transitions · ${graph.n_vertices.toLocaleString()} vertices`;
}

function fillPicker() {
  const select = $("space");
  const names = [...state.spaces.map((s) => s.name), ...state.graphs.map((g) => GRAPH + g.name),
    ...state.unreadable.map((bad) => `unreadable:${bad.name}`)];
  const current = [...select.querySelectorAll("option")].map((o) => o.value);
  if (current.join("\n") !== names.join("\n")) {
    const options = state.spaces.map((s) => {
      const option = new Option(s.playable ? s.name : `${s.name} (not playable)`, s.name);
      option.disabled = !s.playable;
      return option;
    });
    const group = document.createElement("optgroup");
    group.label = "motion graphs";
    group.append(...state.graphs.map((g) => new Option(`${g.name} (graph)`, GRAPH + g.name)));
    // what the server lists as unreadable: shown, not choosable, the reason on hover
    const broken = state.unreadable.map((bad) => {
      const option = new Option(`${bad.name} (unreadable)`, `unreadable:${bad.name}`);
      option.disabled = true;
      option.title = bad.error;
      return option;
    });
    select.replaceChildren(...options, ...(state.graphs.length ? [group] : []), ...broken);
  }
  if (state.space) select.value = state.space;
}

const reported = new Set();
let listingError = null;  // why the last listing of spaces and graphs failed (null: it did not)
let askedReported = false;  // the URL's space, when unknown, is reported once
async function refreshSpaces() {
  try {
    const [listing, graphs] = await Promise.all([api.spaces(), api.graphs()]);
    state.spaces = listing.spaces;
    state.graphs = graphs.graphs;
    state.unreadable = [...(listing.unreadable || []), ...(graphs.unreadable || [])];
    for (const bad of state.unreadable) {
      if (!reported.has(bad.name)) console.info(`morphspace: ${bad.name} is unreadable: ${bad.error}`);
      reported.add(bad.name);
    }
  } catch (err) {
    listingError = err;
    return false;
  }
  listingError = null;
  const playable = state.spaces.filter((s) => s.playable);
  const known = graphName(state.space) ? state.graphs.some((g) => g.name === graphName(state.space))
    : playable.some((s) => s.name === state.space);
  if (!state.space || !known) {
    const preferred = playable.find((s) => s.name === "locomotion") ?? playable[0];
    if (state.space && !askedReported && preferred) {  // the URL named something this server cannot play
      const name = graphName(state.space) ?? state.space;
      const bad = state.unreadable.find((b) => b.name === name);
      const why = bad ? `unreadable (${bad.error})` : state.spaces.some((s) => s.name === name) ? "not playable"
        : `not on this server`;
      say(`${graphName(state.space) ? "graph" : "space"} "${name}" is ${why}; showing ${preferred.name}`, "error", 10000);
    }
    askedReported = true;
    if (preferred) chooseSpace(preferred.name);
  } else if (connection.state === "idle") {
    chooseSpace(state.space);  // named in the URL
  }
  fillPicker();
  return true;
}

function chooseSpace(name) {
  recorder.spaceChosen(name);  // a recording of another space ends here
  const chosen = state.graphs.find((g) => g.name === graphName(name));
  const info = chosen ? null : state.spaces.find((s) => s.name === name);
  state.space = name;
  const defs = chosen ? graphDefs(chosen) : info?.parameters;
  if (!state.targets[name] && defs) {
    const fromLink = name === fromUrl.space ? state.urlParams : {};
    state.targets[name] = Object.fromEntries(defs.map((p) => {
      const asked = fromLink[p.name];
      return [p.name, Number.isFinite(asked) ? Math.min(p.max, Math.max(p.min, asked)) : p.default];
    }));
  }
  if (info) $("space-info").textContent = describeSpace(info);
  if (chosen) $("space-info").textContent = describeGraph(chosen);
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
  if (keyOf(topology) !== state.space) return;  // an older hello's answer
  viewer.setTopology(topology);
  const isGraph = Boolean(topology.graph);
  const defs = isGraph ? graphDefs(topology) : topology.parameters;
  const mine = targets();
  for (const def of defs) if (!(def.name in mine)) mine[def.name] = def.value;
  state.targets[state.space] = mine;
  panel.build(defs, mine);
  // on a graph the arrows steer the cyclic nodes' parameters (the walk's speed and turn)
  const cyclic = new Set((topology.nodes ?? []).filter((n) => n.cyclic).map((n) => n.name));
  const hint = steering.configure(isGraph ? defs.filter((d) => d.nodes.some((n) => cyclic.has(n))) : defs);
  $("steer-hint").textContent = isGraph ? `Keys: ${hint ? `${hint}; ` : ""}Space: jump, R: reach, 1–9: go to a node ` +
    "(or click it), P pauses, ? lists every key." : hint ? `Keys: ${hint}. Space pauses, R resets, ? lists every key.` : "";
  graph.topology(topology);
  $("graph-section").hidden = !isGraph;
  for (const id of ["heatmap", "compare"]) $(id).disabled = isGraph;  // pulls and heatmaps are for spaces
  if (isGraph && comparison.on) $("compare").click();
  heat.forGraph(isGraph);
  const names = steering.keys().length ? [steering.forward, steering.turn].filter(Boolean).map((d) => d.name.replace(/_/g, " ")) : [];
  $("steer-keys").textContent = steering.centre ? "arrows / WASD: steer" : names.length ? `arrows / WASD: ${names.join(", ")}` : "";
  state.mode = topology.mode;
  buildModes(topology.modes);
  const info = isGraph ? null : state.spaces.find((s) => s.name === topology.space);
  if (info) $("space-info").textContent = describeSpace(info);
  buildStatusRows(topology.parameters);
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
  viewer.keepTrailOnce = false;  // a replay the page had just asked for is overtaken: clear as a reset
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
function help() {
  const nodes = state.topology?.graph ? state.topology.nodes : null;
  const graphKeys = nodes && [
    { keys: "Space", what: "jump (at the jump sliders)" }, { keys: "R", what: "reach (at the reach slider)" },
    { keys: `1–${Math.min(9, nodes.length)}`, what: `go to ${nodes.slice(0, 9).map((n) => n.name).join(", ")}` },
    { keys: "P", what: "pause / resume" }];
  showHelp(steering, state.space, graphKeys);
}
$("help-button").addEventListener("click", help);
setUpDialogs(["help-dialog", "share-dialog", "pictures-dialog"]);
const drawer = setUpDrawer();
setUpStatusBox();
setUpStick(steering, null);
const recorder = new Recorder(() => {
  const info = state.spaces.find((s) => s.name === state.space);
  return info && keyOf(state.topology) === state.space ? { space: state.space, info, targets: targets(), mode: state.mode } : null;
}, say, () => {  // on a graph stream: the graph recorded (recording_graph.js)
  const info = state.topology?.graph && keyOf(state.topology) === state.space
    ? state.graphs.find((g) => g.name === state.topology.graph) : null;
  const start = info && graph.nodeInfo(info.start);
  return info ? { info, mode: state.mode, rate: state.rate, params: start ? graph.paramsOf(start) : undefined } : null;
});
recorder.watch(connection);
setUpDownloads(() => {  // the frame on screen from its space; on a graph, from the space of the node shown
  if (!state.frame || !state.topology || keyOf(state.topology) !== state.space) return null;
  if (!state.topology.graph) return { space: state.space, name: state.space, defs: state.topology.parameters, frame: state.frame };
  const node = state.topology.nodes.find((n) => n.name === state.frame.node);
  return node ? { space: node.space, name: `${state.topology.graph}-${node.name}`, defs: node.parameters, frame: state.frame }
    : null;
});

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
      codec: state.codec, heatmap: state.heatmap, paused: state.paused, topologySpace: keyOf(state.topology),
      targets: { ...targets() }, requested: frame && pick(frame.requested), realised: frame && pick(frame.realised),
      frame: frame && { seq: frame.seq, ack: frame.ack, phase: frame.phase, mode: frame.mode, clamped: frame.clamped,
        root: frame.root, heading: frame.heading, errorMax: frame.error_max ?? null, time: frame.time,
        finished: frame.finished, node: frame.node ?? null, target: frame.target ?? null,
        progress: frame.progress ?? null },
      graph: state.topology?.graph ?? null, graphs: state.graphs.map((g) => g.name),
      action: state.action && { ...state.action }, shownParameters: (state.topology?.parameters ?? []).map((p) => p.name),
      stats: stats.snapshot(), framesDrawn: viewer.framesDrawn, errors: state.errors.map((e) => `${e.code}: ${e.message}`),
      spaces: state.spaces.map((s) => s.name), lastParamsSeq: connection.seq, replays: state.replays,
      recording: recorder.describe(),
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
    // said again at every failed retry (the same key replaces it), with the server's reason
    const tell = () => say(`Cannot list the server's motion spaces (${listingError?.message || listingError}); `
      + "retrying every second…", "error", 1500, "listing");
    tell();
    const retry = setInterval(async () => {
      if (await refreshSpaces()) {
        clearInterval(retry);
        say("The server's motion spaces are listed again.", "info", 4000, "listing");
        if (!state.space) say("No playable motion space on this server yet: build one (Jobs panel).", "warn", 10000);
      } else {
        tell();
      }
    }, 1000);
  }
  if (ok && !state.space) say("No playable motion space on this server yet: build one (Jobs panel).", "warn", 10000);
});
