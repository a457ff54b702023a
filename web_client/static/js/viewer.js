// The three.js scene: the streamed character (one BufferGeometry whose position attribute is
// rewritten in place per frame), a ground grid that follows it, the camera (presets in
// camera.js), the heatmap colouring, the travelled path, a trail of every n-th frame, and a
// second copy of the character for the side-by-side comparison.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { CameraRig } from "./camera.js";
import { typedView } from "./connection.js";
import { GRID_TILE_M, gridTexture, heatmapLut, LUT_SIZE, softwareGL } from "./scenery.js";

const BODY_COLOUR = 0xc9a27e;
const TRAIL_COLOUR = 0x8fa7c9;
const PATH_POINTS = 8192;
export class Viewer {
  /** quality: {antialias, shadows} (both default on; ?lite=1 turns them off for software GL). */
  constructor(canvas, quality = {}) {
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: quality.antialias ?? !softwareGL(canvas) });
    this.software = softwareGL(canvas);
    // Software GL (e.g. headless Chromium's SwiftShader) draws every pixel on the CPU: start at a
    // lower resolution without shadows, so the page stays responsive; adapt() tunes it further.
    const lite = quality.lite ?? this.software;
    this.pixelRatio = lite ? 0.5 : Math.min(window.devicePixelRatio || 1, 2);
    this.renderer.setPixelRatio(this.pixelRatio);
    this.renderer.shadowMap.enabled = quality.shadows ?? !lite;
    this.frameMs = null;
    this.renderer.shadowMap.type = THREE.PCFShadowMap;
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0xdfe4ea);
    this.scene.fog = new THREE.Fog(0xdfe4ea, 14, 34);
    this.camera = new THREE.PerspectiveCamera(45, 1, 0.05, 200);
    this.camera.position.set(4.2, 2.0, -2.4);
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.target.set(0, 0.9, 0);
    this.controls.enableDamping = true;
    this.controls.maxPolarAngle = Math.PI * 0.495;
    this.controls.minDistance = 0.8;
    this.controls.maxDistance = 25;
    this.rig = new CameraRig(this.camera, this.controls, canvas);

    this.scene.add(new THREE.HemisphereLight(0xf4f6ff, 0x7d6e5a, 1.4));
    this.sun = new THREE.DirectionalLight(0xffffff, 2.2);
    this.sun.position.set(2.5, 6, -3);
    this.sun.castShadow = true;
    this.sun.shadow.mapSize.set(1024, 1024);
    Object.assign(this.sun.shadow.camera, { left: -3, right: 3, top: 3, bottom: -3, near: 0.5, far: 15 });
    this.scene.add(this.sun, this.sun.target);

    // Ground grid: a 1 m grid with 5 m major lines drawn into a texture (lines rendered as
    // GL lines get lost on some software renderers); the plane re-centres in 5 m steps.
    const groundSize = 300;
    const material = new THREE.MeshStandardMaterial({ map: gridTexture(groundSize / GRID_TILE_M), roughness: 1 });
    this.ground = new THREE.Mesh(new THREE.PlaneGeometry(groundSize, groundSize), material);
    this.ground.rotation.x = -Math.PI / 2;
    this.ground.receiveShadow = true;
    this.scene.add(this.ground);
    this.origin = new THREE.AxesHelper(0.5);
    this.origin.position.y = 0.01;
    this.scene.add(this.origin);

    const pathGeometry = new THREE.BufferGeometry();
    pathGeometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(PATH_POINTS * 3), 3));
    pathGeometry.setDrawRange(0, 0);
    this.path = new THREE.Line(pathGeometry, new THREE.LineBasicMaterial({ color: 0x2a5db0 }));
    this.path.frustumCulled = false;
    this.pathCount = 0;
    this.scene.add(this.path);

    this.lut = heatmapLut();
    this.mesh = null;
    this.topology = null;
    this.heatmap = { on: false, scale: 0.02 };  // metres at the red end
    this.trail = { on: false, every: 8, count: 12, meshes: [], next: 0, bucket: null };
    this.framesDrawn = 0;
    this.lastTime = null;
    this.lastFrame = null;        // the newest frame drawn (recoloured when the heat scale changes)
    this.keepTrailOnce = false;   // a replayed clip: keep the finished run's trail
    this.compare = null;          // {mesh} while the side-by-side view is on
    this.resize();
    // the canvas changes size with the window and with the layout (drawer, toolbar wrapping)
    new ResizeObserver(() => this.resize()).observe(canvas);
  }

  resize() {
    const { clientWidth: w, clientHeight: h } = this.canvas;
    if (w === 0 || h === 0) return;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = (this.compare ? w / 2 : w) / h;
    this.camera.updateProjectionMatrix();
  }

  /** A new topology: rebuild the character mesh and forget the path and trail. */
  setTopology(topology) {
    const comparing = this.compare !== null;
    if (comparing) this.setCompare(false);
    this.topology = topology;
    const n = topology.n_vertices;
    if (this.mesh) {
      this.scene.remove(this.mesh);
      this.mesh.geometry.dispose();
      this.mesh.material.dispose();
    }
    const geometry = new THREE.BufferGeometry();
    const position = new THREE.BufferAttribute(new Float32Array(n * 3), 3);
    position.setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute("position", position);
    const colour = new THREE.BufferAttribute(new Float32Array(n * 3).fill(0.5), 3);
    colour.setUsage(THREE.DynamicDrawUsage);
    geometry.setAttribute("color", colour);
    geometry.setIndex(new THREE.BufferAttribute(typedView(topology.faces, Uint32Array), 1));
    const material = new THREE.MeshStandardMaterial({ color: BODY_COLOUR, roughness: 0.65, metalness: 0.0 });
    this.mesh = new THREE.Mesh(geometry, material);
    this.mesh.castShadow = true;
    this.mesh.frustumCulled = false;  // positions change every frame; bounds would go stale
    this.mesh.visible = false;
    this.scene.add(this.mesh);
    this.lo = topology.bounds_min;
    this.step = topology.bounds_max.map((hi, k) => (hi - topology.bounds_min[k]) / 65535);
    this._applyHeatmapMaterial();
    this.clearPath();
    this.clearTrail();
    this.lastTime = null;
    this.lastFrame = null;
    if (comparing) this.setCompare(true);
  }

  /** Dequantise (q16) or copy (f32) a frame's root-local vertices into the position attribute. */
  _writePositions(frame, mesh = this.mesh) {
    const out = mesh.geometry.attributes.position.array;
    if (this.topology.codec === "q16") {
      const q = typedView(frame.vertices, Uint16Array);
      const [lx, ly, lz] = this.lo;
      const [sx, sy, sz] = this.step;
      for (let i = 0; i < q.length; i += 3) {
        out[i] = lx + q[i] * sx;
        out[i + 1] = ly + q[i + 1] * sy;
        out[i + 2] = lz + q[i + 2] * sz;
      }
    } else {
      out.set(typedView(frame.vertices, Float32Array));
    }
  }

  _writeColours(frame) {
    const colours = this.mesh.geometry.attributes.color;
    const out = colours.array;
    const lut = this.lut;
    if (frame.error_um) {
      const um = typedView(frame.error_um, Uint16Array);
      const k = (LUT_SIZE - 1) / (this.heatmap.scale * 1e6);
      for (let i = 0; i < um.length; i += 1) {
        const j = Math.min(LUT_SIZE - 1, Math.round(um[i] * k)) * 3;
        out[i * 3] = lut[j];
        out[i * 3 + 1] = lut[j + 1];
        out[i * 3 + 2] = lut[j + 2];
      }
    }
    colours.needsUpdate = true;
  }

  _applyHeatmapMaterial() {
    if (!this.mesh) return;
    const material = this.mesh.material;
    material.vertexColors = this.heatmap.on;
    material.color.set(this.heatmap.on ? 0xffffff : BODY_COLOUR);
    material.needsUpdate = true;
  }

  setHeatmap(on, scale) {
    const switched = on !== this.heatmap.on;
    this.heatmap.on = on;
    if (scale !== undefined) this.heatmap.scale = scale;
    this._applyHeatmapMaterial();
    // recolour what is on screen now: a paused stream sends no new frame for the new scale
    if (on && this.mesh && this.lastFrame?.error_um) this._writeColours(this.lastFrame);
    if (switched) this.clearTrail();  // old snapshots carry the other colouring
  }

  /** The colours the heatmap gives the drawn mesh now: (n * 3) linear RGB (for tests). */
  vertexColours() {
    return this.mesh ? Array.from(this.mesh.geometry.attributes.color.array) : [];
  }

  setTrail(on, every, count) {
    const trail = this.trail;
    trail.on = on;
    if (every !== undefined) trail.every = Math.max(1, every);
    if (count !== undefined && count !== trail.count) {
      trail.count = Math.max(1, count);
      this.clearTrail();
    }
    if (!on) this.clearTrail();
  }

  clearTrail() {
    for (const m of this.trail.meshes) {
      this.scene.remove(m);
      m.geometry.dispose();
      m.material.dispose();
    }
    this.trail.meshes = [];
    this.trail.next = 0;
    this.trail.bucket = null;
  }

  clearPath() {
    this.pathCount = 0;
    this.path.geometry.setDrawRange(0, 0);
  }

  /** Draw one streamed frame: vertices in place, normals, root transform, colours, path, trail. */
  showFrame(frame) {
    if (!this.mesh) return;
    if (this.lastTime !== null && frame.time < this.lastTime - 1e-6) {
      this.clearPath();  // the clock went back (reset, a replayed clip): a new path starts
      // a replayed clip keeps the finished run's trail (the ring replaces it snapshot by
      // snapshot), so the whole jump stays in view; a reset by the user clears it
      if (!this.keepTrailOnce) this.clearTrail();
      this.keepTrailOnce = false;
    }
    this.lastTime = frame.time;
    this.lastFrame = frame;
    const geometry = this.mesh.geometry;
    this._writePositions(frame);
    geometry.attributes.position.needsUpdate = true;
    geometry.computeVertexNormals();
    if (this.heatmap.on) this._writeColours(frame);
    this.mesh.position.set(frame.root[0], frame.root[1], frame.root[2]);
    this.mesh.rotation.set(0, frame.heading, 0);
    this.mesh.visible = true;
    this._extendPath(frame.root);
    if (this.trail.on) {
      // every n-th frame of the stream (by frame number, so a slow page keeps the spacing)
      const bucket = Math.floor(frame.seq / this.trail.every);
      if (bucket !== this.trail.bucket) {
        this.trail.bucket = bucket;
        this._snapshot();
      }
    }
    this.framesDrawn += 1;
  }

  _extendPath(root) {
    const array = this.path.geometry.attributes.position.array;
    if (this.pathCount > 0) {
      const i = (this.pathCount - 1) * 3;
      const dx = array[i] - root[0], dz = array[i + 2] - root[2];
      if (dx * dx + dz * dz < 0.0004) return;  // 2 cm
      if (dx * dx + dz * dz > 4) this.clearPath();  // a jump of 2 m: a reset, not a path
    }
    if (this.pathCount === PATH_POINTS) {
      array.copyWithin(0, (PATH_POINTS / 2) * 3);
      this.pathCount = PATH_POINTS / 2;
    }
    array.set([root[0], 0.01, root[2]], this.pathCount * 3);
    this.pathCount += 1;
    this.path.geometry.setDrawRange(0, this.pathCount);
    this.path.geometry.attributes.position.needsUpdate = true;
  }

  /** Copy the character as it is now into the trail (a ring of `count` meshes, oldest faded). */
  _snapshot() {
    const trail = this.trail;
    let copy;
    if (trail.meshes.length < trail.count) {
      const geometry = new THREE.BufferGeometry();
      geometry.setAttribute("position", this.mesh.geometry.attributes.position.clone());
      geometry.setAttribute("normal", this.mesh.geometry.attributes.normal.clone());
      geometry.setAttribute("color", this.mesh.geometry.attributes.color.clone());
      geometry.setIndex(this.mesh.geometry.index.clone());
      // pushed back in depth, so the live character wins where the newest copy coincides with it
      const material = new THREE.MeshStandardMaterial({ color: TRAIL_COLOUR, roughness: 0.8, transparent: true,
        polygonOffset: true, polygonOffsetFactor: 2, polygonOffsetUnits: 2 });
      copy = new THREE.Mesh(geometry, material);
      copy.castShadow = true;
      copy.frustumCulled = false;
      trail.meshes.push(copy);
      this.scene.add(copy);
    } else {
      copy = trail.meshes[trail.next];
      for (const name of ["position", "normal", "color"]) {
        copy.geometry.attributes[name].array.set(this.mesh.geometry.attributes[name].array);
        copy.geometry.attributes[name].needsUpdate = true;
      }
    }
    copy.material.vertexColors = this.heatmap.on;
    copy.material.color.set(this.heatmap.on ? 0xffffff : TRAIL_COLOUR);
    copy.material.needsUpdate = true;
    copy.position.copy(this.mesh.position);
    copy.rotation.copy(this.mesh.rotation);
    copy.visible = true;
    copy.userData.age = 0;
    trail.next = (trail.meshes.indexOf(copy) + 1) % trail.count;
    // fade: newest most opaque
    const n = trail.meshes.length;
    trail.meshes.forEach((m, i) => {
      const age = (trail.next - 1 - i + n) % n;  // 0 = newest
      m.material.opacity = 0.85 - 0.6 * (age / Math.max(1, trail.count - 1));
    });
  }

  /**
   * Resolution follows the frame time: down while frames take over 60 ms to come round
   * (an average of dt), back up while they take under 25 ms; at most one step a second, and not
   * during the first frames (shader compilation).
   */
  adapt(dt) {
    this.adaptFrames = (this.adaptFrames ?? 0) + 1;
    if (this.adaptFrames < 30) return;
    this.frameMs = this.frameMs === null ? 16.7 : 0.9 * this.frameMs + 0.1 * dt * 1000;
    const now = performance.now();
    if (now - (this.adaptedAt ?? 0) < 1000) return;
    const best = Math.min(window.devicePixelRatio || 1, 2);
    let ratio = this.pixelRatio;
    // pixels drawn scale with ratio²: aim at ~30 ms in one step, never below half resolution
    if (this.frameMs > 60 && ratio > 0.5) ratio = Math.max(0.5, ratio * Math.max(0.5, Math.sqrt(30 / this.frameMs)));
    else if (this.frameMs < 25 && ratio < best) ratio = Math.min(best, ratio * 1.25);
    if (ratio !== this.pixelRatio) {
      this.pixelRatio = ratio;
      this.renderer.setPixelRatio(ratio);
      this.resize();
      this.adaptedAt = now;
    }
  }

  // ------------------------------------------------------------ side by side

  /** Side by side on/off: the right half shows a second copy drawn from pulled frames. */
  setCompare(on) {
    if (on && !this.compare && this.mesh) {
      const geometry = new THREE.BufferGeometry();
      const position = this.mesh.geometry.attributes.position.clone();
      position.setUsage(THREE.DynamicDrawUsage);
      geometry.setAttribute("position", position);
      geometry.setIndex(this.mesh.geometry.index);
      // the plain body colour: pulled frames carry no heatmap distances
      const mesh = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial({ color: BODY_COLOUR, roughness: 0.65 }));
      mesh.castShadow = true;
      mesh.frustumCulled = false;
      mesh.visible = false;
      mesh.layers.set(2);
      this.mesh.layers.set(1);
      this.scene.add(mesh);
      this.compare = { mesh, seq: null };
    } else if (!on && this.compare) {
      this.scene.remove(this.compare.mesh);
      this.compare.mesh.geometry.dispose();
      this.compare.mesh.material.dispose();
      this.compare = null;
      if (this.mesh) this.mesh.layers.set(0);
    }
    this.resize();
  }

  /** A pulled frame for the right half, placed where the streamed `frame` it matches stands. */
  showCompareFrame(pulled, frame) {
    const compare = this.compare;
    if (!compare || !this.mesh) return;
    this._writePositions(pulled, compare.mesh);
    compare.mesh.geometry.attributes.position.needsUpdate = true;
    compare.mesh.geometry.computeVertexNormals();
    compare.mesh.position.set(frame.root[0], frame.root[1], frame.root[2]);
    compare.mesh.rotation.set(0, frame.heading, 0);
    compare.mesh.visible = true;
    compare.seq = frame.seq;
  }

  // ------------------------------------------------------------ camera and drawing

  /** Camera preset: chase, side, front or free (camera.js). */
  setCameraPreset(name) {
    this.rig.setPreset(name);
  }

  /** Per animation frame: camera, grid, sun (over the camera's shoulder: what is seen is lit), render. */
  render(dt) {
    const visible = this.mesh && this.mesh.visible;
    this.rig.update(dt, visible ? this.mesh.position : null, visible ? this.mesh.rotation.y : 0);
    const t = this.controls.target;
    this.ground.position.set(Math.round(t.x / GRID_TILE_M) * GRID_TILE_M, 0, Math.round(t.z / GRID_TILE_M) * GRID_TILE_M);
    const [sx, sz] = this.rig.keyLightDirection();
    this.sun.position.set(t.x + 3 * sx, 6, t.z + 3 * sz);
    this.sun.target.position.set(t.x, 0, t.z);
    const { width: w, height: h } = this.renderer.getSize(new THREE.Vector2());
    if (!this.compare) {
      this.camera.layers.set(0);
      this.renderer.render(this.scene, this.camera);
      return;
    }
    // two halves: the streamed mesh (layer 1) left, its comparison (layer 2) right
    this.renderer.setScissorTest(true);
    const half = Math.floor(w / 2);
    this.camera.aspect = half / h;
    this.camera.updateProjectionMatrix();
    for (const [x, width, layer] of [[0, half, 1], [half, w - half, 2]]) {
      this.renderer.setViewport(x, 0, width, h);
      this.renderer.setScissor(x, 0, width, h);
      this.camera.layers.set(0);
      this.camera.layers.enable(layer);
      this.renderer.render(this.scene, this.camera);
    }
    this.renderer.setScissorTest(false);
    this.renderer.setViewport(0, 0, w, h);
  }
}
