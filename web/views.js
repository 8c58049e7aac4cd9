// Rendering of the live state (one telemetry message) into the panels. Pure view code: no requests.

import { $, el, fmt, setText } from "./dom.js";

const MODE_CLASS = {
  streaming: "ok", ready: "idle", connected: "idle", disconnected: "idle", ended: "idle",
  stopping: "warn", stopped: "warn", ending: "warn", fault: "bad",
};

export function renderStatus(s) {
  const mode = $("#mode");
  setText(mode, s.state || "—");
  mode.className = `pill mode ${MODE_CLASS[s.state] || "idle"}`;
  setText($("#link"), `link ${s.link || "—"}`);
  setText($("#model"), `${s.model || ""}${s.simulated ? " · simulator" : ""} ${s.robot ? `@ ${s.robot}` : ""}`);
  const why = s.state === "fault" && s.fault ? `fault: ${s.fault.message}`
    : s.stop_reason && ["stopping", "stopped"].includes(s.state)
      ? `stopped: ${s.stop_reason}${s.resumable ? " (resumable)" : ""}` : "";
  setText($("#stop-reason"), why);
  setText($("#lease-holder"), s.lease && s.lease.held ? `control: ${s.lease.client}` : "control: free");
}

/** Why a Cartesian motion goes slower than asked or stops short (singularity, joint limit, ...). */
export function renderHeldBack(s) {
  const c = s.cartesian;
  const reasons = c && Array.isArray(c.held_back_by) ? c.held_back_by : [];
  const box = $("#held-back");
  box.hidden = reasons.length === 0;
  if (reasons.length) {
    setText(box, `Cartesian motion held back: ${reasons.join(", ")} (${fmt(c.scale * 100, 0)} % of the speed asked)`);
  }
}

/** The flange or tool pose from the controller's feedback, named as the backend names it. */
export function renderPose(s, robot) {
  const names = (robot && robot.pose_names) || ["X", "Y", "Z", "W", "P", "R"];
  const head = $("#pose-head");
  if (head.dataset.names !== names.join()) {
    head.dataset.names = names.join();
    head.replaceChildren(...names.map((n) => el("th", {}, n)));
    $("#pose-row").replaceChildren(...names.map((n) => el("td", { id: `pose-${n}` }, "—")));
  }
  const c = s.cart_servo || [];
  names.forEach((n, i) => setText($(`#pose-${n}`), fmt(c[i], 1)));
}

/** Joint rows: position in its range, then velocity, acceleration and jerk as % of their limits. */
export class JointTable {
  constructor(tbody) {
    this.tbody = tbody;
    this.rows = [];
  }

  build(names) {
    this.rows = names.map((name) => {
      const cells = { pos: el("td", { class: "num" }), range: bar(), vel: bar(), acc: bar(), jerk: bar() };
      const tr = el("tr", { dataset: { joint: name } }, el("th", {}, name), cells.pos,
        el("td", {}, cells.range.node), el("td", {}, cells.vel.node), el("td", {}, cells.acc.node),
        el("td", {}, cells.jerk.node));
      return { tr, cells };
    });
    this.tbody.replaceChildren(...this.rows.map((r) => r.tr));
  }

  /** s: telemetry; robot: /api/robot (axes, ranges); limits: /api/limits (fallback limits). */
  render(s, robot, limits, warnFraction) {
    const q = axisPositions(s);
    const fallback = limits ? [limits.vel_deg_s || limits.speed, limits.acc_deg_s2 || limits.accel, limits.jerk_deg_s3]
      : [];
    const lim = (key, i) => (s[key] && s[key].some((v) => v > 0) ? s[key] : fallback[i] || []);
    const limitsNow = [lim("vel_limit", 0), lim("acc_limit", 1), lim("jerk_limit", 2)];
    this.rows.forEach(({ cells }, i) => {
      const axis = robot && robot.axes ? robot.axes[i] : null;
      const unit = axis && axis.unit === "mm" ? " mm" : "°";
      setText(cells.pos, `${fmt(q[i], 2)}${unit}`);
      if (axis) {
        // FANUC ranges are in the model convention: J3 there is J3 + j23 * J2 of the FANUC convention.
        const qm = i === 2 && robot.j23_factor ? q[2] + robot.j23_factor * q[1] : q[i];
        cells.range.set(((qm - axis.min) / (axis.max - axis.min)) * 100, `${fmt(axis.min, 0)}…${fmt(axis.max, 0)}`,
          true);
      }
      ["vel", "acc", "jerk"].forEach((key, k) => {
        const v = s[key] ? Math.abs(s[key][i]) : NaN;
        const pct = limitsNow[k][i] ? (100 * v) / limitsNow[k][i] : NaN;
        cells[key].set(pct, Number.isFinite(pct) ? `${fmt(pct, 0)}%` : "—", false, warnFraction);
      });
    });
  }
}

/** Where the axes are: the controller's feedback once it reports, else the last command. */
export function axisPositions(s) {
  return (s.status_received > 0 ? s.q_servo : s.q_cmd) || [];
}

function bar() {
  const fill = el("span", { class: "fill" });
  const label = el("span", { class: "label" });
  const node = el("span", { class: "bar" }, fill, label);
  return {
    node,
    set(pct, text, isPosition = false, warnFraction = 0.9) {
      const p = Number.isFinite(pct) ? Math.max(0, Math.min(100, pct)) : 0;
      if (isPosition) {
        fill.style.left = `calc(${p}% - 2px)`; // a marker at the position, not a fill
        fill.className = "fill marker";
      } else {
        fill.style.width = `${p}%`;
        fill.className = `fill ${pct >= 100 ? "bad" : pct >= 100 * warnFraction ? "warn" : "ok"}`;
      }
      setText(label, text);
    },
  };
}

export function renderTiming(s) {
  const us = (v) => (v ? `${fmt(v, 0)} µs` : "—");
  const rows = {
    "t-p50": us(s.latency_p50_us), "t-p99": us(s.latency_p99_us), "t-max": us(s.latency_max_us),
    "t-last": us(s.latency_last_us), "t-interval": s.status_interval_last_ms ? `${fmt(s.status_interval_last_ms, 2)} ms` : "—",
    "t-late": String(s.late_commands ?? "—"), "t-lost": String(s.status_lost ?? "—"),
    "t-dup": String(s.status_duplicated ?? "—"), "t-malformed": String(s.malformed ?? "—"),
    "t-sent": String(s.commands_sent ?? "—"), "t-received": String(s.status_received ?? "—"),
  };
  for (const [id, text] of Object.entries(rows)) setText($(`#${id}`), text);
  $("#t-late").classList.toggle("bad", s.late_commands > 0);
  $("#t-lost").classList.toggle("bad", s.status_lost > 0);
}

/** Fault (what stopped the session) first, then the controller's alarm history, newest first. */
export function renderAlarms(s) {
  const box = $("#alarm-list");
  const items = [];
  if (s.state === "fault" && s.fault) items.push(alarmItem({ ...s.fault, kind: "fault" }));
  if (s.link_error) items.push(el("li", { class: "alarm warn" }, el("b", {}, "link "), s.link_error));
  for (const a of [...(s.alarms || [])].reverse()) items.push(alarmItem({ ...a, kind: a.warning ? "warning" : "alarm" }));
  for (const w of [...(s.warnings || [])].reverse()) items.push(alarmItem({ ...w, kind: "warning" }));
  const key = JSON.stringify([s.state, s.fault, s.link_error, s.alarms, s.warnings]);
  if (box.dataset.key === key) return; // same content: keep the DOM (and any text selection)
  box.dataset.key = key;
  box.replaceChildren(...(items.length ? items : [el("li", { class: "muted" }, "no alarms")]));
  $("#alarm-count").textContent = String((s.alarms || []).filter((a) => !a.warning).length);
}

function alarmItem(a) {
  return el("li", { class: `alarm ${a.kind === "warning" ? "warn" : "bad"}`, dataset: { code: a.code || "" } },
    el("div", {}, el("b", { class: "code" }, a.code || a.kind), " ", a.message || ""),
    a.cause ? el("div", { class: "cause" }, el("span", { class: "muted" }, "cause: "), a.cause) : null,
    a.remedy ? el("div", { class: "remedy" }, el("span", { class: "muted" }, "remedy: "), a.remedy) : null);
}

/** Input sources, when the service runs with --inputs: {enabled, active, sources: [{name, kind,
 * rate_hz, age_s, stale, active}]}. */
export function renderInputs(section, s) {
  const summary = s.inputs;
  const sources = summary && Array.isArray(summary.sources) ? summary.sources : [];
  section.hidden = !summary;
  if (!summary) return;
  setText($("#inputs-status", section), `${summary.enabled ? "enabled" : "disabled"} · in control: `
    + `${summary.active || "none"}${summary.owner ? ` · only ${summary.owner} may command` : ""}`);
  const rows = sources.map((src) => el("tr", { class: src.stale ? "warn-row" : "", dataset: { source: src.name } },
    el("td", {}, src.name), el("td", {}, src.kind || ""), el("td", {}, src.stale ? "stale" : "live"),
    el("td", { class: "num" }, Number.isFinite(src.rate_hz) ? `${fmt(src.rate_hz, 0)} Hz` : "—"),
    el("td", { class: "num" }, Number.isFinite(src.age_s) ? `${fmt(src.age_s * 1000, 0)} ms` : "—"),
    el("td", {}, src.active ? "in control" : "")));
  const key = JSON.stringify(sources.map((r) => [r.name, r.stale, r.active, Math.round(r.rate_hz || 0),
    Math.round((r.age_s || 0) * 100)]));
  const tbody = $("tbody", section);
  if (tbody.dataset.key === key) return;
  tbody.dataset.key = key;
  tbody.replaceChildren(...(rows.length ? rows : [el("tr", {}, el("td", { colspan: "6", class: "muted" },
    "no sources configured"))]));
}
