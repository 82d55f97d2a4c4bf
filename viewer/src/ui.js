// The side panel: colour mode, class and object lists with checkboxes, the selection.

import { NONE_RGB, cssColour, paletteRgb } from "./colours.js";

function el(tag, { dataset = {}, ...props } = {}, children = []) {
  const node = Object.assign(document.createElement(tag), props);
  Object.assign(node.dataset, dataset);
  for (const child of children) node.append(child);
  return node;
}

function swatch(rgb) {
  const node = el("span", { className: "swatch" });
  node.style.background = cssColour(rgb);
  return node;
}

function checkRow(label, rgb, checked, onToggle, dataset) {
  const box = el("input", { type: "checkbox", checked });
  Object.assign(box.dataset, dataset);
  box.addEventListener("change", () => onToggle(box.checked));
  return el("label", { className: "row" }, [box, swatch(rgb), el("span", { textContent: label })]);
}

/** Class rows: one per class present (and "none"), hiding every Gaussian of that class. */
export function renderClasses(container, classes, actions) {
  container.replaceChildren();
  for (const c of classes) {
    const rgb = c.id >= 0 ? paletteRgb(c.id) : NONE_RGB;
    const label = `${c.name} (${c.instances} object${c.instances === 1 ? "" : "s"})`;
    container.append(checkRow(label, rgb, true, (on) => actions.setClassHidden(c.id, !on), { classId: c.id }));
  }
}

/** Object rows: a checkbox to hide it and a button to select it. */
export function renderObjects(container, instances, actions) {
  container.replaceChildren();
  for (const r of instances) {
    const row = checkRow(`#${r.id} ${r.label ?? "unlabelled"}`, paletteRgb(r.id - 1), true,
      (on) => actions.setInstanceHidden(r.id, !on), { instanceId: r.id });
    row.addEventListener("click", (event) => {
      if (event.target.tagName !== "INPUT") { event.preventDefault(); actions.select(r.id); }
    });
    row.dataset.instanceId = r.id;
    container.append(row);
  }
}

function size(record) {
  return record.bbox_max.map((v, i) => (v - record.bbox_min[i]).toFixed(2)).join(" × ");
}

/** The selection panel: class, score, size and counts of `record` (or a hint when null). */
export function renderSelection(container, record, onDownload) {
  container.replaceChildren();
  document.querySelectorAll("#objects .row").forEach((row) => {
    row.classList.toggle("selected", record !== null && Number(row.dataset.instanceId) === record.id);
  });
  if (record === null) {
    container.append(el("p", { className: "hint", textContent: "Click an object to select it." }));
    return;
  }
  const fields = [
    ["object", `#${record.id}`],
    ["class", record.label ?? "unlabelled"],
    ["score", record.score.toFixed(3)],
    ["size (m)", size(record)],
    ["Gaussians", String(record.n_gaussians)],
    ["views", String(record.n_views)],
  ];
  const table = el("dl", { id: "selection-fields" });
  for (const [key, value] of fields) {
    table.append(el("dt", { textContent: key }), el("dd", { textContent: value, dataset: { field: key } }));
  }
  const button = el("button", { id: "download", type: "button", textContent: "Download PLY" });
  button.addEventListener("click", onDownload);
  container.append(table, button);
}

export function showError(message) {
  const box = document.getElementById("error");
  box.textContent = message;
  box.hidden = false;
}

export function setStatus(message) {
  document.getElementById("status").textContent = message;
}
