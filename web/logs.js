// Session logs: the list from /api/sessions with download links, and a plot of one log's joint
// velocities as a percentage of each joint's limit (so all joints share one axis).

import { $, el, fmt } from "./dom.js";
import { axisUnits, envelopeByTime, parseSessionLog, timeTicks, velocities } from "./sessionlog.js";

const JOINT_COLORS = ["#4fb3ff", "#7ddc6f", "#ffcc4d", "#ff8a3d", "#d98cff", "#ff5f7a", "#5fe0d0", "#c0c0c0", "#a0a0ff"];

export class LogsPanel {
  constructor({ api, root, limits, onError }) {
    Object.assign(this, { api, root, limits, onError });
    this.list = $("#log-list", root);
    this.canvas = $("#log-plot", root);
    this.summary = $("#log-summary", root);
    this.title = $("#log-title", root);
    this.axes = $("#log-axes", root);
    this.selected = null;
    this.plotted = null;
    $("#log-refresh", root).addEventListener("click", () => this.refresh());
    $("#log-fit", root).addEventListener("change", () => this.plotted && this.draw(this.plotted));
    new ResizeObserver(() => this.plotted && this.draw(this.plotted)).observe(this.canvas);
  }

  async refresh() {
    let logs;
    try {
      logs = await this.api.get("/api/sessions");
    } catch (exc) {
      this.onError(`Session logs: ${exc.message}`);
      return;
    }
    if (logs.length === 0) {
      this.list.replaceChildren(el("li", { class: "muted" }, "no session logs yet"));
      return;
    }
    this.list.replaceChildren(...logs.map((log) => el("li", { class: log.name === this.selected ? "selected" : "" },
      el("button", { type: "button", class: "link", onclick: () => this.plot(log.name), "data-log": log.name },
        log.name.replace(/\.srvlog$/, "")),
      el("span", { class: "muted" }, ` ${(log.bytes / 1024).toFixed(0)} KiB · ${new Date(log.modified_unix * 1000)
        .toLocaleString()} `),
      el("a", { href: `/api/sessions/${encodeURIComponent(log.name)}`, download: log.name }, "download"))));
  }

  async plot(name) {
    this.selected = name;
    for (const li of this.list.children) {
      li.classList.toggle("selected", li.querySelector(`[data-log="${CSS.escape(name)}"]`) !== null);
    }
    this.title.textContent = `loading ${name}…`;
    try {
      const res = await fetch(`/api/sessions/${encodeURIComponent(name)}`, { cache: "no-store" });
      if (!res.ok) throw new Error(`${res.status} ${res.statusText}`);
      const log = parseSessionLog(await res.arrayBuffer());
      const lim = this.limits();
      // Limits of the running robot apply only if the log is of the same model.
      const sameModel = lim && log.header.model === lim.model;
      const limit = sameModel ? lim.vel_deg_s || lim.speed : null;
      this.plotted = { name, log, vel: velocities(log), limit, fraction: lim ? lim.limit_fraction : null,
        units: axisUnits(log) };
      const seconds = log.count > 1 ? log.t[log.count - 1] - log.t[0] : 0;
      this.title.textContent = `${name} · ${log.header.model} · ${log.count} commands · ${fmt(seconds, 1)} s`
        + (limit ? "" : " · limits unknown for this model: speeds shown unscaled");
      this.draw(this.plotted);
      this.renderSummary(this.plotted);
    } catch (exc) {
      this.title.textContent = `${name}: ${exc.message}`;
      this.onError(`Plot ${name}: ${exc.message}`);
    }
  }

  renderSummary({ vel, limit, log, units }) {
    const rows = vel.map((v, j) => {
      let peak = 0;
      for (const x of v) peak = Math.max(peak, Math.abs(x));
      const pct = limit ? (100 * peak) / limit[j] : NaN;
      const name = log.axes[j];
      return el("tr", { dataset: { joint: name } },
        el("td", {}, el("span", { class: "swatch", style: `background:${JOINT_COLORS[j % JOINT_COLORS.length]}` }),
          ` ${name}`),
        el("td", { class: "unit" }, `${units[j]}/s`),
        el("td", { class: "num peak" }, fmt(peak, 1)),
        el("td", { class: "num" }, limit ? fmt(limit[j], 0) : "—"),
        el("td", { class: `num ${pct >= 100 ? "bad" : ""}` }, limit ? fmt(pct, 1) : "—"));
    });
    // Every column says its unit; the speeds' unit is the axis' own (° or mm), in the unit column.
    this.summary.replaceChildren(
      el("thead", {}, el("tr", {}, el("th", {}, "axis"), el("th", {}, "unit"), el("th", {}, "peak speed (unit)"),
        el("th", {}, "limit (unit)"), el("th", {}, "peak (% of limit)"))),
      el("tbody", {}, rows));
  }

  draw({ vel, limit, fraction, log, units }) {
    const c = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    const w = c.clientWidth;
    const h = c.clientHeight;
    if (!w || !h) return;
    c.width = Math.round(w * dpr);
    c.height = Math.round(h * dpr);
    const g = c.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, h);
    const series = vel.map((v, j) => (limit ? v.map((x) => (100 * x) / limit[j]) : v));
    let peak = 0;
    for (const s of series) for (const x of s) peak = Math.max(peak, Math.abs(x));
    // Full scale shows the margin to the limit; "fit" shows the shape of slow motions.
    const fit = $("#log-fit", this.root).checked;
    const yMax = limit && !fit ? Math.max(110, peak * 1.05) : Math.max(limit ? 5 : 1, peak * 1.15);
    const left = 56;
    const bottom = 22; // the time axis
    const plotW = w - left - 8;
    const plotH = h - bottom;
    const y = (val) => plotH / 2 - (val / yMax) * (plotH / 2 - 10);
    g.font = "11px system-ui, sans-serif";
    g.fillStyle = "#9fb0c3";
    g.strokeStyle = "#2b3440";
    g.beginPath();
    g.moveTo(left, y(0)); g.lineTo(w, y(0));
    g.moveTo(left, plotH); g.lineTo(w, plotH);
    g.stroke();
    const mixed = new Set(units).size > 1;
    const unit = limit ? "%" : mixed ? " /s" : ` ${units[0]}/s`;
    for (const val of [yMax, 0, -yMax]) g.fillText(`${val.toFixed(0)}${unit}`, 2, y(val) + 4);
    // The time axis: seconds from the log's first command.
    const t0 = log.count ? log.t[0] : 0;
    const duration = log.count > 1 ? log.t[log.count - 1] - t0 : 0;
    const ticks = timeTicks(duration, Math.max(2, Math.floor(plotW / 70)));
    const xOf = (sec) => left + (duration > 0 ? (sec / duration) * plotW : 0);
    g.strokeStyle = "#2b3440";
    g.beginPath();
    for (const sec of ticks) {
      g.moveTo(xOf(sec), plotH); g.lineTo(xOf(sec), plotH + 4);
    }
    g.stroke();
    g.fillStyle = "#9fb0c3";
    for (const sec of ticks) {
      const text = `${+sec.toFixed(2)} s`;
      const tw = g.measureText(text).width;
      g.fillText(text, Math.min(w - tw - 2, Math.max(left, xOf(sec) - tw / 2)), plotH + 16);
    }
    c.dataset.ticks = ticks.map((sec) => +sec.toFixed(2)).join(" ");
    this.axes.textContent = `x: time since the first command (s), 0 to ${fmt(duration, 2)} s · y: speed, `
      + (limit ? "% of each axis' limit" : mixed ? units.map((u, j) => `${log.axes[j]} ${u}/s`).join(", ") : `${units[0]}/s`);
    if (limit && yMax >= 100) {
      this.hline(g, left, w, y(100), "#ff5f7a", [6, 4]);
      this.hline(g, left, w, y(-100), "#ff5f7a", [6, 4]);
      if (fraction) {
        this.hline(g, left, w, y(100 * fraction), "#ffcc4d", [2, 4]);
        this.hline(g, left, w, y(-100 * fraction), "#ffcc4d", [2, 4]);
      }
      g.fillStyle = "#ff5f7a";
      g.fillText("limit", w - 36, y(100) - 3);
    }
    const buckets = Math.max(1, Math.floor(plotW));
    // velocity k is between commands k and k + 1: placed at the later one's time
    const times = log.t.subarray(1, log.count);
    series.forEach((s, j) => {
      if (s.length === 0) return;
      const { lo, hi } = envelopeByTime(s, times, t0, duration, buckets);
      g.strokeStyle = JOINT_COLORS[j % JOINT_COLORS.length];
      g.lineWidth = 1.2;
      g.beginPath();
      for (let b = 0; b < buckets; b += 1) {
        const x = left + (b * plotW) / buckets;
        g.moveTo(x, y(lo[b]) + 0.5);
        g.lineTo(x, y(hi[b]) - 0.5);
        if (b + 1 < buckets) g.lineTo(left + ((b + 1) * plotW) / buckets, y((lo[b + 1] + hi[b + 1]) / 2));
      }
      g.stroke();
    });
  }

  hline(g, x0, x1, yy, color, dash) {
    g.save();
    g.strokeStyle = color;
    g.setLineDash(dash);
    g.beginPath();
    g.moveTo(x0, yy); g.lineTo(x1, yy);
    g.stroke();
    g.restore();
  }
}
