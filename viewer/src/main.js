// dcseg viewer: the labelled Gaussians of one run, coloured by instance or class, with picking,
// hide/show and download of the selected object. Configuration comes from the page (see
// dcseg/viewer/__init__.py); data requests carry the API key in a header, never in the URL.

import * as THREE from "three";
import { SparkRenderer } from "@sparkjsdev/spark";
import { fetchAll } from "./api.js";
import { frame, frameUp, makeControls, upVector } from "./camera.js";
import { subsetPly } from "./ply.js";
import { applyView, buildSplats, instanceAt, membersOf, readLabelledScene, robustBounds } from "./scene.js";
import { renderClasses, renderObjects, renderSelection, setStatus, showError } from "./ui.js";

const CLICK_SLOP_PX = 4; // a pointer that moved further was a drag of the camera, not a click
const FRAMES_AFTER_CHANGE = 8; // frames drawn after a change: Spark sorts and uploads over a few
const RUN_UP = "run"; // the panel's choice for a frame.json up vector that is no world axis

function readConfig() {
  const node = document.getElementById("dcseg-config");
  if (!node) throw new Error("page has no #dcseg-config");
  return JSON.parse(node.textContent);
}

function classSummary(scene, instances, labels) {
  const names = new Map(labels.map((l) => [l.id, l.name]));
  const present = new Set(scene.classIds);
  const counts = new Map();
  for (const r of instances) counts.set(r.label_id, (counts.get(r.label_id) ?? 0) + 1);
  return [...present].sort((a, b) => a - b).map((id) => ({
    id,
    name: id >= 0 ? names.get(id) ?? `class ${id}` : "none",
    instances: counts.get(id) ?? 0,
  }));
}

function download(bytes, name) {
  const url = URL.createObjectURL(new Blob([bytes], { type: "application/octet-stream" }));
  const link = Object.assign(document.createElement("a"), { href: url, download: name });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

/** The up axis to start with: frame.json's (when served and it states one), else the page's. */
function initialUp(config, frameBody) {
  const stated = frameBody === null ? null : frameUp(frameBody);
  if (stated !== null) return { up: stated, source: "frame.json" };
  return { up: config.up ?? "+z", source: "default" };
}

/** Offer frame.json's up vector (not a world axis) in the panel's up-axis choice. */
function offerRunUp(vector) {
  const option = document.createElement("option");
  option.value = RUN_UP;
  option.textContent = `run (${vector.map((v) => v.toFixed(2)).join(", ")})`;
  document.getElementById("up").prepend(option);
}

class Viewer {
  constructor(config, scene, instances, labels, frameBody = null) {
    this.config = config;
    this.frame = frameBody;
    this.scene = scene;
    this.instances = instances;
    this.labels = labels;
    this.records = new Map(instances.map((r) => [r.id, r]));
    this.view = { mode: "instance", hiddenInstances: new Set(), hiddenClasses: new Set(), selected: null };
    this.canvas = document.getElementById("canvas");
    this.renderer = new THREE.WebGLRenderer({ canvas: this.canvas, antialias: false });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    this.camera = new THREE.PerspectiveCamera(50, 1, 0.01, 100);
    this.three = new THREE.Scene();
    this.three.background = new THREE.Color(0x15171a);
    // Frames are drawn only after a change (camera, view, Spark's sort finishing): an idle
    // viewer costs nothing, which matters on CPUs rendering WebGL in software.
    this.pending = FRAMES_AFTER_CHANGE;
    this.three.add(new SparkRenderer({ renderer: this.renderer, onDirty: () => this.redraw(2) }));
    this.splats = buildSplats(scene);
    this.three.add(this.splats.mesh);
    this.controls = makeControls(this.camera, this.canvas);
    this.frames = 0;
  }

  redraw(frames = FRAMES_AFTER_CHANGE) {
    this.pending = Math.max(this.pending, frames);
  }

  start() {
    this.resize();
    new ResizeObserver(() => this.resize()).observe(this.canvas);
    // The run's up axis (frame.json); the panel's choice overrides it. `upSource` is for tests.
    const { up, source } = initialUp(this.config, this.frame);
    this.upSource = source;
    this.runUp = up;
    if (Array.isArray(up)) offerRunUp(up);
    this.setUp(Array.isArray(up) ? RUN_UP : up);
    this.bindPointer();
    this.bindPanel();
    this.refresh();
    this.renderer.setAnimationLoop(() => {
      if (this.pending <= 0) return;
      this.pending -= 1;
      this.renderer.render(this.three, this.camera);
      this.frames += 1;
    });
  }

  resize() {
    const { clientWidth: w, clientHeight: h } = this.canvas;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / Math.max(h, 1);
    this.camera.updateProjectionMatrix();
    this.redraw();
  }

  /** Orbit about up axis `name` (a world axis, or RUN_UP for frame.json's up vector). */
  setUp(name) {
    const up = upVector(name === RUN_UP ? this.runUp : name);
    this.controls.dispose();
    this.camera.up.copy(up);
    this.controls = makeControls(this.camera, this.canvas);
    this.controls.addEventListener("change", () => this.redraw());
    frame(this.camera, this.controls, robustBounds(this.scene), up);
    document.getElementById("up").value = name;
  }

  refresh() {
    applyView(this.scene, this.splats, this.view);
    this.redraw();
    const record = this.view.selected === null ? null : this.records.get(this.view.selected) ?? null;
    renderSelection(document.getElementById("selection"), record, () => this.downloadSelected());
  }

  select(id) {
    this.view.selected = id !== null && this.records.has(id) ? id : null;
    this.refresh();
  }

  bindPointer() {
    let down = null;
    this.canvas.addEventListener("pointerdown", (e) => { down = [e.clientX, e.clientY]; });
    this.canvas.addEventListener("pointerup", (e) => {
      if (down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) <= CLICK_SLOP_PX) {
        this.select(this.pick(e.clientX, e.clientY));
      }
      down = null;
    });
  }

  /** The instance under the viewport point (x, y) in CSS pixels, or null. */
  pick(x, y) {
    const rect = this.canvas.getBoundingClientRect();
    this.camera.updateMatrixWorld();
    const pixel = { x: x - rect.left, y: y - rect.top, width: rect.width, height: rect.height };
    return instanceAt(this.scene, this.view, this.camera, pixel);
  }

  /** Viewport CSS pixel of world point `xyz` (for tests and overlays). */
  project(xyz) {
    const p = new THREE.Vector3(...xyz).project(this.camera);
    const rect = this.canvas.getBoundingClientRect();
    return { x: rect.left + ((p.x + 1) / 2) * rect.width, y: rect.top + ((1 - p.y) / 2) * rect.height };
  }

  setInstanceHidden(id, hidden) {
    if (hidden) this.view.hiddenInstances.add(id); else this.view.hiddenInstances.delete(id);
    this.refresh();
  }

  setClassHidden(id, hidden) {
    if (hidden) this.view.hiddenClasses.add(id); else this.view.hiddenClasses.delete(id);
    this.refresh();
  }

  selectedPly() {
    if (this.view.selected === null) return null;
    return subsetPly(this.scene.ply, membersOf(this.scene, this.view.selected));
  }

  downloadSelected() {
    const bytes = this.selectedPly();
    if (bytes === null) return;
    const record = this.records.get(this.view.selected);
    const label = (record.label ?? "unlabelled").replace(/[^A-Za-z0-9_-]+/g, "_");
    download(bytes, `instance_${record.id}_${label}.ply`);
  }

  bindPanel() {
    for (const input of document.querySelectorAll("input[name=mode]")) {
      input.addEventListener("change", () => { this.view.mode = input.value; this.refresh(); });
    }
    document.getElementById("up").addEventListener("change", (e) => this.setUp(e.target.value));
    const actions = {
      setClassHidden: (id, hidden) => this.setClassHidden(id, hidden),
      setInstanceHidden: (id, hidden) => this.setInstanceHidden(id, hidden),
      select: (id) => this.select(id),
    };
    renderClasses(document.getElementById("classes"), classSummary(this.scene, this.instances, this.labels), actions);
    renderObjects(document.getElementById("objects"), this.instances, actions);
  }
}

async function main() {
  const config = readConfig();
  document.title = `dcseg · ${config.title}`;
  document.getElementById("title").textContent = config.title;
  setStatus("loading…");
  const urls = config.frame ? { ...config.files, frame: config.frame } : config.files;
  const responses = await fetchAll(urls);
  const [buffer, instances, labels, frameBody] = await Promise.all([
    responses.scene.arrayBuffer(), responses.instances.json(), responses.labels.json(),
    responses.frame ? responses.frame.json() : null,
  ]);
  const scene = readLabelledScene(buffer, config.files.scene);
  const viewer = new Viewer(config, scene, instances.instances, labels.labels, frameBody);
  viewer.start();
  setStatus(`${scene.n} Gaussians, ${instances.instances.length} objects`);
  return viewer;
}

// For tests and scripting: `ready` resolves to the Viewer; `loaded` turns true with it.
const hook = { loaded: false, error: null, viewer: null };
hook.ready = main().then(
  (viewer) => { hook.viewer = viewer; hook.loaded = true; return viewer; },
  (error) => { hook.error = String(error.message ?? error); showError(hook.error); throw error; },
);
window.dcsegViewer = hook;
