// Teach points: the list from GET /api/points with "Go to" (POST /api/points/{name}/move) and delete,
// and a name to teach the arm's current position under (POST /api/points/{name}). A refusal shows the
// server's own words: what was wrong and what to do next.

import { $, el, fmt } from "./dom.js";

export class PointsPanel {
  /** api: Api; root: the card; onRender(): lets the console enable the new buttons (data-needs). */
  constructor({ api, root, onRender }) {
    Object.assign(this, { api, root, onRender });
    this.list = $("#point-list", root);
    this.message = $("#point-message", root);
    $("#point-teach-form", root).addEventListener("submit", (ev) => { ev.preventDefault(); this.teach(); });
    $("#point-refresh", root).addEventListener("click", () => this.refresh());
  }

  async refresh() {
    try {
      this.render(await this.api.get("/api/points"));
    } catch (exc) {
      this.show(`Points: ${exc.message}`, false);
    }
  }

  render(points) {
    if (!points.length) {
      this.list.replaceChildren(el("li", { class: "muted" }, "no points taught"));
    } else {
      this.list.replaceChildren(...points.map((p) => el("li", { dataset: { point: p.name } },
        el("b", {}, p.name),
        el("span", { class: "muted small-text", title: `joints ${p.joints.map((q) => fmt(q, 2)).join(" ")}` },
          p.xyzwpr.length ? p.xyzwpr.slice(0, 3).map((v) => fmt(v, 1)).join(" ") : p.joints.map((q) => fmt(q, 1)).join(" ")),
        // The pose is that tool's TCP: a point taught with another tool shows where that tool's tip was.
        p.tool ? el("span", { class: "muted small-text point-tool", title: "the tool whose TCP the pose is" },
          `@${p.tool}`) : false,
        el("button", { type: "button", class: "small", "data-needs": "lease", "data-moves": "", "aria-label": `go to ${p.name}`,
          onclick: () => this.goTo(p.name) }, "Go to"),
        el("button", { type: "button", class: "small", "data-needs": "lease", "aria-label": `delete ${p.name}`,
          onclick: () => this.remove(p.name) }, "×"))));
    }
    if (this.onRender) this.onRender();
  }

  async teach() {
    const name = $("#point-name", this.root).value.trim();
    try {
      // A name already taught is replaced only when the operator says so (the server refuses otherwise).
      // The state is read now, beside the points: the telemetry can be a frame behind, and an arm that
      // settled since then was taken for a moving one (no question, then the server refused the name).
      const [points, s] = await Promise.all([this.api.get("/api/points"), this.api.get("/api/state")]);
      const old = points.find((p) => p.name === name);
      // Asked only where teaching can succeed: elsewhere the server's refusal says what to do first
      // (it checks the state before the name), rather than a question answered for nothing.
      const teachable = ["streaming", "stopped"].includes(s.state) && s.status_live && s.settled;
      if (old && teachable) {
        const by = old.taught_by ? ` by ${old.taught_by}` : "";
        const at = old.taught_unix ? ` at ${new Date(old.taught_unix * 1000).toLocaleString()}` : "";
        if (!window.confirm(`Replace the point ${name} (taught${by}${at}) with the arm's position now?`)) {
          this.show(`kept ${name}: nothing taught`, true);
          return;
        }
      }
      const p = await this.api.post(`/api/points/${encodeURIComponent(name)}${old && teachable ? "?replace=true" : ""}`);
      this.show(`taught ${p.name}`, true);
      await this.refresh();
    } catch (exc) {
      this.show(`Teach refused: ${exc.message}`, false);
    }
  }

  async goTo(name) {
    try {
      await this.api.post(`/api/points/${encodeURIComponent(name)}/move`, {});
      this.show(`going to ${name}`, true);
    } catch (exc) {
      this.show(`Go to ${name} refused: ${exc.message}`, false);
    }
  }

  async remove(name) {
    if (!window.confirm(`Delete the point ${name}?`)) return;
    try {
      await this.api.del(`/api/points/${encodeURIComponent(name)}`);
      this.show(`deleted ${name}`, true);
      await this.refresh();
    } catch (exc) {
      this.show(`Delete refused: ${exc.message}`, false);
    }
  }

  show(text, ok) {
    this.message.textContent = text;
    this.message.classList.toggle("ok", ok);
  }
}
