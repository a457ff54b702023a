// What the status overlay reports: frames per second received, latency from a parameter change
// (the Params message's seq) to the first frame whose ack reaches it, dropped frames.
const WINDOW_MS = 1000;
const KEEP_LATENCIES = 64;

function percentile(sorted, q) {
  if (sorted.length === 0) return null;
  return sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))];
}

export class StreamStats {
  constructor() {
    this.framesTotal = 0;
    this.reset();
  }

  /** Forget the per-connection counters (a new hello or a reconnect). */
  reset() {
    this.arrivals = [];
    this.pending = new Map();   // params seq -> performance.now() when sent
    this.latencies = [];
    this.lastLatency = null;
    this.lastSeq = 0;
    this.pulledSeqs = new Set();  // frame numbers taken by pulled frames (side by side): not gaps
    this.gaps = 0;
    this.serverDropped = 0;
    this.frames = 0;
  }

  /** A Params message with this seq left now. */
  sent(seq) {
    if (seq !== null) this.pending.set(seq, performance.now());
  }

  /** A streamed frame arrived. */
  frame(frame) {
    const now = performance.now();
    this.arrivals.push(now);
    while (this.arrivals.length && this.arrivals[0] < now - WINDOW_MS) this.arrivals.shift();
    this.frames += 1;
    this.framesTotal += 1;
    if (frame.pull_id === undefined || frame.pull_id === null) {
      if (this.lastSeq && frame.seq > this.lastSeq + 1) {
        let missing = frame.seq - this.lastSeq - 1;
        for (const seq of this.pulledSeqs) {
          if (seq > this.lastSeq && seq < frame.seq) missing -= 1;
          if (seq < frame.seq) this.pulledSeqs.delete(seq);
        }
        this.gaps += missing;
      }
      this.lastSeq = frame.seq;
    }
    this.serverDropped = frame.dropped;
    for (const [seq, sentAt] of this.pending) {
      if (seq <= frame.ack) {
        this.lastLatency = now - sentAt;
        this.latencies.push(this.lastLatency);
        if (this.latencies.length > KEEP_LATENCIES) this.latencies.shift();
        this.pending.delete(seq);
      }
    }
  }

  /** A pulled frame arrived (its number is not a gap in the stream). */
  pulled(frame) {
    this.pulledSeqs.add(frame.seq);
  }

  fps() {
    const now = performance.now();
    return this.arrivals.filter((t) => t >= now - WINDOW_MS).length * (1000 / WINDOW_MS);
  }

  latency() {
    const sorted = [...this.latencies].sort((a, b) => a - b);
    return { last: this.lastLatency, median: percentile(sorted, 0.5), p95: percentile(sorted, 0.95), n: sorted.length };
  }

  snapshot() {
    return {
      fps: this.fps(), latency: this.latency(), dropped: this.serverDropped, gaps: this.gaps,
      frames: this.frames, framesTotal: this.framesTotal, pending: this.pending.size,
    };
  }
}
