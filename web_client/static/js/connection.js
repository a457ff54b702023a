// One WebSocket to /v1/stream that survives server restarts: on close it reconnects with backoff
// and says hello again with the current space, mode, codec and parameter targets.
import { clientMessage, serverMessage } from "./messages.js";
import { CLIENT_MESSAGES } from "../protocol.js";

const BACKOFF_MS = [250, 500, 1000, 2000];
// A connection that brings no message for this long while frames are due (not paused, rate > 0;
// at least three frame periods) is taken as lost: a server stopped without closing the socket,
// or a network gone, may never close it in the browser.
export const SILENCE_MS = 5000;

/** A typed array over msgpack bin bytes, copied only when the offset is misaligned. */
export function typedView(bytes, Ctor) {
  const { BYTES_PER_ELEMENT: size } = Ctor;
  if (bytes.byteOffset % size === 0) {
    return new Ctor(bytes.buffer, bytes.byteOffset, bytes.byteLength / size);
  }
  return new Ctor(bytes.slice().buffer);
}

export class StreamConnection {
  /**
   * url: ws://host/v1/stream; hello(): the fields of the next Hello (space, codec, mode, params...);
   * handlers: {topology(t), frame(f), pulled(f), notice(n), error(e), state(s)}.
   */
  constructor(url, hello, handlers) {
    this.url = url;
    this.hello = hello;
    this.handlers = handlers;
    this.ws = null;
    this.state = "idle";          // idle | connecting | open | reconnecting
    this.seq = 0;
    this.attempt = 0;
    this.reconnects = 0;
    this.timer = null;
    this.helloSeq = 0;
    this.ready = false;           // a topology arrived for the current hello
    this.window = 0;              // frames in flight the current hello allows (0: no acks)
    this.paused = false;          // a pause was sent (until resume or the next hello)
    this.rate = 60;               // frames per second the current hello or rate message asked for
    this.lastMessage = 0;         // performance.now() when the last message arrived
    this.watchdog = null;
  }

  start() {
    if (this.state === "idle") this._open();
  }

  _setState(state) {
    this.state = state;
    this.handlers.state?.(state);
  }

  _open() {
    clearTimeout(this.timer);
    this._setState(this.attempt === 0 && this.reconnects === 0 ? "connecting" : "reconnecting");
    let ws;
    try {
      ws = new WebSocket(this.url);
    } catch (err) {
      this._schedule();
      return;
    }
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    ws.onopen = () => {
      if (this.attempt > 0 || this.reconnects > 0) this.reconnects += 1;
      this.attempt = 0;
      this.lastMessage = performance.now();
      clearInterval(this.watchdog);
      this.watchdog = setInterval(() => this._checkSilence(ws), 500);
      this._setState("open");
      this.sayHello();
    };
    ws.onmessage = (event) => this._receive(event.data);
    ws.onclose = () => {
      if (this.ws !== ws) return;
      clearInterval(this.watchdog);
      this.ws = null;
      this.ready = false;
      this._schedule();
    };
    ws.onerror = () => {};  // onclose follows and reconnects
  }

  _schedule() {
    const delay = BACKOFF_MS[Math.min(this.attempt, BACKOFF_MS.length - 1)];
    this.attempt += 1;
    this._setState("reconnecting");
    this.timer = setTimeout(() => this._open(), delay);
  }

  _checkSilence(ws) {
    if (this.ws !== ws || !this.open || !this.ready || this.paused || !(this.rate > 0)) return;
    const silent = performance.now() - this.lastMessage;
    if (silent <= Math.max(SILENCE_MS, 3000 / this.rate)) return;
    clearInterval(this.watchdog);
    this.ws = null;
    this.ready = false;
    ws.onclose = null;
    ws.close();
    this.handlers.error?.({ code: "client", message: `no message from the server for ${(silent / 1000).toFixed(1)} s; reconnecting` });
    this._schedule();
  }

  _receive(data) {
    this.lastMessage = performance.now();
    if (typeof data === "string") return;
    let message;
    try {
      message = serverMessage(data);
    } catch (err) {
      this.handlers.error?.({ code: "client", message: `undecodable server message: ${err.message}` });
      return;
    }
    if (message.type === "topology") {
      this.ready = true;
      this.handlers.topology?.(message);
    } else if (message.type === "frame") {
      // With a window, the server keeps at most that many frames in flight until we ack:
      // latest-wins end to end, so a busy page never works through a backlog of stale frames.
      if (this.window > 0 && this.open) this.ws.send(clientMessage("ack", { frame: message.seq }));
      if (!this.ready) return;
      if (message.pull_id !== undefined && message.pull_id !== null) this.handlers.pulled?.(message);
      else this.handlers.frame?.(message);
    } else if (message.type === "notice") {
      this.handlers.notice?.(message);
    } else if (message.type === "error") {
      this.handlers.error?.(message);
    }
  }

  get open() {
    return this.ws !== null && this.ws.readyState === WebSocket.OPEN;
  }

  /** Send a client message; fills in `seq` when the message has one. Returns the seq (or null). */
  send(type, fields = {}) {
    if (!this.open) return null;
    const body = { ...fields };
    let seq = null;
    if (CLIENT_MESSAGES[type]?.includes("seq")) {
      seq = ++this.seq;
      body.seq = seq;
    }
    if (type === "pause") this.paused = true;
    else if (type === "resume") this.paused = false;
    else if (type === "rate") this.rate = body.rate;
    else if (type === "hello") [this.paused, this.rate] = [false, body.rate ?? 60];
    if (type === "resume" || type === "rate" || type === "hello") this.lastMessage = performance.now();
    this.ws.send(clientMessage(type, body));  // throws MessageError for fields protocol.js lacks
    return seq;
  }

  /** (Re)start streaming with the current hello fields (a new topology follows). */
  sayHello() {
    const fields = this.hello();
    if (!fields || !(fields.space || fields.graph)) return null;
    this.window = fields.window ?? 0;
    this.ready = false;
    this.helloSeq = this.send("hello", fields);
    return this.helloSeq;
  }

  /** Drop the connection as if the server had gone (used by tests of the reconnect path). */
  drop() {
    this.ws?.close();
  }
}
