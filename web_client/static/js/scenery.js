// What the viewer's scene is made of, apart from the character: the ground grid's texture, the
// heatmap's colour table, and the test for a software WebGL rasteriser.
import * as THREE from "three";
import { colourAt } from "./colormap.js";

export const GRID_TILE_M = 5;
export const LUT_SIZE = 256;

/** A repeating texture of one GRID_TILE_M square: 1 m minor lines, a major line on its edge. */
export function gridTexture(repeat) {
  const size = 512;
  const canvas = document.createElement("canvas");
  canvas.width = canvas.height = size;
  const g = canvas.getContext("2d");
  g.fillStyle = "#c9ced4";
  g.fillRect(0, 0, size, size);
  const cell = size / GRID_TILE_M;
  g.fillStyle = "#a3abb4";
  for (let i = 1; i < GRID_TILE_M; i += 1) {
    g.fillRect(i * cell - 1.5, 0, 3, size);
    g.fillRect(0, i * cell - 1.5, size, 3);
  }
  g.fillStyle = "#7d8792";
  g.fillRect(0, 0, 5, size);
  g.fillRect(0, 0, size, 5);
  const texture = new THREE.CanvasTexture(canvas);
  texture.wrapS = texture.wrapT = THREE.RepeatWrapping;
  texture.repeat.set(repeat, repeat);
  texture.anisotropy = 8;
  texture.colorSpace = THREE.SRGBColorSpace;
  return texture;
}

/** True when WebGL runs on a CPU rasteriser (SwiftShader, llvmpipe). */
export function softwareGL(canvas) {
  const gl = canvas.getContext("webgl2");
  const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
  const renderer = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : "";
  return /swiftshader|llvmpipe|software/i.test(renderer);
}

function srgbToLinear(c) {
  return c <= 0.04045 ? c / 12.92 : Math.pow((c + 0.055) / 1.055, 2.4);
}

/** (LUT_SIZE * 3) linear-space colours of the heatmap scale. */
export function heatmapLut() {
  const lut = new Float32Array(LUT_SIZE * 3);
  for (let i = 0; i < LUT_SIZE; i += 1) {
    colourAt(i / (LUT_SIZE - 1), lut, i * 3);
    for (let k = 0; k < 3; k += 1) lut[i * 3 + k] = srgbToLinear(lut[i * 3 + k]);
  }
  return lut;
}
