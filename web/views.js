// Rendering of the live state (one telemetry message) into the panels. Pure view code: no requests.

import { $, el, fmt, setText } from "./dom.js";

const MODE_CLASS = {
  streaming: "ok", ready: "idle", connected: "idle", disconnected: "idle", ended: "idle",
  stopping: "warn", stopped: "warn", ending: "warn", fault: "bad",
};

/** Link phases in which the controller's own state (READY, STREAMING, ...) is live news. */
const LINK_HEALTHY = new Set(["connected", "fetching_tables", "waiting_ready", "streaming", "ending"]);

/** What the mode pill may say: the controller's state only while the link carries it. A READY beside
 * "link fault" contradicted itself: with the link down (fault, closed, idle), or no telemetry, the
 * last state heard is no longer true. Pure: (state, telemetry up?) -> {text, cls, title}. */
export function headerMode(s, telemetryUp = true) {
  const state = s.state || "";
  if (!telemetryUp) {
    return { text: "no telemetry", cls: "bad", title: `last heard: ${state || "nothing"} (not live)` };
  }
  if (state === "fault") return { text: "fault", cls: "bad", title: s.fault ? s.fault.message : "" };
  if (state === "disconnected" || state === "ended") return { text: state, cls: "idle", title: "" };
  const link = s.link || "";
  if (link === "fault" || (link && !LINK_HEALTHY.has(link) && state !== "ending")) {
    return { text: link === "fault" ? "link fault" : `link ${link}`, cls: "bad",
      title: `controller state ${state} is not live: ${s.link_error || `the link is ${link}`}` };
  }
  return { text: state || "—", cls: MODE_CLASS[state] || "idle", title: "" };
}

/** ``you``: our operator's name where this console holds the lease (its buttons say so too): the pill
 * and the Take/Release buttons must agree, with or without live telemetry. */
export function renderStatus(s, telemetryUp = true, you = "") {
  const mode = $("#mode");
  const m = headerMode(s, telemetryUp);
  setText(mode, m.text);
  mode.className = `pill mode ${m.cls}`;
  mode.title = m.title;
  setText($("#link"), `link ${s.link || "—"}`);
  $("#link").title = s.link_error || "";
  // Short in the one-line header (the stop reason needs the room); the address is in the tooltip.
  setText($("#model"), `${s.model || ""}${s.simulated ? " · sim" : ""}`);
  $("#model").title = `${s.model || ""}${s.simulated ? " · simulator" : ""} ${s.robot ? `@ ${s.robot}` : ""}`;
  const why = s.state === "fault" && s.fault ? `fault: ${s.fault.message}`
    : s.stop_reason && ["stopping", "stopped"].includes(s.state)
      ? `stopped: ${s.stop_reason}${s.resumable ? " (resumable)" : ""}`
      : s.link === "fault" && s.link_error ? `link fault: ${s.link_error}`
        : ["connected", "ended"].includes(s.state) && s.not_ready ? `not ready: ${s.not_ready}` : "";
  setText($("#stop-reason"), why);
  $("#stop-reason").title = why;
  renderHolder(s, you);
}

/** Who has control: "you (name)" where this console holds the lease, else the server's holder. */
export function renderHolder(s, you = "") {
  const other = s && s.lease && s.lease.held ? s.lease.client : null;
  setText($("#lease-holder"), you ? `control: you (${you})` : other ? `control: ${other}` : "control: free");
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

/** A trajectory replay's progress (POST /api/trajectory): played share, time, and why it ended early. */
export function renderReplay(s) {
  const t = s.trajectory;
  const row = $("#replay-row");
  row.hidden = !t;
  if (!t) return;
  const share = t.total_s > 0 ? Math.min(1, t.time_s / t.total_s) : 1;
  $("#replay-progress").value = share;
  row.dataset.state = t.state;
  const what = t.state === "ended" ? `ended: ${t.reason || "left before its end"}`
    : t.state === "paused" ? "paused (resume continues it)" : t.state;
  setText($("#replay-info"), `${fmt(share * 100, 0)} % · ${fmt(t.time_s, 1)} / ${fmt(t.total_s, 1)} s · ${what}`);
}

/** Where each pose name lives in ``cart_servo``, which is always X Y Z W P R (a Janome's R, the
 * rotation about Z, is in slot 5 like FANUC's R: its 4-name row showed slot 3, W, as R). */
const POSE_SLOT = { X: 0, Y: 1, Z: 2, W: 3, P: 4, R: 5 };

export function poseSlots(robot) {
  const names = (robot && robot.pose_names) || ["X", "Y", "Z", "W", "P", "R"];
  if (robot && Array.isArray(robot.pose_slots) && robot.pose_slots.length === names.length) {
    return names.map((n, i) => [n, robot.pose_slots[i]]);
  }
  return names.map((n, i) => [n, n in POSE_SLOT ? POSE_SLOT[n] : i]);
}

/** The flange or tool pose from the controller's feedback, named as the backend names it. */
export function renderPose(s, robot) {
  const slots = poseSlots(robot);
  const names = slots.map(([n]) => n);
  const head = $("#pose-head");
  if (head.dataset.names !== names.join()) {
    head.dataset.names = names.join();
    head.replaceChildren(...names.map((n) => el("th", {}, n)));
    $("#pose-row").replaceChildren(...names.map((n) => el("td", { id: `pose-${n}` }, "—")));
  }
  const c = s.cart_servo || [];
  for (const [n, slot] of slots) setText($(`#pose-${n}`), fmt(c[slot], 1));
}

/** Joint rows: position in its range, then velocity, acceleration and jerk as % of their limits. */
export class JointTable {
  constructor(tbody) {
    this.tbody = tbody;
    this.rows = [];
  }

  build(names) {
    this.rows = names.map((name) => {
      const cells = { pos: el("td", { class: "num" }), range: rangeBar(), vel: bar(), acc: bar(), jerk: bar() };
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
        cells.range.set(((qm - axis.min) / (axis.max - axis.min)) * 100, `${fmt(axis.min, 0)}…${fmt(axis.max, 0)}`);
      }
      ["vel", "acc", "jerk"].forEach((key, k) => {
        const v = s[key] ? Math.abs(s[key][i]) : NaN;
        const pct = limitsNow[k][i] ? (100 * v) / limitsNow[k][i] : NaN;
        cells[key].set(pct, Number.isFinite(pct) ? `${fmt(pct, 0)}%` : "—", warnFraction);
      });
    });
  }
}

/** Where the axes are: the controller's feedback once it reports, else the last command. */
export function axisPositions(s) {
  return (s.status_received > 0 ? s.q_servo : s.q_cmd) || [];
}

/** A joint's position in its range: a marker on a track, the range's text beside the track. */
function rangeBar() {
  const marker = el("span", { class: "marker" });
  const label = el("span", { class: "label" });
  const node = el("span", { class: "range" }, el("span", { class: "track" }, marker), label);
  return {
    node,
    set(pct, text) {
      const p = Number.isFinite(pct) ? Math.max(0, Math.min(100, pct)) : 0;
      marker.style.left = `calc(${p}% - ${(p / 100) * 4}px)`; // the 4 px marker stays inside the track
      setText(label, text);
    },
  };
}

/** A share of a limit: a fill under its percentage. */
function bar() {
  const fill = el("span", { class: "fill" });
  const label = el("span", { class: "label" });
  const node = el("span", { class: "bar" }, fill, label);
  return {
    node,
    set(pct, text, warnFraction = 0.9) {
      const p = Number.isFinite(pct) ? Math.max(0, Math.min(100, pct)) : 0;
      fill.style.width = `${p}%`;
      fill.className = `fill ${pct >= 100 ? "bad" : pct >= 100 * warnFraction ? "warn" : "ok"}`;
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

/** When an alarm happened: the wall clock (the service's, else when this console first saw it) and
 * the controller's own time stamp when it sent one. */
export function alarmWhen(a, firstSeenUnix) {
  const unix = Number.isFinite(a.time_unix) ? a.time_unix : firstSeenUnix;
  const parts = [];
  if (Number.isFinite(unix)) {
    const d = new Date(unix * 1000);
    const hms = d.toLocaleTimeString([], { hour: "2-digit", minute: "2-digit", second: "2-digit", hour12: false });
    parts.push(`${Number.isFinite(a.time_unix) ? "" : "seen "}${hms}.${String(d.getMilliseconds()).padStart(3, "0")}`);
  }
  if (Number.isFinite(a.controller_time_ms)) parts.push(`controller ${a.controller_time_ms} ms`);
  return parts.join(" · ");
}

/** The identity of an alarm occurrence, to remember when the console first saw it. */
const alarmKey = (a) => `${a.code}|${a.message}|${a.time_unix ?? ""}|${a.controller_time_ms ?? ""}`;
const firstSeen = new Map();

/** A controller's warning reaches the servo process too (the service forwards each one it lists), so
 * it is in ``alarms``/``alarm_history`` and again in ``warnings``/``warning_history``; the servo
 * process's own (session log, Janome link) are only in its lists. Its warnings that no alarm entry
 * stands for, oldest first: each pairs with the newest unpaired warning alarm of the same code and
 * message stamped within SAME_WITHIN_S (both lists keep the order they happened in). */
const SAME_WITHIN_S = 5;
export function servoOnlyWarnings(warnings, alarms) {
  const unpaired = (alarms || []).filter((a) => a.warning);
  const near = (a, w) => !(Number.isFinite(a.time_unix) && Number.isFinite(w.time_unix))
    || Math.abs(a.time_unix - w.time_unix) < SAME_WITHIN_S;
  const out = [];
  for (const w of [...(warnings || [])].reverse()) {
    const i = unpaired.findLastIndex((a) => a.code === w.code && (a.message || a.code) === w.message && near(a, w));
    if (i >= 0) unpaired.splice(i, 1);
    else out.push(w);
  }
  return out.reverse();
}

/** The history, oldest first: the service's ``alarm_history`` (else what this console saw) and the
 * servo process's warnings not in it (``warning_history``, kept across resets), by wall clock. */
export function mergedHistory(s, seen) {
  const alarms = Array.isArray(s.alarm_history) ? s.alarm_history : seen;
  const warnings = servoOnlyWarnings(s.warning_history, alarms).map((w) => ({ ...w, warning: true }));
  if (!warnings.length) return alarms;
  const t = (a) => (Number.isFinite(a.time_unix) ? a.time_unix : Infinity);
  return [...alarms, ...warnings].sort((a, b) => t(a) - t(b));  // stable: ties keep their order
}

/** Active: the fault (what stopped the session), the link error, then the controller's active alarms
 * and the servo process's active warnings, newest first. History, apart: see mergedHistory. Warnings
 * are marked as such in both. */
export function renderAlarms(s) {
  const box = $("#alarm-list");
  const now = Date.now() / 1000;
  const active = s.alarms || [];
  for (const a of active) if (!firstSeen.has(alarmKey(a))) firstSeen.set(alarmKey(a), { a, seen: now });
  const when = (a) => alarmWhen(a, firstSeen.has(alarmKey(a)) ? firstSeen.get(alarmKey(a)).seen : undefined);
  const items = [];
  if (s.state === "fault" && s.fault) items.push(alarmItem({ ...s.fault, kind: "fault" }, alarmWhen(s.fault)));
  if (s.link_error) items.push(el("li", { class: "alarm warn" }, el("b", {}, "link "), s.link_error));
  if (s.alarm_poll_error) {  // new controller alarms wait until its list can be read again
    items.push(el("li", { class: "alarm warn" }, el("b", {}, "alarm list "), `cannot be read: ${s.alarm_poll_error}`));
  }
  for (const a of [...active].reverse()) items.push(alarmItem({ ...a, kind: a.warning ? "warning" : "alarm" }, when(a)));
  const warnings = servoOnlyWarnings(s.warnings, active);
  for (const w of [...warnings].reverse()) items.push(alarmItem({ ...w, kind: "warning" }, when(w)));
  const history = mergedHistory(s, [...firstSeen.values()].map(({ a }) => a).slice(-50));
  const key = JSON.stringify([s.state, s.fault, s.link_error, s.alarm_poll_error, active, warnings, history]);
  if (box.dataset.key === key) return; // same content: keep the DOM (and any text selection)
  box.dataset.key = key;
  box.replaceChildren(...(items.length ? items : [el("li", { class: "muted" }, "no alarms")]));
  $("#alarm-count").textContent = String(active.filter((a) => !a.warning).length);
  $("#alarm-history-count").textContent = `(${history.length})`;
  $("#alarm-history").replaceChildren(...(history.length
    ? [...history].reverse().map((a) => alarmItem({ ...a, kind: a.warning ? "warning" : "alarm", past: true }, when(a)))
    : [el("li", { class: "muted" }, "no alarms seen")]));
}

function alarmItem(a, when) {
  const warning = a.kind === "warning";
  return el("li", { class: `alarm ${warning ? "warn" : "bad"}${a.past ? " past" : ""}`,
    dataset: { code: a.code || "", kind: a.kind } },
  el("div", {}, el("b", { class: "code" }, a.code || a.kind), " ",
    warning ? el("span", { class: "kind" }, "warning") : null, warning ? " " : null, a.message || ""),
  when ? el("div", { class: "when" }, when) : null,
  a.cause ? el("div", { class: "cause" }, el("span", { class: "muted" }, "cause: "), a.cause) : null,
  a.remedy ? el("div", { class: "remedy" }, el("span", { class: "muted" }, "remedy: "), a.remedy) : null);
}

/** Why a source is down, or "": its ``failure`` (the device, the reason and the fix, when the service
 * names them) else GET /api/inputs' errors and last_error. */
export function sourceFailure(row) {
  if (!row) return "";
  const errors = row.errors && typeof row.errors === "object" ? Object.entries(row.errors).filter(([, n]) => n > 0) : [];
  const counts = errors.map(([k, n]) => `${k.replaceAll("_", " ")} ×${n}`).join(", ");
  if (row.failure) {
    const f = row.failure;
    const text = typeof f === "string" ? f : f.message || [f.device, f.reason, f.fix && `Fix: ${f.fix}`].filter(Boolean).join(": ");
    return [text, counts && `(${counts})`].filter(Boolean).join(" ");
  }
  const down = row.connected === false;
  if (!down && !row.last_error && errors.length === 0) return "";
  const reason = row.last_error || (down ? "not connected" : "");
  return [reason, counts && `(${counts})`].filter(Boolean).join(" ");
}

/** A source whose device cannot be used (not merely quiet: that is "stale"). */
const isFailed = (row) => Boolean(row && (row.failure || row.connected === false));

/** Input sources, when the service runs with --inputs. ``s.inputs`` (telemetry): {enabled, active,
 * owner, sources: [{name, kind, rate_hz, age_s, stale, active}]}; ``detail``: GET /api/inputs, whose
 * rows add each source's connection and errors (a source that cannot be opened says why). */
export function renderInputs(section, s, detail = null) {
  const summary = s.inputs;
  const sources = summary && Array.isArray(summary.sources) ? summary.sources : [];
  section.hidden = !summary;
  if (!summary) return;
  setText($("#inputs-status", section), `${summary.enabled ? "enabled" : "disabled"} · in control: `
    + `${summary.active || "none"}${summary.owner ? ` · only ${summary.owner} may command` : ""}`);
  const enable = $("#inputs-enable", section);
  setText(enable, summary.enabled ? "Disable inputs" : "Enable inputs");
  enable.setAttribute("aria-pressed", String(Boolean(summary.enabled)));
  // The telemetry's row, completed by GET /api/inputs' (connection, errors) where polled.
  const full = new Map(((detail && detail.sources) || []).map((r) => [r.name, r]));
  const merged = (src) => ({ ...(full.get(src.name) || {}), ...src, failure: src.failure || (full.get(src.name) || {}).failure });
  const failures = sources.map((src) => [src.name, sourceFailure(merged(src))]).filter(([, why]) => why);
  const failed = new Set(sources.filter((src) => isFailed(merged(src))).map((src) => src.name));
  const stateOf = (src) => (failed.has(src.name) ? "failed" : src.stale ? "stale" : "live");
  const rows = sources.map((src) => el("tr", {
    class: failed.has(src.name) ? "bad-row" : src.stale ? "warn-row" : "", dataset: { source: src.name } },
  el("td", {}, src.name), el("td", {}, src.kind || ""), el("td", {}, stateOf(src)),
  el("td", { class: "num" }, Number.isFinite(src.rate_hz) ? `${fmt(src.rate_hz, 0)} Hz` : "—"),
  el("td", { class: "num" }, Number.isFinite(src.age_s) ? `${fmt(src.age_s * 1000, 0)} ms` : "—"),
  el("td", {}, src.active ? "in control" : "")));
  const key = JSON.stringify([sources.map((r) => [r.name, r.stale, r.active, Math.round(r.rate_hz || 0),
    Math.round((r.age_s || 0) * 100)]), failures, [...failed]]);
  const tbody = $("tbody", section);
  if (tbody.dataset.key === key) return;
  tbody.dataset.key = key;
  tbody.replaceChildren(...(rows.length ? rows : [el("tr", {}, el("td", { colspan: "6", class: "muted" },
    "no sources configured"))]));
  $("#inputs-failures", section).replaceChildren(...failures.map(([name, why]) => el("li",
    { dataset: { source: name } }, el("b", {}, `${name}: `), why)));
}
