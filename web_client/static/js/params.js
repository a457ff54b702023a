// Sliders generated from a space's parameter definitions, keyboard steering (arrows / WASD),
// and a throttled sender: the page asks for targets, the server smooths and realises them.
const SEND_INTERVAL_MS = 50;

function decimals(def) {
  const span = def.max - def.min;
  return span >= 20 ? 1 : span >= 2 ? 2 : 3;
}

export function formatValue(def, value) {
  return value === null || value === undefined || !Number.isFinite(value) ? "–" : value.toFixed(decimals(def));
}

/** Sliders for the parameters [{name, unit, min, max, value|default}] in `container`. */
export class ParameterPanel {
  constructor(container, onChange) {
    this.container = container;
    this.onChange = onChange;
    this.defs = [];
    this.inputs = new Map();
  }

  build(defs, targets) {
    this.defs = defs;
    this.inputs.clear();
    this.container.replaceChildren();
    for (const def of defs) {
      const row = document.createElement("div");
      row.className = "param";
      row.dataset.name = def.name;
      const value = targets[def.name];
      const id = `param-${def.name}`;
      row.innerHTML = `
        <div class="head"><label class="name" for="${id}"></label>
          <span><span class="value"></span> <span class="unit"></span></span></div>
        <input type="range" id="${id}" name="${def.name}">
        <div class="range"><span class="lo"></span><span class="hi"></span></div>`;
      row.querySelector(".name").textContent = def.name.replace(/_/g, " ");
      row.querySelector(".unit").textContent = def.unit;
      row.querySelector(".lo").textContent = formatValue(def, def.min);
      row.querySelector(".hi").textContent = formatValue(def, def.max);
      const input = row.querySelector("input");
      input.min = String(def.min);
      input.max = String(def.max);
      input.step = String((def.max - def.min) / 500);
      input.value = String(value);
      input.setAttribute("aria-valuetext", `${formatValue(def, value)} ${def.unit}`);
      input.addEventListener("input", () => this.onChange(def.name, Number(input.value)));
      input.addEventListener("pointerup", () => input.blur());  // arrows steer again after a drag
      this.inputs.set(def.name, { input, label: row.querySelector(".value"), def });
      row.querySelector(".value").textContent = formatValue(def, value);
      this.container.append(row);
    }
  }

  /** Show a target set elsewhere (keyboard steering) on its slider. */
  show(name, value) {
    const entry = this.inputs.get(name);
    if (!entry) return;
    if (document.activeElement !== entry.input) entry.input.value = String(value);
    entry.label.textContent = formatValue(entry.def, value);
    entry.input.setAttribute("aria-valuetext", `${formatValue(entry.def, value)} ${entry.def.unit}`);
  }
}

/** Sends Params messages at most every SEND_INTERVAL_MS, always with the newest targets. */
export class ParamSender {
  constructor(send) {
    this.send = send;          // send(params) -> seq
    this.pending = {};
    this.timer = null;
    this.lastSent = -Infinity;
  }

  queue(name, value) {
    this.pending[name] = value;
    if (this.timer !== null) return;
    const wait = Math.max(0, this.lastSent + SEND_INTERVAL_MS - performance.now());
    this.timer = setTimeout(() => this.flush(), wait);
  }

  flush() {
    this.timer = null;
    if (Object.keys(this.pending).length === 0) return;
    const params = this.pending;
    this.pending = {};
    this.lastSent = performance.now();
    this.send(params);
  }

  clear() {
    clearTimeout(this.timer);
    this.timer = null;
    this.pending = {};
  }
}

const KEYS = {
  ArrowUp: "faster", KeyW: "faster", ArrowDown: "slower", KeyS: "slower",
  ArrowLeft: "left", KeyA: "left", ArrowRight: "right", KeyD: "right",
};

function typingInto(target) {
  if (!target || !target.tagName) return false;
  if (target.tagName === "SELECT" || target.tagName === "TEXTAREA") return true;
  return target.tagName === "INPUT" && !["checkbox", "radio", "range"].includes(target.type);
}

/** Controls that act on Space themselves (buttons, checkboxes...): Space is theirs, not pause. */
function ownsSpace(target) {
  return Boolean(target && (target.tagName === "BUTTON" || target.tagName === "SUMMARY" ||
    (target.tagName === "INPUT" && ["checkbox", "radio", "range", "file"].includes(target.type))));
}

const spoken = (def) => def.name.replace(/_/g, " ");

/**
 * Keyboard (and touch stick) control of a space's parameters. Up/W and Down/S move the speed
 * parameter (or the first parameter); Left/A and Right/D move turn_rate (or the second
 * parameter). A turn made with the keys or the stick springs back to straight ahead when they
 * let go, like a game; a turn set on the slider holds. Positive turn rates turn left (heading
 * about +Y). In a space without turn_rate (jumps, reaches) the keys just move its parameters.
 */
export class Steering {
  constructor({ getTarget, setTarget }) {
    this.getTarget = getTarget;
    this.setTarget = setTarget;
    this.held = new Set();
    this.forward = null;
    this.turn = null;
    this.centre = false;
    this.springing = false;   // the turn was last moved by keys or the stick: it springs back
    this.stick = { x: 0, y: 0, active: false };
  }

  /** Choose the controlled parameters from the definitions; returns a one-line hint. */
  configure(defs) {
    const byName = Object.fromEntries(defs.map((d) => [d.name, d]));
    this.forward = byName.speed ?? defs[0] ?? null;
    this.turn = byName.turn_rate ?? defs.find((d) => d !== this.forward) ?? null;
    this.centre = this.turn !== null && this.turn.name === "turn_rate";
    this.springing = false;
    return this.keys().filter((k) => k.param).map((k) => `${k.keys}: ${k.what}`).join(" · ");
  }

  /** The keys of the current space: [{keys, what, param}] (param: a parameter key). */
  keys() {
    const list = [];
    if (this.forward) {
      const name = spoken(this.forward);
      list.push({ keys: "↑ / W", what: this.forward.name === "speed" ? "faster" : `more ${name}`, param: true });
      list.push({ keys: "↓ / S", what: this.forward.name === "speed" ? "slower" : `less ${name}`, param: true });
    }
    if (this.turn && this.centre) {
      list.push({ keys: "← / A", what: "turn left (straight again when released)", param: true });
      list.push({ keys: "→ / D", what: "turn right (straight again when released)", param: true });
    } else if (this.turn) {
      list.push({ keys: "→ / D", what: `more ${spoken(this.turn)}`, param: true });
      list.push({ keys: "← / A", what: `less ${spoken(this.turn)}`, param: true });
    }
    return list;
  }

  /** A slider moved a parameter: a turn set there holds (no spring back). */
  sliderMoved(name) {
    if (this.turn && name === this.turn.name) this.springing = false;
  }

  /** The touch stick: x, y in [-1, 1] (right, up); active while a finger holds it. */
  setStick(x, y, active) {
    this.stick = { x, y, active };
    if (active && this.turn && Math.abs(x) > 0.05) this.springing = true;
  }

  attach(target, { onPause, onReset, onKey }) {
    target.addEventListener("keydown", (event) => {
      if (typingInto(event.target) || event.ctrlKey || event.metaKey || event.altKey) return;
      if (onKey?.(event)) {
        event.preventDefault();
      } else if (event.code === "Space") {
        if (ownsSpace(event.target)) return;
        onPause();
        event.preventDefault();
      } else if (event.code === "KeyR") {
        onReset();
      } else if (KEYS[event.code]) {
        // a slider focused from the keyboard keeps its arrow keys (clicked sliders give focus back)
        if (event.target?.type === "range" && event.code.startsWith("Arrow")) return;
        this.held.add(KEYS[event.code]);
        if (KEYS[event.code] === "left" || KEYS[event.code] === "right") this.springing = true;
        event.preventDefault();
      }
    });
    target.addEventListener("keyup", (event) => this.held.delete(KEYS[event.code]));
    window.addEventListener("blur", () => this.held.clear());
  }

  /** Advance the steered targets by dt seconds of held keys. */
  tick(dt) {
    const move = (def, direction, perSecond) => {
      if (!def) return;
      const now = this.getTarget(def.name);
      const next = Math.min(def.max, Math.max(def.min, now + direction * (def.max - def.min) * perSecond * dt));
      if (next !== now) this.setTarget(def.name, next);
    };
    if (this.held.has("faster")) move(this.forward, +1, 0.5);
    if (this.held.has("slower")) move(this.forward, -1, 0.5);
    const stick = this.stick;
    if (stick.active && Math.abs(stick.y) > 0.1) move(this.forward, Math.sign(stick.y), 0.5 * Math.abs(stick.y));
    const left = this.held.has("left"), right = this.held.has("right");
    // without turn_rate, Right/D raises the second parameter (as on its slider)
    const leftwards = this.centre ? +1 : -1;
    if (left && !right) move(this.turn, leftwards, 0.8);
    if (right && !left) move(this.turn, -leftwards, 0.8);
    const stickTurns = stick.active && this.turn && Math.abs(stick.x) > 0.05;
    if (stickTurns && this.centre) {
      // the stick sets the turn directly: full left is the largest left turn
      const straight = Math.min(this.turn.max, Math.max(this.turn.min, 0));
      const end = stick.x < 0 ? this.turn.max : this.turn.min;
      this.setTarget(this.turn.name, straight + (end - straight) * Math.abs(stick.x));
    } else if (stickTurns) {
      move(this.turn, Math.sign(stick.x), 0.8 * Math.abs(stick.x));
    }
    if (!left && !right && !stickTurns && this.centre && this.turn && this.springing) {
      const now = this.getTarget(this.turn.name);
      const straight = Math.min(this.turn.max, Math.max(this.turn.min, 0));
      const stepSize = (this.turn.max - this.turn.min) * 1.2 * dt;
      if (Math.abs(now - straight) > 1e-9) {
        this.setTarget(this.turn.name, Math.abs(now - straight) <= stepSize ? straight : now - Math.sign(now - straight) * stepSize);
      } else {
        this.springing = false;
      }
    }
  }
}
