// The page's layout on small screens and touch: the control panel as a drawer (below 900 px
// wide), the status box compact (below 700 px wide, or when the user collapses it), and the touch
// steering stick (on touch screens, or when ticked in Playback).
const $ = (id) => document.getElementById(id);

const NARROW = window.matchMedia("(max-width: 900px)");
const COMPACT = window.matchMedia("(max-width: 700px)");
const TOUCH = window.matchMedia("(pointer: coarse)");

export function setUpDrawer() {
  const panel = $("panel");
  const toggle = $("drawer-toggle");
  const set = (open) => {
    panel.classList.toggle("open", open);
    toggle.setAttribute("aria-expanded", String(open));
    toggle.textContent = open ? "✕ Close" : "☰ Controls";
  };
  toggle.addEventListener("click", () => {
    const opening = !panel.classList.contains("open");
    set(opening);
    if (opening) panel.querySelector("select, input, button:not(#drawer-close)")?.focus();
  });
  $("drawer-close").addEventListener("click", () => { set(false); toggle.focus(); });
  panel.addEventListener("keydown", (event) => {
    if (event.key === "Escape" && NARROW.matches && panel.classList.contains("open")) {
      set(false);
      toggle.focus();
    }
  });
  NARROW.addEventListener("change", () => set(false));
  return { open: () => set(true), close: () => set(false), isOpen: () => panel.classList.contains("open") };
}

export function setUpStatusBox() {
  const box = $("status");
  const toggle = $("status-toggle");
  const set = (compact) => {
    box.classList.toggle("compact", compact);
    toggle.setAttribute("aria-expanded", String(!compact));
    toggle.textContent = compact ? "details" : "less";
  };
  set(COMPACT.matches);
  COMPACT.addEventListener("change", () => set(COMPACT.matches));
  toggle.addEventListener("click", () => set(!box.classList.contains("compact")));
}

/** The touch stick: drag the knob; steering.setStick(x, y, active) with x, y in [-1, 1]. */
export function setUpStick(steering, forced) {
  const stick = $("stick");
  const knob = $("stick-knob");
  const checkbox = $("touch");
  checkbox.checked = forced ?? (TOUCH.matches || navigator.maxTouchPoints > 0);
  const show = () => { stick.hidden = !checkbox.checked; };
  checkbox.addEventListener("change", show);
  show();
  let pointer = null;
  const move = (event) => {
    const rect = stick.getBoundingClientRect();
    const radius = rect.width / 2;
    let x = (event.clientX - rect.left - radius) / radius;
    let y = -(event.clientY - rect.top - radius) / radius;
    const length = Math.hypot(x, y);
    if (length > 1) { x /= length; y /= length; }
    knob.style.transform = `translate(${x * (radius - 20)}px, ${-y * (radius - 20)}px)`;
    steering.setStick(x, y, true);
  };
  stick.addEventListener("pointerdown", (event) => {
    pointer = event.pointerId;
    stick.setPointerCapture(pointer);
    move(event);
    event.preventDefault();
  });
  stick.addEventListener("pointermove", (event) => { if (event.pointerId === pointer) move(event); });
  const release = (event) => {
    if (event.pointerId !== pointer) return;
    pointer = null;
    knob.style.transform = "";
    steering.setStick(0, 0, false);
  };
  stick.addEventListener("pointerup", release);
  stick.addEventListener("pointercancel", release);
}
