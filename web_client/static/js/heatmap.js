// The error heatmap's controls: on/off, the distance at the red end (fixed in mm, or auto: the
// largest distance in recent frames), the legend. A change recolours the frame on screen at once,
// even while paused (no new frame comes then).
import { cssGradient } from "./colormap.js";
import { say } from "./overlay.js";

const $ = (id) => document.getElementById(id);

export class HeatmapControls {
  /** state: the page state (heatmap, frame); url: a UrlWriter; scale: the URL's "auto" or mm. */
  constructor(state, viewer, connection, url, scale) {
    this.state = state;
    this.viewer = viewer;
    this.autoMax = 0;  // metres: a slowly decaying maximum of the frames' error_max (auto scale)
    this.lastScale = "20";  // the last good "red at" (mm): put back when one that is not is typed
    if (scale === "auto") $("heat-auto").checked = true;
    else if (scale !== null && scale > 0) $("heat-scale").value = String(scale);
    if (this.validScale($("heat-scale").value)) this.lastScale = $("heat-scale").value;
    $("heatmap").checked = state.heatmap;
    viewer.setHeatmap(state.heatmap, this.scale());
    $("heatmap").addEventListener("change", (event) => {
      state.heatmap = event.target.checked;
      viewer.setHeatmap(state.heatmap, this.scale());
      connection.send("heatmap", { on: state.heatmap });
      this.updateLegend();
      url.changed();
    });
    $("heat-scale").addEventListener("change", () => {
      // a scale that is not a number of millimetres above 0: said, and the last good one back
      if (this.validScale($("heat-scale").value)) this.lastScale = $("heat-scale").value;
      else {
        say(`red at: give millimetres above 0 (kept ${this.lastScale} mm)`, "error");
        $("heat-scale").value = this.lastScale;
        viewer.setHeatmap(state.heatmap, this.scale());
        this.updateLegend();
        url.changed();
      }
    });
    for (const id of ["heat-scale", "heat-auto"]) {
      $(id).addEventListener("input", () => {
        // auto starts from the largest distance of the frame on screen, and the mesh is
        // recoloured at once on the new scale
        this.autoMax = state.frame?.error_max ?? 0;
        viewer.setHeatmap(state.heatmap, this.scale());
        this.updateLegend();
        url.changed();
      });
    }
    this.updateLegend();
  }

  validScale(text) {
    const mm = Number(text);
    return text !== "" && Number.isFinite(mm) && mm > 0;
  }

  /** Metres at the red end. */
  scale() {
    if ($("heat-auto").checked) return Math.max(this.autoMax, 1e-4);
    const text = $("heat-scale").value;
    return Number(this.validScale(text) ? text : this.lastScale) / 1000;
  }

  /** The scale as the URL keeps it: "auto" or millimetres (the last good value while one is typed). */
  urlScale() {
    if ($("heat-auto").checked) return "auto";
    return this.validScale($("heat-scale").value) ? $("heat-scale").value : this.lastScale;
  }

  /** A graph streams (no heatmap there): the heatmap goes off, its controls are disabled and the
   * legend hidden; back on a space the controls come back (the heatmap stays off until asked). */
  forGraph(isGraph) {
    if (isGraph && this.state.heatmap) {
      this.state.heatmap = false;
      $("heatmap").checked = false;
      this.viewer.setHeatmap(false, this.scale());
    }
    this.updateLegend();  // (it enables the scale unless auto: disabled after it on a graph)
    for (const id of ["heat-scale", "heat-auto", "compare-mode"]) $(id).disabled = isGraph;
    if (!isGraph) $("heat-scale").disabled = $("heat-auto").checked;
  }

  /** A streamed frame arrived: the auto scale follows its largest distance. */
  frame(frame) {
    if (frame.error_max !== undefined && frame.error_max !== null && $("heat-auto").checked) {
      this.autoMax = Math.max(frame.error_max, this.autoMax * 0.98);
      this.viewer.heatmap.scale = this.scale();
    }
  }

  /** Five times a second: the auto scale's legend. */
  tick() {
    if (this.state.heatmap && $("heat-auto").checked) this.updateLegend();
  }

  updateLegend() {
    const legend = $("legend");
    legend.hidden = !this.state.heatmap;
    legend.querySelector(".legend-bar").style.background = cssGradient();
    const mm = this.scale() * 1000;
    $("heat-scale").disabled = $("heat-auto").checked;
    $("legend-mid").textContent = `${(mm / 2).toPrecision(3)} mm`;
    $("legend-max").textContent = `≥ ${mm.toPrecision(3)} mm`;
  }
}
