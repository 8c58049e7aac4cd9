// Client-side reader of the binary session log (servo_app/fanuc/session_log.py, format 1):
// b"SERVOLOG", u32 header length, JSON header, then 56-byte little-endian records.

const MAGIC = "SERVOLOG";
const RECORD = 56;
const KIND_COMMAND = 1;
const JOINT_FORMAT = 1; // DataFormat.JOINT, in bit 1 of a command's flags

/** -> {header, t: Float64Array, q: Float32Array[] (per axis), count, axes: names} of the position
 * commands. The header says which (``commands``: "joint_format" keeps joint-format commands only, as
 * a FANUC stream may mix formats; "all" every target sent) and whether they come at a fixed interval. */
export function parseSessionLog(buf) {
  const bytes = new Uint8Array(buf);
  if (bytes.length < 12 || new TextDecoder().decode(bytes.subarray(0, 8)) !== MAGIC) {
    throw new Error("not a servo_app session log (bad magic)");
  }
  const dv = new DataView(buf);
  const n = dv.getUint32(8, true);
  const header = JSON.parse(new TextDecoder().decode(bytes.subarray(12, 12 + n)));
  const all = header.commands === "all";
  const axes = header.axes || ["J1", "J2", "J3", "J4", "J5", "J6"];
  const wanted = all ? (off) => dv.getUint8(off) === KIND_COMMAND : (off) => isJointCommand(dv, off);
  const start = 12 + n;
  const total = Math.floor((buf.byteLength - start) / RECORD); // a partial last record is dropped
  let count = 0;
  for (let i = 0; i < total; i += 1) if (wanted(start + i * RECORD)) count += 1;
  const t = new Float64Array(count);
  const q = axes.map(() => new Float32Array(count));
  let k = 0;
  for (let i = 0; i < total; i += 1) {
    const off = start + i * RECORD;
    if (!wanted(off)) continue;
    t[k] = dv.getFloat64(off + 1, true);
    for (let j = 0; j < axes.length; j += 1) q[j][k] = dv.getFloat32(off + 20 + 4 * j, true);
    k += 1;
  }
  return { header, t, q, count, axes, fixedInterval: header.fixed_interval !== false };
}

function isJointCommand(dv, off) {
  return dv.getUint8(off) === KIND_COMMAND && ((dv.getUint8(off + 13) >> 1) & 1) === JOINT_FORMAT;
}

/** Velocities between consecutive commands. FANUC: each command is one interval of motion on the
 * controller, so the interval, not the jittery send time, is the divisor. Janome: targets are not
 * periodic, so the logged times are. */
export function velocities(log) {
  const dt = (log.header.interval_ms || 8) / 1000;
  return log.q.map((qj) => {
    const v = new Float32Array(Math.max(0, qj.length - 1));
    for (let k = 1; k < qj.length; k += 1) {
      const step = log.fixedInterval ? dt : log.t[k] - log.t[k - 1];
      v[k - 1] = step > 0 ? (qj[k] - qj[k - 1]) / step : 0;
    }
    return v;
  });
}

/** Min/max per bucket: decimating by min/max keeps every peak visible, averaging would hide them. */
export function envelope(v, buckets) {
  const n = v.length;
  const lo = new Float32Array(buckets);
  const hi = new Float32Array(buckets);
  for (let b = 0; b < buckets; b += 1) {
    const i0 = Math.floor((b * n) / buckets);
    const i1 = Math.max(i0 + 1, Math.floor(((b + 1) * n) / buckets));
    let mn = Infinity;
    let mx = -Infinity;
    for (let i = i0; i < i1 && i < n; i += 1) {
      if (v[i] < mn) mn = v[i];
      if (v[i] > mx) mx = v[i];
    }
    lo[b] = mn === Infinity ? 0 : mn;
    hi[b] = mx === -Infinity ? 0 : mx;
  }
  return { lo, hi };
}

/** Each axis' position unit: the header's ``units`` when it has them, else mm for X Y Z (a Janome's
 * axes) and ° for the rest (joints, R). */
export function axisUnits(log) {
  const u = log.header.units;
  if (Array.isArray(u) && u.length === log.axes.length) return u.map((x) => (x === "deg" ? "°" : x));
  return log.axes.map((a) => (["X", "Y", "Z"].includes(a) ? "mm" : "°"));
}

/** Min/max per time bucket over [t0, t0 + duration]: samples need not be evenly spaced (Janome). A
 * bucket without a sample repeats the one before, so a pause draws as a flat line, not a gap. */
export function envelopeByTime(v, t, t0, duration, buckets) {
  if (!(duration > 0)) return envelope(v, buckets);
  const lo = new Float32Array(buckets).fill(Infinity);
  const hi = new Float32Array(buckets).fill(-Infinity);
  for (let i = 0; i < v.length; i += 1) {
    const b = Math.min(buckets - 1, Math.max(0, Math.floor(((t[i] - t0) / duration) * buckets)));
    if (v[i] < lo[b]) lo[b] = v[i];
    if (v[i] > hi[b]) hi[b] = v[i];
  }
  let last = 0;
  for (let b = 0; b < buckets; b += 1) {
    if (lo[b] === Infinity) {
      lo[b] = last;
      hi[b] = last;
    } else {
      last = (lo[b] + hi[b]) / 2;
    }
  }
  return { lo, hi };
}

/** Round tick times (s) from 0 to ``duration``, at most ``most`` of them: 1, 2, 5 times a power of 10. */
export function timeTicks(duration, most = 10) {
  if (!(duration > 0)) return [0];
  let step = 10 ** Math.floor(Math.log10(duration / most));
  for (const m of [1, 2, 5, 10]) {
    if (duration / (step * m) <= most) {
      step *= m;
      break;
    }
  }
  const out = [];
  for (let k = 0; k * step <= duration + 1e-9; k += 1) out.push(k * step);
  return out;
}
