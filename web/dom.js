// Tiny DOM helpers: the console has no framework, these keep the view code short.

export const $ = (sel, root = document) => root.querySelector(sel);
export const $$ = (sel, root = document) => [...root.querySelectorAll(sel)];

/** el("button", {class: "x", onclick: f}, "text", child) -> element. */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else if (k === "dataset") Object.assign(node.dataset, v);
    else node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) {
    if (c !== undefined && c !== null && c !== false) node.append(c);
  }
  return node;
}

/** Set text only when it changed: telemetry repaints 20+ times a second. */
export function setText(node, text) {
  if (node && node.textContent !== text) node.textContent = text;
}

export const fmt = (v, digits = 1) => (Number.isFinite(v) ? v.toFixed(digits) : "—");
