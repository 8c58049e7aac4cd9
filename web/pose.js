// FANUC XYZWPR poses for the Cartesian step jog: W, P, R about the fixed X, Y, Z axes, so
// R = Rz(R) Ry(P) Rx(W) (servo_app/robots/conventions.py). 3x3 matrices as arrays of rows.

const rad = (d) => (d * Math.PI) / 180;
const deg = (r) => (r * 180) / Math.PI;

export function rotAxis(axis, angleDeg) {
  const c = Math.cos(rad(angleDeg));
  const s = Math.sin(rad(angleDeg));
  if (axis === 0) return [[1, 0, 0], [0, c, -s], [0, s, c]];
  if (axis === 1) return [[c, 0, s], [0, 1, 0], [-s, 0, c]];
  return [[c, -s, 0], [s, c, 0], [0, 0, 1]];
}

export function mul(a, b) {
  return a.map((row) => [0, 1, 2].map((j) => row[0] * b[0][j] + row[1] * b[1][j] + row[2] * b[2][j]));
}

export function wprToMatrix(w, p, r) {
  return mul(rotAxis(2, r), mul(rotAxis(1, p), rotAxis(0, w)));
}

export function matrixToWpr(m) {
  const cp = Math.hypot(m[0][0], m[1][0]);
  const p = Math.atan2(-m[2][0], cp);
  if (cp < 1e-9) return [0, deg(p), deg(Math.atan2(-m[0][1], m[1][1]))]; // gimbal lock: R takes it all
  return [deg(Math.atan2(m[2][1], m[2][2])), deg(p), deg(Math.atan2(m[1][0], m[0][0]))];
}

/** The pose ``xyzwpr`` moved by ``dist`` (mm or deg) along or about ``axis`` (0..2) of the base
 * frame or of the tool frame (the pose's own axes). */
export function stepPose(xyzwpr, { linear, axis, dist, frame }) {
  const [x, y, z, w, p, r] = xyzwpr;
  const m = wprToMatrix(w, p, r);
  if (linear) {
    // Base: along a world axis. Tool: along a column of the pose's rotation.
    const dir = frame === "tool" ? [m[0][axis], m[1][axis], m[2][axis]] : [0, 1, 2].map((i) => (i === axis ? 1 : 0));
    return [x + dist * dir[0], y + dist * dir[1], z + dist * dir[2], w, p, r];
  }
  const rot = rotAxis(axis, dist);
  const moved = frame === "tool" ? mul(m, rot) : mul(rot, m);
  return [x, y, z, ...matrixToWpr(moved)];
}
