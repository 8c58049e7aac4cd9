// Target entry: a joint (axis) target or a pose target, typed in and sent with Go (POST /api/target).
// A refusal shows the server's own words under the form: what was wrong and what to do next.

import { $, $$, el, fmt } from "./dom.js";

const plural = (w) => (w.endsWith("is") ? `${w.slice(0, -2)}es` : `${w}s`); // Axis -> Axes, Joint -> Joints

export class TargetForm {
  /** api: Api; root: the form; telemetry(): the last state; robot(): /api/robot or null. */
  constructor({ api, root, telemetry, robot, onSent }) {
    Object.assign(this, { api, root, telemetry, robot, onSent });
    this.fields = $("#target-fields", root);
    this.error = $("#target-error", root);
    this.built = "";
    for (const input of $$('input[name="target-kind"]', root)) input.addEventListener("change", () => this.build(true));
    $("#target-fill", root).addEventListener("click", () => this.fill());
    root.addEventListener("submit", (ev) => { ev.preventDefault(); this.go(); });
  }

  get kind() {
    return $('input[name="target-kind"]:checked', this.root).value;
  }

  /** The fields of the chosen kind: the robot's axes for joints, X Y Z W P R for a pose. */
  names() {
    const r = this.robot();
    if (this.kind === "joints") return r ? r.joint_names : ["J1", "J2", "J3", "J4", "J5", "J6"];
    return ["X", "Y", "Z", "W", "P", "R"];
  }

  units() {
    const r = this.robot();
    if (this.kind === "joints") return this.names().map((_, i) => (r && r.axes && r.axes[i] && r.axes[i].unit === "mm" ? "mm" : "°"));
    return ["mm", "mm", "mm", "°", "°", "°"];
  }

  /** (Re)build the inputs when the kind or the robot changed; ``fill``: start from where the arm is. */
  build(fill = false) {
    const r = this.robot();
    // Pose targets need a backend that takes Cartesian motion (FANUC); others move their axes.
    $("#target-pose-choice", this.root).hidden = Boolean(r && r.cartesian_jog === false);
    if (r && r.cartesian_jog === false && this.kind !== "joints") {
      $('input[name="target-kind"][value="joints"]', this.root).checked = true;
    }
    if (r && r.axis_label) $("#target-joint-label", this.root).textContent = plural(r.axis_label);
    const names = this.names();
    const units = this.units();
    const sig = `${this.kind}:${names.join()}`;
    if (sig !== this.built) {
      this.built = sig;
      this.fields.replaceChildren(...names.map((n, i) => el("label", {},
        `${n} (${units[i]})`,
        el("input", { type: "number", step: "any", required: true, name: n, "aria-label": `target ${n} in ${units[i]}`,
          dataset: { target: n } }))));
      fill = true;
    }
    if (fill) this.fill();
  }

  /** The current position into the fields: the controller's feedback once it reports. */
  fill() {
    const s = this.telemetry() || {};
    const values = this.kind === "joints"
      ? (s.status_received > 0 ? s.q_servo : s.q_cmd) || []
      : s.cart_servo || [];
    $$("input", this.fields).forEach((input, i) => {
      if (Number.isFinite(values[i])) input.value = fmt(values[i], 3);
    });
  }

  async go() {
    const inputs = $$("input", this.fields);
    const values = inputs.map((i) => Number(i.value));
    const bad = inputs.find((i, k) => i.value.trim() === "" || !Number.isFinite(values[k]));
    if (bad) {
      this.show(`${bad.name}: enter a number`, false);
      bad.focus();
      return;
    }
    const body = this.kind === "joints" ? { joints: values } : { xyzwpr: values };
    this.show("sending…", true);
    try {
      await this.api.post("/api/target", body);
      this.show(`going to ${this.names().map((n, i) => `${n} ${fmt(values[i], 1)}`).join(" ")}`, true);
      if (this.onSent) this.onSent();
    } catch (exc) {
      this.show(`Target refused: ${exc.message}`, false);
    }
  }

  show(text, ok) {
    this.error.textContent = text;
    this.error.classList.toggle("ok", ok);
  }
}
