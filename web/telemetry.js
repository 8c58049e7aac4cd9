// Live state from /ws/telemetry: reconnects by itself and declares the link lost when messages stop,
// since a half-open socket can stay "open" long after the server went away.

const STALE_MS = 1000; // 20+ messages expected in that time at the rates we ask for

export class Telemetry {
  constructor({ hz = 20, onState, onLink }) {
    this.hz = hz;
    this.onState = onState;
    this.onLink = onLink; // (up: boolean, why: string)
    this.ws = null;
    this.up = false;
    this.lastMessage = 0;
    this.retryMs = 250;
  }

  start() {
    this.connect();
    setInterval(() => this.watch(), 250);
  }

  connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const ws = new WebSocket(`${proto}//${location.host}/ws/telemetry?hz=${this.hz}`);
    this.ws = ws;
    ws.onmessage = (m) => {
      this.lastMessage = performance.now();
      this.retryMs = 250;
      this.setUp(true, "");
      let s;
      try {
        s = JSON.parse(m.data);
      } catch {
        return;
      }
      this.onState(s);
    };
    ws.onclose = () => {
      if (this.ws !== ws) return;
      this.ws = null;
      this.setUp(false, "telemetry connection closed");
      setTimeout(() => this.connect(), this.retryMs);
      this.retryMs = Math.min(this.retryMs * 2, 4000);
    };
    ws.onerror = () => ws.close();
  }

  watch() {
    if (this.up && performance.now() - this.lastMessage > STALE_MS) {
      this.setUp(false, `no telemetry for ${STALE_MS} ms`);
      if (this.ws) this.ws.close(); // onclose reconnects
    }
  }

  setUp(up, why) {
    if (up === this.up) return;
    this.up = up;
    this.onLink(up, why);
  }
}
