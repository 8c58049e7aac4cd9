// REST client: bearer token and control lease ride on every call; errors carry the server's detail.

const TOKEN_KEY = "servo.token";
const OPERATOR_KEY = "servo.operator";
const LEASE_KEY = "servo.lease";

export class ApiError extends Error {
  constructor(status, message, detail = message) {
    super(message); // in the console's words (forOperator)
    this.status = status; // 0: no answer (network down, timeout)
    this.detail = detail; // the server's own text, for a client of the API
  }
}

const POSE = ["X", "Y", "Z", "W", "P", "R"];

// The server's refusals end with the next step as an API call, for any client; the operator does it
// with a button. Parenthesised calls only name the route: dropped.
const NEXT_STEPS = [
  [/: this request has (no|an) X-Lease-Id[^;]*; send the lease id from POST \/api\/lease as X-Lease-Id, or /g, "; "],
  [/acquire it first \(POST \/api\/lease\)/g, "take control first: press Take control"],
  [/\s*\((?:GET|POST|PUT|DELETE) \/api\/[^)]*\)/g, ""],
  [/POST \/api\/session\/start( \(ServoClient\.start\(\)\))?/g, "press Start"],
  [/POST \/api\/session\/resume/g, "press Resume"],
  [/POST \/api\/session\/end/g, "press End"],
  [/POST \/api\/reset/g, "press Reset"],
  [/POST \/api\/lease with force=true/g, "press Take over"],
  [/POST \/api\/lease\b/g, "press Take control"],
  [/POST \/api\/points\/[^\s?;,]+\?replace=true/g, "Teach here again and confirm replacing it"],
  [/POST \/api\/points\/[^\s;,]+/g, "Teach here"],
  [/GET \/api\/points/g, "the Points list"],
  [/GET \/api\/state shows/g, "the console shows"],
];

/** A field path of the API ("body.joints.0", "joints[0]") as the console labels it ("J1"). */
function fieldName(path, axes) {
  const [name, index] = path;
  if (index === undefined || !/^\d+$/.test(String(index))) return path.join(".");
  const i = Number(index);
  if (name === "joints") return axes[i] || `axis ${i + 1}`;
  if (name === "xyzwpr") return POSE[i] || `pose ${i + 1}`;
  return `${name} ${i + 1}`;
}

/** A refusal in the console's words: its fields and next steps as the operator sees them. */
export function forOperator(text, axes = []) {
  let out = text.replace(/\b(joints|xyzwpr)\[(\d+)\]/g, (_, name, i) => fieldName([name, i], axes));
  for (const [rest, button] of NEXT_STEPS) out = out.replace(rest, button);
  return out;
}

// FastAPI answers {"detail": "text"} or, for validation errors, {"detail": [{loc, msg}, ...]}.
function detailText(data, fallback, axes) {
  const d = data && data.detail;
  if (typeof d === "string") return d;
  if (Array.isArray(d)) {
    return d.map((e) => {
      // Without where the field came from and the model a union picked ("body", "JointTarget").
      const loc = (e.loc || []).filter((p, i) => !(i === 0 && ["body", "query", "path"].includes(p))
        && !(i === 1 && /^[A-Z][A-Za-z]*$/.test(p)));
      return loc.length ? `${fieldName(loc, axes)}: ${e.msg}` : e.msg;
    }).join("; ");
  }
  return fallback;
}

export class Api {
  constructor() {
    // sessionStorage: the token survives a reload but not closing the tab (a shared operator PC).
    this.token = sessionStorage.getItem(TOKEN_KEY) || "";
    this.operator = sessionStorage.getItem(OPERATOR_KEY) || "";
    this.leaseId = sessionStorage.getItem(LEASE_KEY) || "";
    this.axes = []; // the robot's axis names (GET /api/robot), for refusals naming an axis by index
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
      const detail = exc.name === "AbortError" ? `${method} ${path}: no answer in ${timeoutMs} ms`
        : `${method} ${path}: ${exc.message}`;
      // The browser's "Failed to fetch" says nothing to an operator: what it means here does.
      throw new ApiError(0, exc.name === "AbortError" ? `the service did not answer within ${timeoutMs / 1000} s`
        : "the service cannot be reached (it has stopped, or the network is down)", detail);
    } finally {
      clearTimeout(timer);
    }
    let data = null;
    try {
      data = await res.json();
    } catch {
      // not JSON (e.g. a proxy error page): the status says enough
    }
    if (!res.ok) {
      const detail = detailText(data, `${res.status} ${res.statusText}`, this.axes);
      throw new ApiError(res.status, forOperator(detail, this.axes), detail);
    }
    return data;
  }

  get(path, opts) { return this.call("GET", path, undefined, opts); }
  post(path, body, opts) { return this.call("POST", path, body, opts); }
  put(path, body, opts) { return this.call("PUT", path, body, opts); }
  del(path, opts) { return this.call("DELETE", path, undefined, opts); }
}
