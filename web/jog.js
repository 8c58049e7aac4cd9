// Jog pad: hold-to-run. The arm moves only while a button is held: the press sends a jog every
// RENEW_MS with a HOLD_MS hold-to-run time, so if the browser, the network or this code stops
// sending, the servo process stops the arm by itself within HOLD_MS.

import { el } from "./dom.js";
import { stepPose } from "./pose.js";

export const JOG = {
  RENEW_MS: 100,
  HOLD_MS: 250, // > 2 renewal periods: one late or skipped renewal does not stop the arm
  RELEASE_HOLD_MS: 100, // the zero-speed jog sent on release
  MAX_LINEAR_MM_S: 250, // 100 % of the slider: the reduced speed of manual (T1) mode, ISO 10218-1
  MAX_ANGULAR_DEG_S: 90,
  JOINT_FRACTION: 0.25, // 100 % of the slider: this share of each joint's velocity limit
};

const LINEAR = ["X", "Y", "Z"];
const ANGULAR = ["W", "P", "R"];

export class JogPad {
  /**
   * api: Api; root: the pad's container; settings(): {kind: "cart"|"joint", frame, step: bool,
   * stepMm, stepDeg, speed: 0..1}; onError(text); onLost(why): a held jog got no answer (the console
   * sends STOP, as when the telemetry is lost).
   */
  constructor({ api, root, settings, onError, onLost }) {
    Object.assign(this, { api, root, settings, onError, onLost });
    this.active = null; // the press being held: {axis, btn, timer, sent}
    this.pending = false; // a jog request is in flight
    this.chain = Promise.resolve(); // jog requests go out strictly in order (see queue)
    this.velLimit = [];
    this.jointNames = [];
  }

  /** Build the buttons: Cartesian axes, or one row per joint of the connected robot. */
  build({ jointNames, velLimit, units }) {
    this.jointNames = jointNames;
    this.velLimit = velLimit;
    this.units = units || jointNames.map(() => "deg");
    this.render();
  }

  render() {
    this.release();
    const { kind } = this.settings();
    const rows = kind === "joint"
      ? this.jointNames.map((name, i) => [name, { kind: "joint", index: i }])
      : [...LINEAR.map((n, i) => [n, { kind: "lin", index: i }]),
        ...ANGULAR.map((n, i) => [n, { kind: "ang", index: i }])];
    this.root.replaceChildren(...rows.map(([name, axis]) => el("div", { class: "jog-row" },
      this.button(`−${name}`, { ...axis, sign: -1 }, name),
      el("span", { class: "jog-axis" }, name),
      this.button(`+${name}`, { ...axis, sign: 1 }, name))));
  }

  button(label, axis, name) {
    const btn = el("button", {
      type: "button", class: "jog", "aria-label": `jog ${axis.sign > 0 ? "plus" : "minus"} ${name}`,
      dataset: { jog: `${axis.sign > 0 ? "+" : "-"}${name}` },
    }, label);
    // Pointer events cover mouse, touch and pen. The press captures the pointer: the jog goes on while
    // the pointer is down, wherever it is, and stops when it comes up, is cancelled or loses capture.
    // (Without capture a page that moved under a still mouse fired pointerleave and cut the jog short.)
    btn.addEventListener("pointerdown", (ev) => this.onDown(ev, btn, axis));
    for (const type of ["pointerup", "pointercancel", "lostpointercapture", "blur"]) {
      btn.addEventListener(type, () => { if (this.active && this.active.btn === btn) this.release(); });
    }
    btn.addEventListener("contextmenu", (ev) => ev.preventDefault()); // long-press menu on tablets
    btn.addEventListener("click", (ev) => ev.preventDefault()); // keyboard "clicks" never jog
    return btn;
  }

  onDown(ev, btn, axis) {
    ev.preventDefault();
    if (ev.pointerType === "mouse" && ev.button !== 0) return;
    if (this.active) {
      // Two buttons at once (multi-touch) is not a clear command: stop rather than guess.
      this.release();
      return;
    }
    if (this.settings().step) {
      this.step(axis, btn);
      return;
    }
    this.active = { axis, btn, sent: 0, pointerId: ev.pointerId, timer: setInterval(() => this.renew(), JOG.RENEW_MS) };
    try {
      btn.setPointerCapture(ev.pointerId);
    } catch {
      // a synthetic event without a live pointer: pointerup on the button still releases
    }
    btn.classList.add("held");
    document.body.classList.add("jogging");
    this.renew();
  }

  get holding() {
    return this.active !== null;
  }

  /** Requests go through one promise chain so a zero-speed release never overtakes a late jog. */
  queue(fn) {
    const p = this.chain.then(fn);
    this.chain = p.catch(() => {});
    return p;
  }

  renew() {
    const a = this.active;
    if (!a || this.pending) return; // one in flight at a time; HOLD_MS covers a skipped tick
    this.pending = true;
    a.sent += 1;
    this.queue(() => this.api.post("/api/jog", this.jogBody(a.axis, JOG.HOLD_MS), { timeoutMs: 1000 }))
      .catch((exc) => {
        if (this.active !== a) return;
        this.end();
        // No answer: the jog may have reached the arm, and nothing says it stopped: STOP it.
        if (exc.status === 0 && this.onLost) this.onLost(exc.message);
        else this.onError(`Jog refused: ${exc.message}`);
      })
      .finally(() => { this.pending = false; });
  }

  /** Let go: stop renewing and send a zero-speed jog, so the arm decelerates now rather than when
   * the hold-to-run runs out, and the next press can move again without a resume. */
  release() {
    const a = this.end();
    if (a && a.sent > 0) {
      this.queue(() => this.api.post("/api/jog", this.jogBody(a.axis, JOG.RELEASE_HOLD_MS, 0), { timeoutMs: 1000 }))
        .catch(() => {}); // refused because already stopped, or no network: hold-to-run stops it anyway
    }
  }

  /** Stop renewing without sending anything (a STOP request is on its way). Returns the press. */
  end() {
    const a = this.active;
    if (!a) return null;
    clearInterval(a.timer);
    a.btn.classList.remove("held");
    document.body.classList.remove("jogging");
    if (a.pointerId !== undefined && a.btn.hasPointerCapture(a.pointerId)) a.btn.releasePointerCapture(a.pointerId);
    this.active = null;
    return a;
  }

  /** Per-axis speed at the slider setting: mm/s, deg/s (Cartesian) or deg/s of that joint. */
  speedOf(axis) {
    const { speed } = this.settings();
    if (axis.kind === "lin") return speed * JOG.MAX_LINEAR_MM_S;
    if (axis.kind === "ang") return speed * JOG.MAX_ANGULAR_DEG_S;
    return speed * JOG.JOINT_FRACTION * (this.velLimit[axis.index] || 0);
  }

  jogBody(axis, holdMs, scale = 1) {
    const v = axis.sign * this.speedOf(axis) * scale + 0; // + 0: no -0 in the JSON
    if (axis.kind === "joint") {
      const joints = this.jointNames.map(() => 0);
      joints[axis.index] = v;
      return { joints, hold_ms: holdMs };
    }
    const linear = [0, 0, 0];
    const angular = [0, 0, 0];
    (axis.kind === "lin" ? linear : angular)[axis.index] = v;
    return { frame: this.settings().frame, linear, angular, hold_ms: holdMs };
  }

  /** Step jog: an exact move to a target, at the slider's speed. Joints: /api/target with the joint
   * vector; Cartesian: /api/target with the pose moved along/about the axis of the chosen frame. */
  async step(axis, btn) {
    btn.classList.add("held");
    try {
      // The step starts from where the arm is now, read from the service at the press: the last telemetry
      // frame can be a frame behind it (a step taken from an arm still moving there, or from before a
      // move another client made). No resume is sent: the server resumes a target after its own
      // hold-to-run expiry, as it does a jog (one sent on a stale "stopped" was refused as "already streaming").
      const s = await this.api.get("/api/state", { timeoutMs: 1000 });
      const { stepMm, stepDeg, speed, frame } = this.settings();
      let body;
      if (axis.kind === "joint") {
        // From the feedback once the controller reports (Janome's commanded axes start at zero).
        const q = ((s.status_received > 0 ? s.q_servo : s.q_cmd) || []).slice(0, this.jointNames.length);
        if (q.length !== this.jointNames.length) throw new Error("no axis position yet");
        q[axis.index] += axis.sign * (this.units[axis.index] === "mm" ? stepMm : stepDeg);
        body = { joints: q, speed_scale: Math.max(0.01, speed * JOG.JOINT_FRACTION) };
      } else {
        const pose = (s.cart_servo || []).slice(0, 6);
        if (pose.length !== 6) throw new Error("no pose yet");
        const linear = axis.kind === "lin";
        body = {
          xyzwpr: stepPose(pose, { linear, axis: axis.index, dist: axis.sign * (linear ? stepMm : stepDeg), frame }),
          linear_speed: Math.max(1, speed * JOG.MAX_LINEAR_MM_S),
          angular_speed: Math.max(1, speed * JOG.MAX_ANGULAR_DEG_S),
        };
      }
      await this.api.post("/api/target", body);
    } catch (exc) {
      this.onError(`Step refused: ${exc.message}`);
    } finally {
      btn.classList.remove("held");
    }
  }
}
