// Clip and performance downloads through POST /v1/spaces/{name}/export (docs/rest.md, Exports):
// a clip at the current parameters, or a recording of what the user steers (the targets as a
// track of timed requests) from Record to Stop, both as animated binary glTF at 30 frames/s.
const $ = (id) => document.getElementById(id);

const RATE = 30;
const CLIP_SECONDS = 2;           // a cyclic space's clip (a one-shot space: its longest source)
const SYNC_VERTEX_FRAMES = 1e6;   // the server's default limit for an export answered at once
const MAX_REQUESTS = 1000;        // the export's track limit
const MERGE_S = 0.1;              // requests closer than this are one (the newest)

export class Recorder {
  /** current(): {space, info (GET /v1/spaces entry), targets, mode} or null; say(text, kind). */
  constructor(current, say) {
    this.current = current;
    this.say = say;
    this.recording = null;  // {space, start, params, track, limit}
    this.downloads = 0;
    $("download-clip").addEventListener("click", () => this.clip());
    $("record").addEventListener("click", () => (this.recording ? this.stop() : this.start()));
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
    const now = this.current();
    if (!now) return;
    this.recording = { space: now.space, mode: now.mode, start: performance.now(), params: { ...now.targets }, track: [],
      limit: Recorder.limitSeconds(now.info) };
    this.timer = setInterval(() => this.tick(), 250);
    $("record").textContent = "Stop (0 s)";
    $("record").setAttribute("aria-pressed", "true");
    this.say(`Recording ${now.space}: steer, then Stop to download it (at most ${this.recording.limit} s).`, "info", 5000);
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
    const seconds = (performance.now() - rec.start) / 1000;
    $("record").textContent = `Stop (${seconds.toFixed(0)} s)`;
    if (seconds >= rec.limit) this.stop();
  }

  stop() {
    const rec = this.recording;
    if (!rec) return;
    this.recording = null;
    clearInterval(this.timer);
    $("record").textContent = "Record";
    $("record").setAttribute("aria-pressed", "false");
    const duration = Math.max(1 / RATE, Math.min(rec.limit, (performance.now() - rec.start) / 1000));
    const track = rec.track.filter((r) => r.time <= duration).map((r) => ({ time: Number(r.time.toFixed(3)), params: r.params }));
    this.download(rec.space, { format: "glb", params: rec.params, track, duration: Number(duration.toFixed(3)), rate: RATE,
      mode: rec.mode }, `${rec.space}-recording.glb`);
  }

  async download(space, body, name) {
    this.say(`Exporting ${name}…`, "info", 3000, "export");
    try {
      const response = await fetch(`/v1/spaces/${encodeURIComponent(space)}/export`, {
        method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
      if (!response.ok) {
        let detail = `HTTP ${response.status}`;
        try { detail = (await response.json()).detail ?? detail; } catch { /* not JSON */ }
        this.say(`Export failed: ${typeof detail === "string" ? detail : JSON.stringify(detail)}`, "error", 10000, "export");
        return;
      }
      const link = Object.assign(document.createElement("a"), { href: URL.createObjectURL(await response.blob()), download: name });
      document.body.append(link);
      link.click();
      link.remove();
      setTimeout(() => URL.revokeObjectURL(link.href), 60000);
      this.downloads += 1;
      this.say(`${name}: ${response.headers.get("X-Morphspace-Frames") ?? "?"} frames.`, "info", 4000, "export");
    } catch (err) {
      this.say(`Export failed: ${err.message}`, "error", 10000, "export");
    }
  }
}
