// Camera framing and the orbit controls, for a world whose up axis the run states.

import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

const UP = {
  "+x": [1, 0, 0], "-x": [-1, 0, 0],
  "+y": [0, 1, 0], "-y": [0, -1, 0],
  "+z": [0, 0, 1], "-z": [0, 0, -1],
};

/** The unit vector of an up axis: a name ("+z", ...) or a vector [x, y, z]. */
export function upVector(up) {
  if (Array.isArray(up)) return new THREE.Vector3(...up).normalize();
  const axis = UP[up];
  if (!axis) throw new Error(`unknown up axis '${up}' (one of ${Object.keys(UP).join(", ")})`);
  return new THREE.Vector3(...axis);
}

/** The up axis a run's frame.json states: its world axis name ("up_axis") when the estimate
 * snapped to one, else its estimated up vector ("up"), else null (a run without poses). */
export function frameUp(frame) {
  const world = frame?.world ?? {};
  if (typeof world.up_axis === "string" && world.up_axis in UP) return world.up_axis;
  const up = world.up;
  const usable = Array.isArray(up) && up.length === 3 && up.every(Number.isFinite);
  return usable && Math.hypot(...up) > 1e-6 ? up : null;
}

/** Place `camera` above and beside the bounds [min, max], looking at their centre. */
export function frame(camera, controls, bounds, up) {
  const [lo, hi] = bounds.map((b) => new THREE.Vector3(...b));
  const centre = lo.clone().add(hi).multiplyScalar(0.5);
  const radius = Math.max(hi.clone().sub(lo).length() / 2, 1e-3);
  const side = new THREE.Vector3(1, 1, 1).projectOnPlane(up);
  if (side.lengthSq() < 1e-9) side.set(1, 0, 0).projectOnPlane(up);
  side.normalize();
  const direction = side.multiplyScalar(0.9).add(up.clone().multiplyScalar(1.1)).normalize();
  const distance = radius / Math.tan(THREE.MathUtils.degToRad(camera.fov / 2)) * 0.75;
  camera.up.copy(up);
  camera.position.copy(centre).addScaledVector(direction, distance);
  camera.near = distance / 200;
  camera.far = distance * 20;
  camera.lookAt(centre);
  camera.updateProjectionMatrix();
  controls.target.copy(centre);
  controls.update();
}

export function makeControls(camera, element) {
  const controls = new OrbitControls(camera, element);
  controls.enableDamping = false;
  controls.screenSpacePanning = true;
  return controls;
}
