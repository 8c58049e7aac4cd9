// The active tool (TCP): a selector in the Control card (on the first screen at laptop widths, with the
// session's other lease-holder controls), filled from GET /api/tools; a change is PUT
// /api/tool. The server takes it only at rest (409 otherwise), so the selector is disabled while the
// arm moves, and a refusal shows the server's words and puts the selector back on the active tool.

import { $, el, fmt } from "./dom.js";

/** Streams in which a tool change waits for the arm to be at rest and settled. */
const ALIVE = new Set(["streaming", "stopping", "stopped", "ending"]);

/** May the tool change now (the server's rule, for the selector): not moving. Pure. */
export function toolChangeAllowed(s) {
  if (!s) return false;
  return !ALIVE.has(s.state) || Boolean(s.at_rest && s.settled);
}

export class ToolPanel {
  /** api: Api; root: the card; canControl(): signed in with the lease. */
  constructor({ api, root, canControl }) {
    Object.assign(this, { api, root, canControl });
    this.select = $("#tool-select", root);
    this.info = $("#tool-info", root);
    this.message = $("#tool-message", root);
    this.tools = [];
    this.active = null;
    this.busy = false;
    this.select.addEventListener("change", () => this.change(this.select.value));
  }

  async refresh() {
    try {
      const answer = await this.api.get("/api/tools");
      this.tools = answer.tools;
      this.active = answer.active;
      this.select.replaceChildren(...this.tools.map((t) => el("option", { value: t.name }, t.name)));
      this.select.value = this.active;
      this.describe();
    } catch (exc) {
      this.show(`Tools: ${exc.message}`, false);
    }
  }

  describe() {
    const t = this.tools.find((x) => x.name === this.active);
    if (!t) return;
    const offset = t.xyzwpr.every((v) => v === 0) ? "the flange" : `XYZ ${t.xyzwpr.slice(0, 3).map((v) => fmt(v, 1)).join(" ")} mm`
      + `, WPR ${t.xyzwpr.slice(3).map((v) => fmt(v, 1)).join(" ")}°`;
    const payload = t.payload_kg === null ? "max payload" : `${fmt(t.payload_kg, 2)} kg`;
    this.info.textContent = `TCP: ${offset} · ${payload}`;
    this.root.dataset.tool = t.name;
  }

  /** Each telemetry message: the active tool as the server has it, the selector enabled at rest. */
  render(s) {
    const name = s.tool && s.tool.name;
    if (name && name !== this.active) {
      this.active = name;
      if (!this.tools.some((t) => t.name === name)) this.refresh(); // defined since (POST /api/tools)
      this.describe();
    }
    if (!this.busy && document.activeElement !== this.select && this.active) this.select.value = this.active;
    const allowed = toolChangeAllowed(s);
    this.select.disabled = this.busy || !allowed || !this.canControl();
    this.select.title = allowed ? "the TCP of jogs, pose targets and the pose shown" : "the tool changes only at rest";
  }

  async change(name) {
    if (name === this.active) return;
    this.busy = true;
    try {
      const t = await this.api.put("/api/tool", { name });
      this.active = t.name;
      this.describe();
      this.show(`tool ${t.name} active`, true);
    } catch (exc) {
      this.select.value = this.active;
      this.show(`Tool change refused: ${exc.message}`, false);
    } finally {
      this.busy = false;
    }
  }

  show(text, ok) {
    this.message.textContent = text;
    this.message.classList.toggle("ok", ok);
  }
}
