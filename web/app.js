// Operator console: wires the panels to the API and the telemetry socket.
// Safety-relevant behaviour lives in jog.js (hold-to-run) and here (STOP, focus/connection loss).

import { Api } from "./api.js";
import { ArmView } from "./armview.js";
import { $, $$ } from "./dom.js";
import { IoPanel } from "./io.js";
import { JOG, JogPad } from "./jog.js";
import { installKeys } from "./keys.js";
import { Lease } from "./lease.js";
import { LogsPanel } from "./logs.js";
import { PointsPanel } from "./points.js";
import { ToolPanel } from "./tools.js";
import { TargetForm } from "./target.js";
import { Telemetry } from "./telemetry.js";
import {
  JointTable, renderAlarms, renderHeldBack, renderHolder, renderInputs, renderPose, renderReplay, renderStatus,
  renderTiming,
} from "./views.js";

const ROBOT_POLL_MS = 100; // arm view refresh (FK on the server)
const INPUTS_POLL_MS = 1000; // GET /api/inputs: each source's connection and errors
// A start answers once the stream runs, or with the reason it cannot (409): that takes up to the service's
// start_timeout_s (5 s) and request timeout (2 s), after bringing up a new servo process if one died.
const START_TIMEOUT_MS = 15000;
const RESET_TIMEOUT_MS = 10000;

const api = new Api();
const ui = { tel: null, limits: null, robot: null, lastMode: null, telemetryUp: false, inputs: null };

// ------------------------------------------------------------------ messages
let messageTimer = null;
/** ``kind`` "stopped": an error saying why the console stopped the arm (or why its STOP failed). It
 * stays until another message or until the arm streams again: an operator back at the console after
 * a few seconds must still see why the arm stands (the server's stop reason says only "stop requested"). */
function say(text, kind = "info") {
  const box = $("#message");
  box.textContent = text;
  box.className = `banner ${kind === "info" ? "info" : "bad"}`;
  box.hidden = false;
  clearTimeout(messageTimer);
  ui.stoppedMessage = kind === "stopped";
  if (!ui.stoppedMessage) messageTimer = setTimeout(() => { box.hidden = true; }, kind === "error" ? 8000 : 4000);
}
const sayError = (text) => say(text, "error");
const sayStopped = (text) => say(text, "stopped");

// ------------------------------------------------------------------ settings
/** Whether the robot's backend takes twists (Cartesian jog); others jog their axes directly. */
const cartesianJog = () => !ui.robot || ui.robot.cartesian_jog !== false;

function settings() {
  const pick = (name) => $(`input[name="${name}"]:checked`).value;
  return {
    kind: cartesianJog() ? pick("jog-kind") : "joint",
    frame: pick("frame"),
    step: pick("jog-mode") === "step",
    stepMm: Number($("#step-mm").value),
    stepDeg: Number($("#step-deg").value),
    speed: Number($("#speed").value) / 100,
  };
}

function showSpeed() {
  const s = settings();
  const pct = Math.round(s.speed * 100);
  $("#speed-out").textContent = s.kind === "joint"
    ? `${pct} % · ${Math.round(s.speed * JOG.JOINT_FRACTION * 100)} % of axis limits`
    : `${pct} % · ${Math.round(s.speed * JOG.MAX_LINEAR_MM_S)} mm/s · ${Math.round(s.speed * JOG.MAX_ANGULAR_DEG_S)} °/s`;
}

// ------------------------------------------------------------------ panels
const jog = new JogPad({
  api, root: $("#jog-pad"), settings, onError: sayError, onLost: (why) => stop(false, why),
});
const io = new IoPanel({ api, root: $("#io-buttons"), onError: sayError });
const logs = new LogsPanel({ api, root: $("#logs-card"), limits: () => ui.limits, onError: sayError });
const arm = new ArmView($("#arm-side"), $("#arm-top"));
const joints = new JointTable($("#joint-rows"));
const points = new PointsPanel({
  api, root: $("#points-card"), onRender: () => refreshControls(),
});
const tools = new ToolPanel({ api, root: $("#control-card"), canControl: () => api.signedIn && lease.held });
const target = new TargetForm({ api, root: $("#target-form"), telemetry: () => ui.tel, robot: () => ui.robot });
const lease = new Lease({
  api,
  onChange: (held, why) => {
    if (!held) jog.end(); // jogs would be refused anyway; STOP still works without the lease
    // Refused while the telemetry was lost: it may be a restarted service, known once it reports.
    if (!held && why.startsWith("control lost") && !ui.telemetryUp) ui.lostWhileBlind = true;
    if (why) (held ? say : sayError)(why);
    refreshControls();
  },
});

// Without telemetry the operator cannot see what the arm does: the console stops a held jog then, and
// starts no motion either (STOP, End and Reset still work).
const BLIND = "telemetry lost: the console cannot show what the arm does, so it moves nothing until the "
  + "telemetry is live again (STOP still works); check the service and the network";

/** Enable what the operator may do now: data-needs="signin" or "lease"; data-moves: also live telemetry. */
function refreshControls() {
  const signedIn = api.signedIn;
  $("#signin").hidden = signedIn;
  $("#signed").hidden = !signedIn;
  $("#signed-as").textContent = signedIn ? `signed in as ${api.operator}` : "";
  $("#take").hidden = lease.held;
  $("#release").hidden = !lease.held;
  const other = ui.tel && ui.tel.lease && ui.tel.lease.held && !lease.held ? ui.tel.lease.client : null;
  $("#take").textContent = other ? `Take over from ${other}` : "Take control";
  for (const node of $$("[data-needs]")) {
    const moves = "moves" in node.dataset;
    const ok = (node.dataset.needs === "lease" ? signedIn && lease.held : signedIn) && !(moves && !ui.telemetryUp);
    if (moves) node.title = ui.telemetryUp ? "" : BLIND;
    if (node.tagName === "BUTTON") node.disabled = !ok;
    else node.classList.toggle("disabled", !ok);
  }
  document.body.classList.toggle("in-control", lease.held);
  renderHolder(ui.tel, you()); // with the buttons: a pill saying "you" beside Take control contradicted them
}

/** Our operator's name while this console holds the lease, for the control pill. */
const you = () => (lease.held ? api.operator : "");

const RESTARTED = "control lost: the service restarted, and the control lease ended with it: "
  + "take control again";

/** Telemetry came back from another run of the service: the lease we held ended with the old run.
 * Said so, rather than the renewal's "it may have expired", which sent the operator looking for a
 * timeout. */
function serviceRestarted() {
  if (lease.held) {
    api.setLease("");
    lease.set(false, RESTARTED);
  } else if (ui.lostWhileBlind) {
    sayError(RESTARTED);
  }
}

// ------------------------------------------------------------------ actions
async function action(label, fn) {
  try {
    await fn();
    return true;
  } catch (exc) {
    sayError(`${label}: ${exc.message}`);
    return false;
  }
}

/** STOP: never waits for anything else (jog requests queue separately), any signed-in client.
 * ``why``: the console stopped a jog by itself (focus or telemetry lost); the message keeps saying why. */
function stop(fast = false, why = "") {
  jog.end();
  if (why) sayStopped(`Jog stopped: ${why}`);
  if (!api.signedIn) {
    sayError("STOP needs a signed-in console: the server takes motion requests only with the token");
    return;
  }
  // The answer joins the cause rather than replacing it: a service gone away is the cause of both the
  // stopped jog and the failed STOP, and "Failed to fetch" alone hid it.
  const cause = why ? `Jog stopped: ${why}` : "";
  const what = fast ? "fast stop" : "stop";
  api.post("/api/session/stop", { fast }, { timeoutMs: 2000 })
    .then((done) => {
      // A detail: nothing was moving (e.g. the session had ended); said as such, not "requested".
      const said = done && done.detail ? `${what}: ${done.detail}` : `${what} requested`;
      if (why) sayStopped(`${cause} (${said})`);
      else say(said);
    })
    .catch((exc) => {
      if (exc.status === 409 && !why) say(`stop: ${exc.message}`); // refused by the service (a stop with nothing moving answers 200, saying so)
      else if (exc.status === 409) sayStopped(`${cause} (stop: ${exc.message})`);
      else sayStopped(`${cause ? `${cause}; ` : ""}STOP failed${exc.message === why ? " too" : `: ${exc.message}`}`);
    });
}

/** A motion the keyboard asks for: refused, saying why, while the telemetry is lost. */
function canMove(label) {
  if (!ui.telemetryUp) sayError(`${label}: ${BLIND}`);
  return ui.telemetryUp;
}

const actions = {
  start: () => canMove("Start") && action("Start", async () => {
    await api.post("/api/session/start", undefined, { timeoutMs: START_TIMEOUT_MS });
    say("session starting");
  }),
  resume: () => canMove("Resume") && action("Resume", async () => {
    await api.post("/api/session/resume");
    say("resumed"); // replaces an earlier refusal, which stayed 8 s beside a streaming arm
  }),
  end: () => action("End", async () => {
    jog.end();
    await api.post("/api/session/end");
    setTimeout(() => logs.refresh(), 1500);
  }),
  reset: () => action("Reset", async () => {
    // A reset may bring up a new servo process (about a second) and then reset the embedded
    // controller (up to its 2 s call timeout): more than the default 3 s on a loaded PC.
    const done = await api.post("/api/reset", undefined, { timeoutMs: RESET_TIMEOUT_MS });
    // replaces a refusal of an earlier reset ("the fault is not reset"); says what it did where unusual
    say(done && done.detail ? `reset: ${done.detail}` : "reset done");
  }),
  take: () => action("Take control", async () => {
    // Who holds it is read now: the telemetry can be a frame behind, and a lease taken since then by
    // another client went unasked and was refused ("control is held by ..."); one released since was
    // asked about for nothing.
    const held = await api.get("/api/lease");
    const other = held.held ? held.client : null;
    if (other && !window.confirm(`Take control from ${other}? Their jogs will be refused.`)) return;
    await lease.take(Boolean(other));
    say("you have control");
  }),
  release: () => action("Release control", () => lease.release()),
  toggleControl: () => (lease.held ? actions.release() : actions.take()),
};

function bindButtons() {
  // pointerdown, not click: STOP acts on the press, not on the release of a touch.
  $("#stop").addEventListener("pointerdown", (ev) => { ev.preventDefault(); stop(false); });
  $("#stop").addEventListener("click", (ev) => { if (ev.detail === 0) stop(false); }); // keyboard Enter
  $("#fast-stop").addEventListener("click", () => stop(true));
  for (const name of ["start", "resume", "end", "reset", "take", "release"]) {
    $(`#${name}`).addEventListener("click", () => actions[name]());
  }
  $("#signin").addEventListener("submit", (ev) => { ev.preventDefault(); signIn(); });
  $("#signout").addEventListener("click", async () => {
    if (lease.held) await lease.release().catch(() => {});
    api.signOut();
    refreshControls();
  });
  for (const input of $$('input[name="jog-kind"]')) {
    input.addEventListener("change", () => { jog.render(); jogKind(); showSpeed(); });
  }
  for (const input of $$('input[name="jog-mode"]')) {
    input.addEventListener("change", () => { jog.release(); $("#step-row").hidden = !settings().step; });
  }
  $("#speed").addEventListener("input", showSpeed);
  $("#inputs-enable").addEventListener("click", enableInputs);
}

/** Enable or disable input control; the answer may warn (a configured source has failed). */
async function enableInputs() {
  const want = !(ui.tel && ui.tel.inputs && ui.tel.inputs.enabled);
  const box = $("#inputs-error");
  box.textContent = "";
  try {
    const ack = await api.post("/api/inputs/enable", { enable: want });
    const d = ack && ack.detail;
    const warn = d && (d.warning || d.message || "");
    if (warn) box.textContent = String(warn);
    say(want ? "inputs enabled" : "inputs disabled");
  } catch (exc) {
    box.textContent = `${want ? "Enable" : "Disable"} inputs: ${exc.message}`;
  }
  pollInputs(false);
}

/** Each source's connection and errors (the telemetry's summary has rate and staleness only). */
async function pollInputs(again = true) {
  if (!document.hidden && ui.tel && ui.tel.inputs) {
    try {
      ui.inputs = await api.get("/api/inputs", { timeoutMs: 2000 });
      renderInputs($("#inputs-card"), ui.tel, ui.inputs);
    } catch {
      // the telemetry pill already shows a dead server
    }
  }
  if (again) setTimeout(pollInputs, INPUTS_POLL_MS);
}

function jogKind() {
  $("#kind-group").hidden = !cartesianJog();
  $("#frame-group").hidden = !cartesianJog();
  $("#frame-group").classList.toggle("disabled", settings().kind === "joint");
}

async function signIn() {
  const token = $("#token").value.trim();
  const operator = $("#operator").value.trim() || "operator";
  const err = $("#signin-error");
  err.hidden = true;
  api.signIn(token, operator);
  try {
    // Renewing checks the token first (401) and changes nothing: without a lease it answers 409.
    await api.post("/api/lease/renew");
  } catch (exc) {
    if (exc.status === 401 || exc.status === 403) {
      api.signOut();
      err.textContent = `Sign-in refused: the server does not accept this token (${exc.status}).`;
      err.hidden = false;
      refreshControls();
      return;
    }
    if (exc.status === 0) {
      api.signOut();
      err.textContent = `Sign-in failed: ${exc.message}`;
      err.hidden = false;
      refreshControls();
      return;
    }
    // 409 (no lease of ours) or any other answer: the token passed authentication.
  }
  $("#token").value = "";
  say(`signed in as ${operator}`);
  refreshControls();
  await lease.restore();
}

// ------------------------------------------------------------------ live state
function onState(s) {
  // First, so that nothing shows the old run's lease as ours beside the new run's state.
  if (s.service_id && ui.serviceId && s.service_id !== ui.serviceId) serviceRestarted();
  ui.serviceId = s.service_id || ui.serviceId;
  ui.lostWhileBlind = false;
  ui.tel = s;
  renderStatus(s, ui.telemetryUp, you());
  renderPose(s, ui.robot);
  tools.render(s);
  renderHeldBack(s);
  renderReplay(s);
  renderTiming(s);
  renderAlarms(s);
  renderInputs($("#inputs-card"), s, ui.inputs);
  io.render(s);
  joints.render(s, ui.robot, ui.limits, ui.limits ? ui.limits.limit_fraction : 0.9);
  if (s.state !== ui.lastMode) {
    if (s.state === "streaming" && ui.stoppedMessage) { // moving again: the stop is history
      $("#message").hidden = true;
      ui.stoppedMessage = false;
    }
    if (s.state === "streaming" && api.signedIn && io.available) io.selectReadBack();
    if (["ended", "fault"].includes(s.state) || ui.lastMode === null) logs.refresh();
    if (s.state === "fault" && jog.holding) jog.end();
    ui.lastMode = s.state;
  }
  // Someone else may hold the lease now: the take button says so. Where we held it, ask the server at
  // once whether it is still ours (a takeover would otherwise show only at the next renewal, seconds on).
  const holder = s.lease && s.lease.held ? s.lease.client : null;
  if (holder !== ui.lastHolder) {
    ui.lastHolder = holder;
    if (lease.held) lease.renew();
    refreshControls();
  }
}

function onLink(up, why) {
  ui.telemetryUp = up;
  // Back after a loss: the service may have restarted (another var directory or robot, points taught
  // or deleted meanwhile by another client): what is shown is read again, not trusted.
  if (up && ui.linkSeen) {
    points.refresh();
    logs.refresh();
    rereadRobot();
  }
  ui.linkSeen = ui.linkSeen || up;
  const pill = $("#conn");
  pill.textContent = up ? "telemetry: live" : `telemetry: lost (${why})`;
  pill.title = pill.textContent;
  if (ui.tel) renderStatus(ui.tel, up, you()); // the last state heard is not news any more
  pill.className = `pill ${up ? "ok" : "bad"}`;
  document.body.classList.toggle("offline", !up);
  if (!up && jog.holding) {
    // The operator can no longer see what the arm does: stop it (the server's hold-to-run would too).
    stop(false, why);
  }
  refreshControls(); // and start no motion until the telemetry is back
}

/** Stop a held jog when the operator's attention is elsewhere. */
function watchFocus() {
  const lost = (why) => {
    if (jog.holding) stop(false, why);
  };
  window.addEventListener("blur", () => lost("the window lost focus"));
  document.addEventListener("visibilitychange", () => { if (document.hidden) lost("the page was hidden"); });
  window.addEventListener("pagehide", () => lost("the page was closed"));
}

async function pollRobot() {
  if (!document.hidden) {
    try {
      ui.robot = await api.get("/api/robot", { timeoutMs: 1000 });
      arm.draw(ui.robot);
    } catch {
      // the telemetry pill already shows a dead server
    }
  }
  setTimeout(pollRobot, ROBOT_POLL_MS);
}

/** Static data (limits, geometry, joint names): retried until the server answers. */
async function loadRobot() {
  for (;;) {
    try {
      await readRobot();
      break;
    } catch {
      await new Promise((r) => setTimeout(r, 1000));
    }
  }
  buildRobot();
  pollRobot();
}

async function readRobot() {
  const limits = await api.get("/api/limits");
  ui.robot = await api.get("/api/robot");
  ui.limits = limits;
  api.axes = ui.robot.joint_names; // a refusal's "joints[0]" is shown as the axis' name
}

/** What the jog pad, joint table and target form are built from, bar the live values. */
const robotKey = (r) => JSON.stringify([r.backend, r.model, r.joint_names, r.axes.map((a) => a.unit),
  r.axis_label, r.pose_caption, r.cartesian_jog]);

/** Telemetry back after a loss, perhaps from a service restarted with another --robot or model:
 * the panels built for the old arm are built again where it differs (the jog pad jogged axes by
 * names the new one may not have). */
async function rereadRobot() {
  if (!ui.builtFor) return; // the first read is still under way: it builds them
  try {
    await readRobot();
  } catch {
    return; // the telemetry pill shows a dead server; the next return reads again
  }
  if (robotKey(ui.robot) !== ui.builtFor) buildRobot();
}

function buildRobot() {
  ui.builtFor = robotKey(ui.robot);
  const names = ui.robot.joint_names;
  joints.build(names);
  // The limit tables in force where the controller has them, else the profile's axis speeds.
  jog.build({ jointNames: names, velLimit: ui.limits.vel_deg_s || ui.robot.axes.map((a) => a.speed),
    units: ui.robot.axes.map((a) => a.unit) });
  $("#joint-label").textContent = ui.robot.axis_label;
  if (!cartesianJog()) $('input[name="jog-kind"][value="joint"]').checked = true;
  jogKind();
  showSpeed();
  jog.render();
  $("#pose-caption").textContent = ui.robot.pose_caption;
  // Outputs through the stream exist only where the backend allows DO.
  io.available = Boolean(ui.limits.io_allow && ui.limits.io_allow.DO);
  $("#io-card").hidden = !io.available;
  arm.draw(ui.robot);
  target.build(true);
  refreshControls();
}

function main() {
  bindButtons();
  jogKind();
  showSpeed();
  watchFocus();
  installKeys({
    stop, settings, showSpeed,
    start: actions.start, resume: actions.resume, end: actions.end, toggleControl: actions.toggleControl,
    toggleKind: () => { jog.render(); jogKind(); showSpeed(); },
  });
  refreshControls();
  if (api.signedIn) lease.restore();
  new Telemetry({ hz: 20, onState, onLink }).start();
  loadRobot();
  logs.refresh();
  points.refresh();
  tools.refresh();
  pollInputs();
}

main();
