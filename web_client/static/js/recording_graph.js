// A motion-graph session recorded in the browser, as a graph recording (docs/file-formats.md,
// "Graph recordings") that `morphspace export` and POST /v1/graphs/{name}/export replay.
//
// Record sends a `reset`: the stream's graph player starts again at its start node, at the
// hello's parameters, at the origin, time 0 (what a recording replays from), then a `params`
// message with the start node's sliders (recorded as the first request). From then on:
// - every frame the stream sends is one step of that player (its `seq` counts the steps; the
//   first after the reset steps 0 s): its `time` goes into `times`, so a replay steps the player
//   by exactly the stream's steps, not by 1 / fps;
// - every `action` and `params` message sent is a request applied just before the step of the
//   first frame that acknowledges it (`ack` >= its seq): request frame = that frame's step - 1.
//   An action's parameters are completed as the server completes them (what the node was last
//   asked for); a `params` message is a `set` request on the node shown then (a blend's target).
//   A message the server refused (an error naming its seq) is dropped.
// A hello (a new space, a reconnection), a `reset`, a blend mode change or a new rate ends the
// recording: a recording has one start, one mode and one clock.
export class GraphRecording {
  /** info: the GET /v1/graphs entry; params: the hello's start parameters; limit: most frames. */
  constructor(info, params, mode, fps, limit) {
    Object.assign(this, { info, mode, fps, limit });
    this.params = { ...(params ?? {}) };
    this.resetSeq = null;   // seq of the reset that starts it
    this.firstSeq = null;   // seq of the stream's first frame after the reset (step 1)
    this.lastSeq = null;
    this.times = [0];       // time of frame k (frame 0: the start, before any step)
    this.requests = [];
    this.pending = [];      // messages sent, not yet acknowledged by a frame
    this.missed = 0;        // frames the stream stepped but that never arrived (seq gaps)
    this.shown = info.start;  // the node a set request changes (the frame before's shown node)
    this.asked = Object.fromEntries(info.nodes.map((n) => [n.name, {}]));  // as GraphPlayer._params
    this.asked[info.start] = { ...this.params };
  }

  /** A message went out; returns why the recording must end, or null. */
  sent(type, fields, seq) {
    if (type === "action") this.pending.push({ seq, node: fields.node, params: { ...(fields.params ?? {}) } });
    else if (type === "params") this.pending.push({ seq, set: true, params: { ...(fields.params ?? {}) } });
    else if (type === "hello") return "the stream started again";
    else if (type === "reset") return "the stream was reset";
    else if (type === "mode") return "the blend mode changed (a recording has one)";
    else if (type === "rate") return "the frame rate changed";
    return null;
  }

  /** The server refused the message ``seq``: it changed nothing, so it is not a request. */
  refused(seq) {
    this.pending = this.pending.filter((m) => m.seq !== seq);
  }

  /** A streamed frame; returns why the recording must end, or null. */
  frame(frame) {
    if (this.firstSeq === null) {
      if (this.resetSeq === null || frame.ack < this.resetSeq) return null;  // from before the reset
      this.firstSeq = frame.seq;
      this.mode = frame.mode;
    } else {
      this.missed += frame.seq - this.lastSeq - 1;
    }
    this.lastSeq = frame.seq;
    const step = this.times.length;  // this frame is the player after `step` steps
    this.apply(frame.ack, step - 1);
    this.times.push(frame.time);
    this.shown = frame.progress !== null && frame.progress !== undefined ? frame.target : frame.node;
    return this.times.length >= this.limit ? `${this.limit} frames, the most exported at once` : null;
  }

  /** The pending messages ``ack`` covers, as requests made at ``at`` (steps before). */
  apply(ack, at) {
    while (this.pending.length && this.pending[0].seq <= ack) {
      const m = this.pending.shift();
      if (m.set) {
        const node = this.shown;
        this.asked[node] = { ...this.asked[node], ...m.params };
        this.requests.push({ frame: at, node, params: m.params, budget: null, set: true });
      } else {
        const params = { ...this.asked[m.node], ...m.params };  // the server's completion (GraphStream.action)
        this.asked[m.node] = params;
        this.requests.push({ frame: at, node: m.node, params, budget: null });
      }
    }
  }

  /** Seconds recorded (the stream's clock). */
  seconds() {
    return this.times.at(-1);
  }

  /** The recording (null when no frame came). */
  document() {
    if (this.firstSeq === null) return null;
    return {
      format: "morphspace-graph-recording", version: 1, graph: this.info.graph, graph_checksum: this.info.checksum,
      start: this.info.start, params: this.params, fps: this.fps, steps: this.times.length - 1, mode: this.mode,
      requests: this.requests, frames_sha256: null, times: this.times, source: "browser",
      missed_frames: this.missed,
    };
  }
}
