// The heatmap colour scale: blue (0) -> cyan -> green -> yellow -> red (>= scale), as in the
// paper's error figures. Shared by the mesh colours and the legend so the two always agree.
export const STOPS = [
  [0.0, [0.10, 0.20, 0.85]],
  [0.25, [0.05, 0.70, 0.95]],
  [0.5, [0.15, 0.85, 0.25]],
  [0.75, [0.98, 0.85, 0.10]],
  [1.0, [0.90, 0.10, 0.08]],
];

/** Write the colour of t in [0, 1] (clamped) into out[offset..offset+2]. */
export function colourAt(t, out, offset) {
  const x = t <= 0 ? 0 : t >= 1 ? 1 : t;
  let i = 1;
  while (i < STOPS.length - 1 && STOPS[i][0] < x) i += 1;
  const [t0, c0] = STOPS[i - 1];
  const [t1, c1] = STOPS[i];
  const u = (x - t0) / (t1 - t0);
  out[offset] = c0[0] + (c1[0] - c0[0]) * u;
  out[offset + 1] = c0[1] + (c1[1] - c0[1]) * u;
  out[offset + 2] = c0[2] + (c1[2] - c0[2]) * u;
}

/** A CSS linear-gradient of the scale (for the legend). */
export function cssGradient() {
  const parts = STOPS.map(([t, c]) => `rgb(${c.map((v) => Math.round(v * 255)).join(",")}) ${t * 100}%`);
  return `linear-gradient(to right, ${parts.join(", ")})`;
}
