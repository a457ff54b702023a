// Camera presets: chase (behind the character), side (at its left), front (facing it, a little
// to its left) and free (orbit anywhere). In a preset the camera keeps its place relative to the
// character's root and heading, smoothly, at the distance the wheel (or a pinch) sets; dragging
// with one pointer (mouse or finger) to orbit makes it free. In free mode it still follows the
// character unless `follow` is off.
import * as THREE from "three";

export const PRESETS = ["chase", "side", "front", "free"];

// root-local offsets (the character faces +Z, its left is +X): direction of the camera from
// the point it looks at, 0.9 m above the root
const OFFSETS = {
  chase: new THREE.Vector3(0.0, 0.35, -1.0),
  side: new THREE.Vector3(1.0, 0.2, 0.08),
  front: new THREE.Vector3(0.35, 0.25, 1.0),
};
const LOOK_HEIGHT = 0.9;
const DRAG_PX = 5;  // a press that moves further than this is an orbit: the camera becomes free

export class CameraRig {
  constructor(camera, controls, canvas) {
    this.camera = camera;
    this.controls = controls;
    this.preset = "free";
    this.follow = true;
    this.distance = 4.6;
    this.onChange = null;  // (preset) after the user took the camera (free) by dragging
    // one pointer dragging orbits (free); two (a pinch) only zoom and keep the preset
    let down = null;
    const pointers = new Set();
    canvas.addEventListener("pointerdown", (e) => {
      pointers.add(e.pointerId);
      down = pointers.size === 1 ? { x: e.clientX, y: e.clientY } : null;
    });
    const up = (e) => {
      pointers.delete(e.pointerId);
      down = null;
    };
    canvas.addEventListener("pointerup", up);
    canvas.addEventListener("pointercancel", up);
    canvas.addEventListener("pointermove", (e) => {
      if (!down || pointers.size !== 1 || this.preset === "free") return;
      if (Math.hypot(e.clientX - down.x, e.clientY - down.y) > DRAG_PX) {
        this.setPreset("free");
        this.onChange?.("free");
      }
    });
  }

  setPreset(name) {
    if (!PRESETS.includes(name)) throw new Error(`unknown camera preset ${name}`);
    this.preset = name;
  }

  /** Move the camera for this animation frame; root: THREE.Vector3 or null, heading in radians. */
  update(dt, root, heading) {
    const controls = this.controls;
    if (root) {
      const k = 1 - Math.exp(-dt * (this.preset === "free" ? 6 : 4));
      if (this.preset !== "free") {
        const look = new THREE.Vector3(root.x, LOOK_HEIGHT, root.z);
        const direction = OFFSETS[this.preset].clone().normalize().applyAxisAngle(new THREE.Vector3(0, 1, 0), heading);
        const place = look.clone().addScaledVector(direction, this.distance);
        controls.target.lerp(look, k);
        this.camera.position.lerp(place, k);
      } else if (this.follow) {
        const target = new THREE.Vector3(root.x, controls.target.y, root.z);
        const delta = target.sub(controls.target).multiplyScalar(k);
        controls.target.add(delta);
        this.camera.position.add(delta);
      }
    }
    // the wheel (or a pinch) scales the distance inside controls.update(): keep that as the
    // preset's distance (measuring it otherwise would shrink it while the camera swings round)
    const before = this.camera.position.distanceTo(controls.target);
    controls.update();
    const after = this.camera.position.distanceTo(controls.target);
    if (this.preset !== "free" && before > 1e-6 && Math.abs(after - before) > 1e-6) {
      this.distance = Math.min(controls.maxDistance, Math.max(controls.minDistance, this.distance * (after / before)));
    }
  }

  /** Horizontal unit direction (x, z) from the target to the key light: the camera's side,
   * turned 40 degrees, so the side of the character the camera sees is the lit one. */
  keyLightDirection() {
    const d = this.camera.position.clone().sub(this.controls.target);
    const angle = Math.atan2(d.x, d.z) + (40 * Math.PI) / 180;
    return [Math.sin(angle), Math.cos(angle)];
  }

  /** Where the camera is relative to the character: for tests and the overlay. */
  describe(root, heading) {
    const d = this.camera.position.clone().sub(new THREE.Vector3(root[0], LOOK_HEIGHT, root[2]));
    d.applyAxisAngle(new THREE.Vector3(0, 1, 0), -heading);  // into the character's frame
    return { preset: this.preset, local: [d.x, d.y, d.z] };
  }
}
