// Smaller tools around the view: the help dialog's key table, the share link, the frame
// downloads (OBJ, GLB from GET /v1/spaces/{name}/frame) and the side-by-side comparison (the
// same pose pulled in a second blend mode: a `pull` message per drawn frame, one at a time).
import { openDialog } from "./dialogs.js";

const $ = (id) => document.getElementById(id);

/** Fill the help dialog with the keys of the current space and open it. */
export function showHelp(steering, spaceName, graphKeys = null) {
  const rows = [
    ...steering.keys(),
    ...(graphKeys ?? [{ keys: "Space", what: "pause / resume" },
      { keys: "R", what: "reset to the origin (a clip plays again)" }]),
    { keys: "C", what: "next camera preset (chase, side, front, free)" },
    { keys: "?", what: "this list" },
    { keys: "Esc", what: "close this list (or the controls drawer)" },
    { keys: "Tab", what: "move through the controls; arrows move a focused slider" },
  ];
  const table = $("help-keys");
  table.replaceChildren(...rows.map(({ keys, what }) => {
    const row = document.createElement("tr");
    row.append(Object.assign(document.createElement("th"), { textContent: keys }),
      Object.assign(document.createElement("td"), { textContent: what }));
    return row;
  }));
  $("help-title").textContent = spaceName ? `Keys in ${spaceName}` : "Keys";
  openDialog("help-dialog", "help-close");
}

/** Show the link to this view, selected, and try to copy it. */
export async function shareLink(url) {
  $("share-url").value = url;
  $("share-note").textContent = "Select and copy the link.";
  openDialog("share-dialog", "share-url");
  $("share-url").select();
  try {
    await navigator.clipboard.writeText(url);
    $("share-note").textContent = "Copied to the clipboard.";
  } catch {
    // no clipboard permission (e.g. plain http on another host): the selected field remains
  }
}

/** The REST URL of the frame on screen: its requested parameters, phase and mode, root-local. */
export function frameUrl(space, defs, frame, format) {
  const params = defs.map((d, i) => `${d.name}:${Number(frame.requested[i].toPrecision(10))}`).join(",");
  const query = new URLSearchParams({ params, phase: String(frame.phase), mode: frame.mode, format, placed: "false" });
  return `/v1/spaces/${encodeURIComponent(space)}/frame?${query}`;
}

/** The OBJ and GLB links of the frame on screen: ``current()`` gives {space (whose /frame is asked), name
 * (of the file), defs (the parameters' definitions), frame} or null (nothing to download). */
export function setUpDownloads(current) {
  for (const format of ["obj", "glb"]) {
    const link = $(`download-${format}`);
    const update = () => {
      const now = current();
      if (!now) {
        link.removeAttribute("href");
        link.setAttribute("aria-disabled", "true");
        return;
      }
      link.removeAttribute("aria-disabled");
      link.href = frameUrl(now.space, now.defs, now.frame, format);
      link.download = `${now.name}-${now.frame.mode}-phase${now.frame.phase.toFixed(3)}.${format}`;
    };
    link.addEventListener("click", update);   // runs before the link is followed
    link.addEventListener("focus", update);
    link.addEventListener("pointerenter", update);
    setInterval(update, 1000);
  }
}

/** Side by side: pulls the drawn frame's pose in another mode and hands it to the viewer. */
export class Comparison {
  constructor(connection, viewer) {
    this.connection = connection;
    this.viewer = viewer;
    this.on = false;
    this.mode = "nonlinear";
    this.nextId = 1;
    this.inFlight = null;  // {id, frame, at}
    this.shown = 0;        // pulled frames drawn (tests read it)
  }

  set(on) {
    this.on = on;
    this.inFlight = null;
    this.viewer.setCompare(on);
  }

  /** A streamed frame was drawn: ask for the same pose in the comparison mode (one at a time). */
  drawn(frame, defs) {
    if (!this.on || !this.connection.open) return;
    const now = performance.now();
    if (this.inFlight && now - this.inFlight.at < 1000) return;
    if (now - (this.lastAt ?? -Infinity) < 50) return;  // at most 20 pulls a second: the message budget
    this.lastAt = now;
    const params = Object.fromEntries(defs.map((d, i) => [d.name, frame.requested[i]]));
    const id = this.nextId++;
    this.inFlight = { id, frame, at: now };
    this.connection.send("pull", { id, params, phase: frame.phase, mode: this.mode });
  }

  pulled(message) {
    if (!this.on || !this.inFlight || message.pull_id !== this.inFlight.id) return;
    this.viewer.showCompareFrame(message, this.inFlight.frame);
    this.inFlight = null;
    this.shown += 1;
  }
}
