// The error heatmap's controls: on/off, the distance at the red end (fixed in mm, or auto: the
// largest distance in recent frames), the legend. A change recolours the frame on screen at once,
// even while paused (no new frame comes then).
import { cssGradient } from "./colormap.js";

const $ = (id) => document.getElementById(id);

export class HeatmapControls {
  /** state: the page state (heatmap, frame); url: a UrlWriter; scale: the URL's "auto" or mm. */
  constructor(state, viewer, connection, url, scale) {
    this.state = state;
    this.viewer = viewer;
    this.autoMax = 0;  // metres: a slowly decaying maximum of the frames' error_max (auto scale)
    if (scale === "auto") $("heat-auto").checked = true;
    else if (scale !== null && scale > 0) $("heat-scale").value = String(scale);
    $("heatmap").checked = state.heatmap;
    viewer.setHeatmap(state.heatmap, this.scale());
    $("heatmap").addEventListener("change", (event) => {
      state.heatmap = event.target.checked;
      viewer.setHeatmap(state.heatmap, this.scale());
      connection.send("heatmap", { on: state.heatmap });
      this.updateLegend();
      url.changed();
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

  /** Metres at the red end. */
  scale() {
    if ($("heat-auto").checked) return Math.max(this.autoMax, 1e-4);
    const mm = Number($("heat-scale").value);
    return (Number.isFinite(mm) && mm > 0 ? mm : 20) / 1000;
  }

  /** The scale as the URL keeps it: "auto" or millimetres. */
  urlScale() {
    return $("heat-auto").checked ? "auto" : $("heat-scale").value;
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
