// Clip and performance downloads through POST /v1/spaces/{name}/export (docs/rest.md, Exports):
// a clip at the current parameters, or a recording of what the user steers (the targets as a
// track of timed requests) from Record to Stop, both as animated binary glTF at 30 frames/s.
// On a motion graph, Record records the session itself (GraphRecording, recording_graph.js): the
// requests sent and the stream's frame clock, downloaded as a graph recording (JSON) and its
// export (POST /v1/graphs/{name}/export).
import { GraphRecording } from "./recording_graph.js";

const $ = (id) => document.getElementById(id);

const RATE = 30;
const CLIP_SECONDS = 2;           // a cyclic space's clip (a one-shot space: its longest source)
const SYNC_VERTEX_FRAMES = 1e6;   // the server's default limit for an export answered at once
const MAX_REQUESTS = 1000;        // the export's track limit
const MERGE_S = 0.1;              // requests closer than this are one (the newest)

export class Recorder {
  /** current(): {space, info (GET /v1/spaces entry), targets, mode} or null; say(text, kind). */
  constructor(current, say, graphNow = () => null) {
    this.current = current;
    this.say = say;
    this.graphNow = graphNow;  // () => {info (GET /v1/graphs entry), mode, rate, params (the start node's
                               // sliders)} on a graph stream, else null
    this.recording = null;  // {space, start, params, track, limit}, or a GraphRecording
    this.downloads = 0;
    this.hello = null;      // the fields of the last hello sent (a graph recording starts from them)
    $("download-clip").addEventListener("click", () => this.clip());
    $("record").addEventListener("click", () => (this.recording ? this.stop() : this.start()));
  }

  /** What is being recorded, for status(): null, {kind: "space", space} or {kind: "graph", resetSeq,
   * firstSeq (the first frame after the reset, null until it comes), steps}. */
  describe() {
    const rec = this.recording;
    if (!rec) return null;
    if (!(rec instanceof GraphRecording)) return { kind: "space", space: rec.space };
    return { kind: "graph", resetSeq: rec.resetSeq, firstSeq: rec.firstSeq, steps: rec.times.length - 1 };
  }

  /** See every message the page sends on ``connection`` (a graph recording keeps its requests). */
  watch(connection) {
    const send = connection.send.bind(connection);
    this.rawSend = send;
    this.connection = connection;
    connection.send = (type, fields = {}) => {
      const seq = send(type, fields);
      if (type === "hello") this.hello = { ...fields };
      if (this.recording instanceof GraphRecording) {
        const why = this.recording.sent(type, fields, seq);
        if (why) this.stop(why);
      }
      return seq;
    };
  }

  /** A streamed frame (a graph recording follows the stream's clock). */
  frame(frame) {
    if (!(this.recording instanceof GraphRecording)) return;
    const why = this.recording.frame(frame);
    if (why) this.stop(why);
  }

  /** An error message from the server: a recorded request it refused is dropped. */
  error(error) {
    if (this.recording instanceof GraphRecording) this.recording.refused(error.seq);
  }

  /** The longest clip the server writes at once for this space, in seconds. */
  static limitSeconds(info) {
    return Math.floor(SYNC_VERTEX_FRAMES / info.n_vertices / RATE) - 1;
  }

  clip() {
    const now = this.current();
    if (!now) return;
    const longest = Math.max(...now.info.sources.map((s) => s.duration));
    const duration = now.info.cyclic ? CLIP_SECONDS : Math.min(longest, Recorder.limitSeconds(now.info));
    this.download(now.space, { format: "glb", params: { ...now.targets }, duration, rate: RATE, mode: now.mode },
      `${now.space}-clip.glb`);
  }

  start() {
    const graph = this.graphNow();
    if (graph) return this.startGraph(graph);
    const now = this.current();
    if (!now) return;
    this.recording = { space: now.space, mode: now.mode, start: performance.now(), params: { ...now.targets }, track: [],
      limit: Recorder.limitSeconds(now.info) };
    this.timer = setInterval(() => this.tick(), 250);
    $("record").textContent = "Stop (0 s)";
    $("record").setAttribute("aria-pressed", "true");
    this.say(`Recording ${now.space}: steer, then Stop to download it (at most ${this.recording.limit} s).`, "info", 5000);
  }

  /** The page switched to ``name`` (a space or a graph): a space's recording ends there (a graph's ends
   * when the stream starts again: GraphRecording.sent). */
  spaceChosen(name) {
    const rec = this.recording;
    if (rec && !(rec instanceof GraphRecording) && rec.space !== name) this.stop();
  }

  /** The targets changed (sliders, keys, stick): a timed request in the recording. */
  changed(space, targets) {
    const rec = this.recording;
    if (!rec) return;
    if (space !== rec.space) return this.stop();  // another space: the recording ends there
    const time = (performance.now() - rec.start) / 1000;
    const last = rec.track.at(-1);
    if (last && time - last.time < MERGE_S) last.params = { ...targets };
    else rec.track.push({ time, params: { ...targets } });
    if (rec.track.length >= MAX_REQUESTS) this.stop();
  }

  tick() {
    const rec = this.recording;
    if (!rec) return;
    const seconds = rec instanceof GraphRecording ? rec.seconds() : (performance.now() - rec.start) / 1000;
    if (rec instanceof GraphRecording) {
      $("record").textContent = `Stop (${seconds.toFixed(0)} s)`;
      return;
    }
    $("record").textContent = `Stop (${seconds.toFixed(0)} s)`;
    if (seconds >= rec.limit) this.stop();
  }

  /** Record a graph session: the stream restarts at its start node (a reset) and every request
   * from now on is kept with the frame it was applied at. */
  startGraph(now) {
    const limit = Math.floor(SYNC_VERTEX_FRAMES / now.info.n_vertices) - 1;
    this.recording = new GraphRecording(now.info, this.hello?.params, now.mode, now.rate, limit);
    this.recording.resetSeq = this.rawSend("reset");
    // the reset goes back to the hello's start parameters: the start node's sliders now, recorded
    if (now.params) this.connection.send("params", { params: now.params });
    this.timer = setInterval(() => this.tick(), 250);
    $("record").textContent = "Stop (0 s)";
    $("record").setAttribute("aria-pressed", "true");
    this.say(`Recording ${now.info.name} from its start (${now.info.start}): act, then Stop to download the ` +
      `recording and its glTF (at most ${limit} frames).`, "info", 5000);
  }

  stop(why) {
    const rec = this.recording;
    if (!rec) return;
    this.recording = null;
    clearInterval(this.timer);
    $("record").textContent = "Record";
    $("record").setAttribute("aria-pressed", "false");
    if (rec instanceof GraphRecording) return this.stopGraph(rec, why);
    const duration = Math.max(1 / RATE, Math.min(rec.limit, (performance.now() - rec.start) / 1000));
    const track = rec.track.filter((r) => r.time <= duration).map((r) => ({ time: Number(r.time.toFixed(3)), params: r.params }));
    this.download(rec.space, { format: "glb", params: rec.params, track, duration: Number(duration.toFixed(3)), rate: RATE,
      mode: rec.mode }, `${rec.space}-recording.glb`);
  }

  /** The graph recording as JSON, and its export as glTF (when it has frames). */
  async stopGraph(rec, why) {
    const document_ = rec.document();
    if (why) this.say(`Recording stopped: ${why}.`, "info", 5000, "record");
    if (!document_) return this.say("Nothing recorded: no frame came after Record.", "warn", 5000, "record");
    const name = rec.info.name;
    this.save(new Blob([JSON.stringify(document_, null, 1)], { type: "application/json" }), `${name}-recording.json`);
    this.lastRecording = document_;
    await this.download(name, { format: "glb", recording: document_ }, `${name}-performance.glb`,
      `/v1/graphs/${encodeURIComponent(name)}/export`);
  }

  save(blob, name) {
    const link = Object.assign(document.createElement("a"), { href: URL.createObjectURL(blob), download: name });
    document.body.append(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(link.href), 60000);
  }

  async download(space, body, name, url = `/v1/spaces/${encodeURIComponent(space)}/export`) {
    this.say(`Exporting ${name}…`, "info", 3000, "export");
    try {
      const response = await fetch(url, {
        method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
      if (!response.ok) {
        let detail = `HTTP ${response.status}`;
        try { detail = (await response.json()).detail ?? detail; } catch { /* not JSON */ }
        this.say(`Export failed: ${typeof detail === "string" ? detail : JSON.stringify(detail)}`, "error", 10000, "export");
        return;
      }
      this.save(await response.blob(), name);
      this.downloads += 1;
      this.say(`${name}: ${response.headers.get("X-Morphspace-Frames") ?? "?"} frames.`, "info", 4000, "export");
    } catch (err) {
      this.say(`Export failed: ${err.message}`, "error", 10000, "export");
    }
  }
}
