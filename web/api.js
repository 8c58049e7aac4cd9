// REST client: bearer token and control lease ride on every call; errors carry the server's detail.

const TOKEN_KEY = "servo.token";
const OPERATOR_KEY = "servo.operator";
const LEASE_KEY = "servo.lease";

export class ApiError extends Error {
  constructor(status, detail) {
    super(detail);
    this.status = status; // 0: no answer (network down, timeout)
  }
}

// FastAPI answers {"detail": "text"} or, for validation errors, {"detail": [{loc, msg}, ...]}.
function detailText(data, fallback) {
  const d = data && data.detail;
  if (typeof d === "string") return d;
  if (Array.isArray(d)) return d.map((e) => `${(e.loc || []).join(".")}: ${e.msg}`).join("; ");
  return fallback;
}

export class Api {
  constructor() {
    // sessionStorage: the token survives a reload but not closing the tab (a shared operator PC).
    this.token = sessionStorage.getItem(TOKEN_KEY) || "";
    this.operator = sessionStorage.getItem(OPERATOR_KEY) || "";
    this.leaseId = sessionStorage.getItem(LEASE_KEY) || "";
  }

  get signedIn() {
    return this.token !== "";
  }

  signIn(token, operator) {
    this.token = token;
    this.operator = operator;
    sessionStorage.setItem(TOKEN_KEY, token);
    sessionStorage.setItem(OPERATOR_KEY, operator);
  }

  signOut() {
    this.token = "";
    this.setLease("");
    sessionStorage.removeItem(TOKEN_KEY);
  }

  setLease(id) {
    this.leaseId = id || "";
    if (this.leaseId) sessionStorage.setItem(LEASE_KEY, this.leaseId);
    else sessionStorage.removeItem(LEASE_KEY);
  }

  /** One request; resolves to the JSON answer, rejects with ApiError. */
  async call(method, path, body = undefined, { timeoutMs = 3000 } = {}) {
    const headers = {};
    if (this.token) headers.Authorization = `Bearer ${this.token}`;
    if (this.leaseId) headers["X-Lease-Id"] = this.leaseId;
    if (body !== undefined) headers["Content-Type"] = "application/json";
    // A hung request must not leave a jog button "working": give up and report instead.
    const abort = new AbortController();
    const timer = setTimeout(() => abort.abort(), timeoutMs);
    let res;
    try {
      res = await fetch(path, {
        method, headers, body: body === undefined ? undefined : JSON.stringify(body), signal: abort.signal,
        cache: "no-store",
      });
    } catch (exc) {
      throw new ApiError(0, exc.name === "AbortError" ? `${method} ${path}: no answer in ${timeoutMs} ms`
        : `${method} ${path}: ${exc.message}`);
    } finally {
      clearTimeout(timer);
    }
    let data = null;
    try {
      data = await res.json();
    } catch {
      // not JSON (e.g. a proxy error page): the status says enough
    }
    if (!res.ok) throw new ApiError(res.status, detailText(data, `${res.status} ${res.statusText}`));
    return data;
  }

  get(path, opts) { return this.call("GET", path, undefined, opts); }
  post(path, body, opts) { return this.call("POST", path, body, opts); }
  put(path, body, opts) { return this.call("PUT", path, body, opts); }
  del(path, opts) { return this.call("DELETE", path, undefined, opts); }
}
