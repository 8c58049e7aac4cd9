// Digital outputs DO[1..8]: written through the command packets (so only while streaming), read
// back through the status packets' read-I/O field, which we point at DO[1..16] masked to 1..8.

import { el } from "./dom.js";

export const IO_POINTS = 8;
const READ = { type: "DO", index: 1, mask: (1 << IO_POINTS) - 1 };

export class IoPanel {
  constructor({ api, root, onError }) {
    Object.assign(this, { api, root, onError });
    this.bits = null; // read-back, null while not streaming
    this.available = true; // false for backends without stream I/O (the panel is hidden)
    this.buttons = Array.from({ length: IO_POINTS }, (_, i) => el("button", {
      type: "button", class: "io", "aria-pressed": "false", dataset: { point: String(i + 1) },
      onclick: () => this.toggle(i + 1),
    }, `DO${i + 1}`));
    root.replaceChildren(...this.buttons);
  }

  /** Ask the controller to report DO[1..8] in every status packet (sticky until changed). */
  async selectReadBack() {
    try {
      await this.api.get(`/api/io?type=${READ.type}&index=${READ.index}&mask=${READ.mask}`);
    } catch (exc) {
      this.onError(`I/O read-back: ${exc.message}`);
    }
  }

  render(s) {
    // The status packets carry whatever read was asked last (by anyone): trust only ours.
    const ours = s.io_read_index === undefined || (s.io_read_index === READ.index && s.io_read_mask === READ.mask);
    const live = s.link === "streaming" && ours;
    this.bits = live ? s.io_read_value : null;
    this.buttons.forEach((b, i) => {
      const on = live && ((s.io_read_value >> i) & 1) === 1;
      b.setAttribute("aria-pressed", String(on));
      b.classList.toggle("unknown", !live);
    });
  }

  async toggle(point) {
    if (this.bits === null) {
      this.onError("I/O: outputs are written and read back through the stream: start a session first");
      return;
    }
    const bit = 1 << (point - 1);
    const value = this.bits & bit ? 0 : bit;
    try {
      await this.api.post("/api/io", { type: "DO", index: 1, mask: bit, value });
    } catch (exc) {
      this.onError(`DO${point}: ${exc.message}`);
    }
  }
}
