// The labelled Gaussians of a run: arrays from scene_labelled.ply, and their Spark splats.

import { PackedSplats, SplatMesh, utils } from "@sparkjsdev/spark";
import { NONE_RGB, SH_C0, clamp01, paletteRgb, sigmoid } from "./colours.js";
import { column, parsePly } from "./ply.js";

const DIM = 0.5; // colour factor of the objects around a selection

/** Decode the Gaussians and their ids; throws naming the file and the missing property. */
export function readLabelledScene(buffer, name) {
  const ply = parsePly(buffer, name);
  const get = (p) => column(ply, p);
  const n = ply.count;
  const means = interleave([get("x"), get("y"), get("z")], n);
  const dc = [get("f_dc_0"), get("f_dc_1"), get("f_dc_2")];
  const rgb = new Float32Array(3 * n);
  for (let i = 0; i < n; i++) {
    for (let c = 0; c < 3; c++) rgb[3 * i + c] = clamp01(0.5 + SH_C0 * dc[c][i]);
  }
  const logit = get("opacity");
  const opacity = new Float32Array(n);
  for (let i = 0; i < n; i++) opacity[i] = sigmoid(logit[i]);
  const scales = interleave([get("scale_0"), get("scale_1"), get("scale_2")], n).map(Math.exp);
  const quats = interleave([get("rot_0"), get("rot_1"), get("rot_2"), get("rot_3")], n);
  const instanceIds = column(ply, "instance_id", Int32Array);
  const classIds = column(ply, "semantic_id", Int32Array);
  return { ply, n, means, rgb, opacity, scales, quats, instanceIds, classIds };
}

function interleave(columns, n) {
  const k = columns.length;
  const out = new Float32Array(k * n);
  for (let i = 0; i < n; i++) for (let c = 0; c < k; c++) out[k * i + c] = columns[c][i];
  return out;
}

/** A SplatMesh of the scene's Gaussians (quaternions wxyz in the file, xyzw in Spark). */
export function buildSplats(scene) {
  const packed = new PackedSplats({ maxSplats: scene.n });
  const array = packed.ensureSplats(scene.n);
  const { means: m, scales: s, quats: q, rgb: c, opacity: a } = scene;
  for (let i = 0; i < scene.n; i++) {
    const norm = Math.hypot(q[4 * i], q[4 * i + 1], q[4 * i + 2], q[4 * i + 3]) || 1;
    utils.setPackedSplat(
      array, i,
      m[3 * i], m[3 * i + 1], m[3 * i + 2],
      s[3 * i], s[3 * i + 1], s[3 * i + 2],
      q[4 * i + 1] / norm, q[4 * i + 2] / norm, q[4 * i + 3] / norm, q[4 * i] / norm,
      a[i], c[3 * i], c[3 * i + 1], c[3 * i + 2],
    );
  }
  packed.numSplats = scene.n;
  packed.needsUpdate = true;
  return { packed, mesh: new SplatMesh({ packedSplats: packed }) };
}

/** Whether Gaussian `i` is shown under the current hide/show choices. */
export function isVisible(scene, view, i) {
  return !view.hiddenInstances.has(scene.instanceIds[i]) && !view.hiddenClasses.has(scene.classIds[i]);
}

/** The display colour of Gaussian `i` for `view.mode` ("instance", "class" or "rgb"). */
function displayRgb(scene, view, i) {
  if (view.mode === "rgb") return [scene.rgb[3 * i], scene.rgb[3 * i + 1], scene.rgb[3 * i + 2]];
  const id = view.mode === "instance" ? scene.instanceIds[i] - 1 : scene.classIds[i];
  return id >= 0 ? paletteRgb(id) : NONE_RGB;
}

/** Rewrite every splat's colour and opacity for `view` (mode, hidden sets, selection). */
export function applyView(scene, splats, view) {
  const array = splats.packed.packedArray;
  const cache = new Map();
  for (let i = 0; i < scene.n; i++) {
    const key = view.mode === "rgb" ? -2 : view.mode === "instance" ? scene.instanceIds[i] : scene.classIds[i];
    let rgb = view.mode === "rgb" ? displayRgb(scene, view, i) : cache.get(key);
    if (rgb === undefined) { rgb = displayRgb(scene, view, i); cache.set(key, rgb); }
    const dim = view.selected !== null && scene.instanceIds[i] !== view.selected ? DIM : 1;
    const alpha = isVisible(scene, view, i) ? scene.opacity[i] : 0;
    utils.setPackedSplatRgba(array, i, rgb[0] * dim, rgb[1] * dim, rgb[2] * dim, alpha);
  }
  splats.packed.needsUpdate = true;
  splats.mesh.updateVersion();
}

/** Indices of the Gaussians of instance `id`. */
export function membersOf(scene, id) {
  const out = [];
  for (let i = 0; i < scene.n; i++) if (scene.instanceIds[i] === id) out.push(i);
  return out;
}

const PICK_SIGMAS = 2; // a splat covers the pixels within 2 standard deviations of its centre
const PICK_MIN_PX = 2;
const PICK_MIN_OPACITY = 0.2;

/**
 * The instance of the front-most visible Gaussian whose screen footprint covers `pixel`
 * ({x, y, width, height} in CSS pixels of the canvas), or null (background or no instance).
 * Spark's ellipsoid raycast leaves gaps between sparse splats; the footprint matches what is
 * drawn.
 */
export function instanceAt(scene, view, camera, pixel) {
  const e = camera.matrixWorldInverse.elements;
  const focal = pixel.height / 2 / Math.tan((camera.fov * Math.PI) / 360);
  const cx = pixel.width / 2;
  const cy = pixel.height / 2;
  let best = -1;
  let bestDepth = Infinity;
  const m = scene.means;
  const s = scene.scales;
  for (let i = 0; i < scene.n; i++) {
    if (scene.opacity[i] < PICK_MIN_OPACITY || !isVisible(scene, view, i)) continue;
    const [x, y, z] = [m[3 * i], m[3 * i + 1], m[3 * i + 2]];
    const depth = -(e[2] * x + e[6] * y + e[10] * z + e[14]); // camera looks down -z
    if (depth <= camera.near || depth >= bestDepth) continue;
    const u = cx + (focal * (e[0] * x + e[4] * y + e[8] * z + e[12])) / depth;
    const v = cy - (focal * (e[1] * x + e[5] * y + e[9] * z + e[13])) / depth;
    const sigma = Math.max(s[3 * i], s[3 * i + 1], s[3 * i + 2]);
    const radius = Math.max(PICK_MIN_PX, (PICK_SIGMAS * sigma * focal) / depth);
    if ((u - pixel.x) ** 2 + (v - pixel.y) ** 2 <= radius * radius) { best = i; bestDepth = depth; }
  }
  return best >= 0 && scene.instanceIds[best] > 0 ? scene.instanceIds[best] : null;
}

/** Robust bounds (2nd-98th percentile per axis) of the Gaussian centres: [min, max]. */
export function robustBounds(scene) {
  const lo = [];
  const hi = [];
  for (let c = 0; c < 3; c++) {
    const v = new Float32Array(scene.n);
    for (let i = 0; i < scene.n; i++) v[i] = scene.means[3 * i + c];
    v.sort();
    lo.push(v[Math.floor(0.02 * (scene.n - 1))]);
    hi.push(v[Math.ceil(0.98 * (scene.n - 1))]);
  }
  return [lo, hi];
}
