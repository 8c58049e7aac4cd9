// The control lease: one client at a time may move the arm. While we hold it we renew it well
// inside its TTL; losing it (expired, taken over) is reported at once, since jogs will be refused.

import { ApiError } from "./api.js";

export class Lease {
  constructor({ api, onChange }) {
    this.api = api;
    this.onChange = onChange; // (held: boolean, why: string)
    this.held = false;
    this.timer = null;
    this.ttlS = 10;
  }

  /** After a reload the lease id is still in sessionStorage: find out whether it is still ours. */
  async restore() {
    if (!this.api.leaseId || !this.api.signedIn) return;
    try {
      const r = await this.api.post("/api/lease/renew");
      this.set(true, "", r.ttl_s);
    } catch {
      this.api.setLease("");
    }
  }

  async take(force = false) {
    const r = await this.api.post("/api/lease", { client: this.api.operator || "console", force });
    this.api.setLease(r.lease_id);
    this.set(true, "", r.ttl_s);
  }

  async release() {
    try {
      if (this.api.leaseId) await this.api.del("/api/lease");
    } catch (e) {
      // 409: our lease id is no longer the current one (it expired or was taken over): nothing to release.
      if (!(e instanceof ApiError && e.status === 409)) throw e;
    } finally {
      this.api.setLease("");
      this.set(false, "released");
    }
  }

  set(held, why, ttlS = this.ttlS) {
    this.ttlS = ttlS || this.ttlS;
    clearInterval(this.timer);
    this.timer = held ? setInterval(() => this.renew(), (this.ttlS * 1000) / 4) : null;
    const changed = held !== this.held;
    this.held = held;
    if (changed || why) this.onChange(held, why);
  }

  async renew() {
    const id = this.api.leaseId;
    try {
      await this.api.post("/api/lease/renew");
    } catch (exc) {
      if (this.api.leaseId !== id) return; // an answer about a lease already given up or replaced
      if (exc.status === 409 || exc.status === 401) { // gone for good; network errors: try again
        this.api.setLease("");
        this.set(false, `control lost: ${exc.message}`);
      }
    }
  }
}
