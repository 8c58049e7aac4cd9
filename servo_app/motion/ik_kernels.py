"""Compiled kernels of the differential IK cycle (:mod:`servo_app.motion.diffik`, :mod:`.ik_limits`).

Why: between its MuJoCo calls and the solve, the IK cycle was hundreds of numpy calls on 6-vectors
(1-2 us each here); each kernel below replaces a group of them with one call (~0.5 us). Pure math,
no I/O, every output written into arrays the caller allocated once. The last few (:func:`collision_fill`,
:func:`table_rows`, :func:`table_problem`, :func:`cartesian_step`) also call MuJoCo's C functions
(:mod:`servo_app.motion.mujoco_c`: kinematics, Jacobians, narrow phases), so a whole Cartesian step
is one call.

Numbers: the limit rows (:func:`acceleration_rows`, :func:`braking_rows`, :func:`configuration_limit_rows`,
:func:`limit_rows`, :func:`collision_rows`) repeat the reference's float operations in its order, so they
equal mink's / the limits' ``compute_qp_inequalities`` to the bit (``tests/test_diffik_equivalence.py``),
and so do the Jacobians :func:`point_jacobian` / :func:`site_objective` make (``mj_jac``'s operations).
The rest (objective, solve, condition number, poses, distances, path bounds) equals the numpy /
MuJoCo / mink code it replaces within rounding (``tests/test_ik_kernels.py`` and
``tests/test_ik_collision_kernels.py`` compare each with an oracle).

Poses are 7-vectors as mink's SE3 stores them: unit quaternion (w x y z), then position (m).
"""

from __future__ import annotations

import math

import numpy as np

from servo_app.jit import kernel
from servo_app.motion.mujoco_c import (
    address,
    doubles,
    mj_comPos,
    mj_geomDistance,
    mj_jacSite,
    mj_kinematics,
    mj_makeConstraint,
    mju_mat2Quat,
    mju_rotVecQuat,
    table_b1,
    table_f1,
    table_f2,
    table_i1,
    table_i2,
)
from servo_app.robots.kernels import DEG_TO_RAD

_MINVAL = 1e-15  # MuJoCo's mjMINVAL: its vector normalisations treat shorter vectors as zero
_LIE_EPS = 1e-10  # mink's _lie_ops_c EPS: small-angle series below it


# ------------------------------------------------------------------------------------ quaternions
@kernel("UniTuple(float64, 4)(float64, float64, float64)")
def _normalize3(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """MuJoCo's ``mju_normalize3``: the unit vector along (x, y, z) and the length; (1, 0, 0) below
    mjMINVAL (the same operations, so the same bits)."""
    length = math.sqrt(x * x + y * y + z * z)
    if length < _MINVAL:
        return 1.0, 0.0, 0.0, length
    inv = 1.0 / length
    return x * inv, y * inv, z * inv, length


@kernel("void(float64[::1], float64[::1], float64[::1])")
def quat_mul(out: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """``out = a * b`` (Hamilton product, as ``mju_mulQuat``); ``out`` may not alias ``a`` or ``b``."""
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@kernel("void(float64[::1], float64[::1], float64[::1])")
def rotation_between(out: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """Base-frame rotation vector taking pose ``b``'s orientation to ``a``'s, the shorter way
    (``mju_quat2Vel(a * conj(b), 1)``), written into ``out`` (3)."""
    bw, bx, by, bz = b[0], -b[1], -b[2], -b[3]
    w = a[0] * bw - a[1] * bx - a[2] * by - a[3] * bz
    x = a[0] * bx + a[1] * bw + a[2] * bz - a[3] * by
    y = a[0] * by - a[1] * bz + a[2] * bw + a[3] * bx
    z = a[0] * bz + a[1] * by - a[2] * bx + a[3] * bw
    x, y, z, sin_half = _normalize3(x, y, z)
    speed = 2.0 * math.atan2(sin_half, w)
    if speed > math.pi:  # the angle beyond pi: the other way round
        speed -= 2.0 * math.pi
    out[0], out[1], out[2] = x * speed, y * speed, z * speed


@kernel("boolean(float64[::1])")
def any_nonzero(v: np.ndarray) -> bool:
    """``v.any()`` for a float vector (a kernel call costs a third of numpy's reduction here)."""
    for x in v:  # noqa: SIM110 - a loop numba compiles (no generator expression)
        if x != 0.0:
            return True
    return False


@kernel("boolean(float64[::1], float64[::1])")
def any_nonzero2(a: np.ndarray, b: np.ndarray) -> bool:
    """``a.any() or b.any()``: an entry of either that is nonzero or NaN (the publish path asks it
    every loop through ``JointShaper.at_rest``: numpy's ``any`` costs ~1.5 us a call here, this 0.3)."""
    return any_nonzero(a) or any_nonzero(b)


@kernel("boolean(UniTuple(float64, 3), UniTuple(float64, 3), float64[::1])")
def twist_si(linear_mm_s: tuple[float, float, float], angular_deg_s: tuple[float, float, float],
             out: np.ndarray) -> bool:
    """A twist in SI units into ``out`` (6): ``linear / 1000.0`` (m/s), then ``np.radians(angular)``
    (rad/s: numpy multiplies by pi / 180, this constant); returns ``out.any()``."""
    for i in range(3):
        out[i] = linear_mm_s[i] / 1000.0
        out[3 + i] = angular_deg_s[i] * DEG_TO_RAD
    return any_nonzero(out)


@kernel("void(float64[::1], float64[::1], float64[::1], float64, float64)")
def advance(out: np.ndarray, pose: np.ndarray, xi: np.ndarray, s: float, dt: float) -> None:
    """``pose`` moved by the base-frame displacement ``(s * xi) * dt`` (translation of the TCP,
    rotation about it: ``mju_quatIntegrate`` of the identity, applied on the left), into ``out`` (7)."""
    vx, vy, vz = (s * xi[3]) * dt, (s * xi[4]) * dt, (s * xi[5]) * dt
    ax, ay, az, angle = _normalize3(vx, vy, vz)
    if angle == 0.0:
        tw, tx, ty, tz = 1.0, 0.0, 0.0, 0.0
    else:
        half = math.sin(0.5 * angle)
        tw, tx, ty, tz = math.cos(0.5 * angle), ax * half, ay * half, az * half
    pw, px, py, pz = pose[0], pose[1], pose[2], pose[3]
    out[0] = tw * pw - tx * px - ty * py - tz * pz
    out[1] = tw * px + tx * pw + ty * pz - tz * py
    out[2] = tw * py - tx * pz + ty * pw + tz * px
    out[3] = tw * pz + tx * py - ty * px + tz * pw
    for i in range(3):
        out[4 + i] = pose[4 + i] + (s * xi[i]) * dt


@kernel("boolean(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1])")
def along_track(out: np.ndarray, ref: np.ndarray, tcp: np.ndarray, xi: np.ndarray, weights: np.ndarray) -> bool:
    """The reference ``ref`` moved along the line ``xi`` to where ``tcp`` is along it (the error's
    share along ``xi`` in the ``weights`` metric), into ``out``; False (``out`` untouched) when
    ``xi`` is zero in that metric."""
    rot = np.empty(3)
    rotation_between(rot, tcp, ref)
    norm = 0.0
    along = 0.0
    for i in range(6):
        wxi = weights[i] * xi[i]
        norm += xi[i] * wxi
        along += (tcp[4 + i] - ref[4 + i] if i < 3 else rot[i - 3]) * wxi
    if norm <= 0.0:
        return False
    advance(out, ref, xi, along / norm, 1.0)
    return True


@kernel("boolean(float64[::1], float64[::1], float64[::1], float64[::1])")
def along_track_to(out: np.ndarray, ref: np.ndarray, tcp: np.ndarray, goal: np.ndarray) -> bool:
    """A pose target's :func:`along_track`: the reference ``ref`` moved on its straight line to ``goal``
    to where ``tcp`` is along it, the position along the line between the positions and the rotation
    along the turn between the orientations, each on its own (a part already at the goal stays),
    into ``out``; False (``out`` untouched) when ``ref`` is at the goal.

    One metric for both left the error across the line a mix: the TCP behind in translation and
    ahead in rotation, the pull-back pushed the translation forward (+4 % of a pose target's speed)."""
    rot = np.empty(3)
    rotation_between(rot, tcp, ref)
    line = np.empty(6)  # ref -> goal: the translation, then the rotation vector
    for i in range(3):
        line[i] = goal[4 + i] - ref[4 + i]
    turn = np.empty(3)
    rotation_between(turn, goal, ref)
    for i in range(3):
        line[3 + i] = turn[i]
    moved = False
    for part in (0, 3):
        norm = 0.0
        along = 0.0
        for i in range(3):
            x = line[part + i]
            norm += x * x
            along += (tcp[4 + i] - ref[4 + i] if part == 0 else rot[i]) * x
        share = along / norm if norm > 0.0 else 0.0
        moved = moved or norm > 0.0
        for i in range(3):
            line[part + i] *= share
    if not moved:
        return False
    advance(out, ref, line, 1.0, 1.0)
    return True


@kernel("float64(float64[::1], float64[::1], float64[:, ::1], float64[::1], float64[::1], float64[::1])")
def turn_cap(prev: np.ndarray, direction: np.ndarray, c: np.ndarray, dq_prev: np.ndarray, lim: np.ndarray,
             out: np.ndarray) -> float:
    """A pose target's speed cap (the share ``s`` of its line ``direction``, model rad per cycle at full
    speed) from how fast the line turns in joint space: the full-speed increment's turn per unit of path
    (measured on FANUC axes ``c @ direction`` against ``prev``, last cycle's, over the share of it the arm
    delivered, ``c @ dq_prev``), at ``s`` s**2 times that per cycle, within ``lim`` (per axis, per cycle).
    This cycle's into ``out`` (not ``prev``); inf when there is nothing to compare (zeros in ``prev``, or
    barely moving).

    Why: with a long tool the flange can pass near J1's axis (the flange Jacobian's condition number only
    18) while the joints that keep the TCP on its line counter-rotate fast (J1 and J6 at 240 deg/s for a
    219 mm/s, 17.7 deg/s target, 1.5 m tool), and the line's joint
    direction turns faster than the acceleration rows let it, cycle by cycle at full speed: the IK fell
    off the line, and any blend, QP step or per-joint brake there (or the shaper's lag) upsets the
    cancellation: the TCP ran at 3-4 x its speed."""
    n = direction.shape[0]
    u = out
    nu = 0.0
    npv = 0.0
    moved = 0.0
    for i in range(n):
        x = 0.0
        y = 0.0
        for k in range(n):
            x += c[i, k] * direction[k]
            y += c[i, k] * dq_prev[k]
        u[i] = x
        nu += x * x
        npv += prev[i] * prev[i]
        moved += y * y
    nu, npv, moved = math.sqrt(nu), math.sqrt(npv), math.sqrt(moved)
    cap = math.inf
    if nu > 0.0 and npv > 0.0:
        share = moved / npv  # the path covered last cycle, in full-speed increments
        if share >= 0.01:
            for i in range(n):
                turn = abs(u[i] - prev[i] * (nu / npv)) / share
                if turn > 0.0:
                    cap = min(cap, math.sqrt(lim[i] / turn))
    return cap


@kernel("boolean(float64[::1], float64[::1], float64, float64)")
def poses_near(a: np.ndarray, b: np.ndarray, tol: float, reach: float) -> bool:
    """``a`` within ``tol`` of ``b``: position (m), and rotation times ``reach`` (m)."""
    dx, dy, dz = a[4] - b[4], a[5] - b[5], a[6] - b[6]
    if math.sqrt(dx * dx + dy * dy + dz * dz) > tol:
        return False
    rot = np.empty(3)
    rotation_between(rot, a, b)
    return math.sqrt(rot[0] * rot[0] + rot[1] * rot[1] + rot[2] * rot[2]) * reach <= tol


# ----------------------------------------------------------------------- singular values (condition)
@kernel("float64(float64[:, ::1], float64, float64[:, ::1])")
def condition_number(jac: np.ndarray, reach: float, work: np.ndarray) -> float:
    """Condition number of ``jac`` (6 x n) with its first three rows divided by ``reach``: largest
    over smallest singular value, 1e12 when the smallest is below 1e-12 of the largest.

    One-sided Jacobi (Hestenes) on the columns instead of LAPACK's SVD: plane rotations until the
    columns are orthogonal to working precision; the singular values are then the column norms, to
    high relative accuracy (the same values as ``np.linalg.svd`` within rounding). ``work``: scratch
    of ``jac``'s shape."""
    m, n = jac.shape
    for i in range(m):
        for j in range(n):
            work[i, j] = jac[i, j] / reach if i < 3 else jac[i, j]
    for _sweep in range(60):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                alpha = 0.0
                beta = 0.0
                gamma = 0.0
                for i in range(m):
                    alpha += work[i, p] * work[i, p]
                    beta += work[i, q] * work[i, q]
                    gamma += work[i, p] * work[i, q]
                if gamma == 0.0 or abs(gamma) <= 1e-15 * math.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = c * t
                for i in range(m):
                    wp, wq = work[i, p], work[i, q]
                    work[i, p] = c * wp - s * wq
                    work[i, q] = s * wp + c * wq
        if not rotated:
            break
    smax = 0.0
    smin = math.inf
    for j in range(n):
        acc = 0.0
        for i in range(m):
            acc += work[i, j] * work[i, j]
        sv = math.sqrt(acc)
        smax = max(smax, sv)
        smin = min(smin, sv)
    return smax / smin if smin > 1e-12 * smax else 1e12


# --------------------------------------------------------------------- mink's SE3 (frame task terms)
@kernel("void(float64[::1], float64[::1], float64[::1], int64)")
def _quat_rotate(out: np.ndarray, v: np.ndarray, q: np.ndarray, v_at: int) -> None:
    """``out[:3]`` = ``v[v_at:v_at + 3]`` rotated by ``q`` (mink's ``quat_rotate``)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    v0, v1, v2 = v[v_at], v[v_at + 1], v[v_at + 2]
    tx = 2.0 * (y * v2 - z * v1)
    ty = 2.0 * (z * v0 - x * v2)
    tz = 2.0 * (x * v1 - y * v0)
    out[0] = v0 + w * tx + (y * tz - z * ty)
    out[1] = v1 + w * ty + (z * tx - x * tz)
    out[2] = v2 + w * tz + (x * ty - y * tx)


@kernel("void(float64[::1], float64[::1], float64[::1])")
def _se3_inverse_multiply(out: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """``a^-1 @ b`` (mink's ``_se3_inverse_multiply``)."""
    iq = np.array([a[0], -a[1], -a[2], -a[3]])
    neg_t = np.array([-a[4], -a[5], -a[6]])
    inv_t = np.empty(3)
    _quat_rotate(inv_t, neg_t, iq, 0)
    quat = np.empty(4)
    quat_mul(quat, iq, b)
    rotated = np.empty(3)
    _quat_rotate(rotated, b, iq, 4)
    for i in range(4):
        out[i] = quat[i]
    for i in range(3):
        out[4 + i] = rotated[i] + inv_t[i]


@kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1])")
def _mat33_mul(out: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """``out = a @ b`` (3 x 3, mink's ``mat33_mul`` order); ``out`` may not alias ``a`` or ``b``."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@kernel("void(float64[:, ::1], float64, float64, float64)")
def _skew(out: np.ndarray, x: float, y: float, z: float) -> None:
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -z, y
    out[1, 0], out[1, 1], out[1, 2] = z, 0.0, -x
    out[2, 0], out[2, 1], out[2, 2] = -y, x, 0.0


@kernel("void(float64[::1], float64[::1])")
def _se3_log(tangent: np.ndarray, t: np.ndarray) -> None:
    """mink's ``_se3_log`` (tangent ``[v; omega]``)."""
    qw, qx, qy, qz = t[0], t[1], t[2], t[3]
    if qw < 0.0:
        qw, qx, qy, qz = -qw, -qx, -qy, -qz
    norm = math.sqrt(qx * qx + qy * qy + qz * qz)
    if norm > 0.0:
        inv = 1.0 / norm
        qx, qy, qz = qx * inv, qy * inv, qz * inv
    if norm < _LIE_EPS:
        wx, wy, wz = 0.0, 0.0, 0.0
    else:
        angle = 2.0 * math.atan2(norm, qw)
        wx, wy, wz = angle * qx, angle * qy, angle * qz
    theta = math.sqrt(wx * wx + wy * wy + wz * wz)
    t2 = theta * theta
    skw = np.empty((3, 3))
    _skew(skw, wx, wy, wz)
    skw2 = np.empty((3, 3))
    _mat33_mul(skw2, skw, skw)
    if t2 < _LIE_EPS:
        for i in range(3):
            for j in range(3):
                skw2[i, j] = -0.5 * skw[i, j] + skw2[i, j] / 12.0
    else:
        half = 0.5 * theta
        coeff = (1.0 - 0.5 * theta * math.cos(half) / math.sin(half)) / t2
        for i in range(3):
            for j in range(3):
                skw2[i, j] = -0.5 * skw[i, j] + coeff * skw2[i, j]
    for i in range(3):  # skw2 is now V^-1
        skw2[i, i] += 1.0
    for i in range(3):
        tangent[i] = skw2[i, 0] * t[4] + skw2[i, 1] * t[5] + skw2[i, 2] * t[6]
    tangent[3], tangent[4], tangent[5] = wx, wy, wz


@kernel("void(float64[:, ::1], float64[::1])")
def _se3_jlog(jlog: np.ndarray, t: np.ndarray) -> None:
    """mink's ``_se3_jlog``: the inverse right Jacobian at ``log(t)`` (6 x 6)."""
    tangent = np.empty(6)
    _se3_log(tangent, t)
    vx, vy, vz = -tangent[0], -tangent[1], -tangent[2]
    wx, wy, wz = -tangent[3], -tangent[4], -tangent[5]
    jlog[:, :] = 0.0
    inner = wx * wx + wy * wy + wz * wz
    if inner < _LIE_EPS:
        for i in range(6):
            jlog[i, i] = 1.0
        return
    theta = math.sqrt(inner)
    t2 = theta * theta  # >= _LIE_EPS here: mink's small-angle series is never used
    t4 = t2 * t2
    st, ct = math.sin(theta), math.cos(theta)
    b = (theta - st) / (t2 * theta)
    c = (1.0 - 0.5 * t2 - ct) / t4
    d = (2.0 * theta - 3.0 * st + theta * ct) / (2.0 * t4 * theta)
    v, w = np.empty((3, 3)), np.empty((3, 3))
    _skew(v, vx, vy, vz)
    _skew(w, wx, wy, wz)
    vw, wvw, vww = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    wvww, wwvw = np.empty((3, 3)), np.empty((3, 3))
    _mat33_mul(vw, v, w)
    wv = vw.T.copy()  # (VW)^T = WV for skew matrices
    _mat33_mul(wvw, wv, w)
    _mat33_mul(vww, vw, w)
    _mat33_mul(wvww, wvw, w)
    _mat33_mul(wwvw, w, wvw)
    q = np.empty((3, 3))  # Sola et al. eq. 180
    for i in range(3):
        for j in range(3):
            q[i, j] = (0.5 * v[i, j] + b * (wv[i, j] + vw[i, j] + wvw[i, j])
                       - c * (vww[i, j] - vww[j, i] - 3.0 * wvw[i, j]) + d * (wvww[i, j] + wwvw[i, j]))
    beta = (1.0 / t2) * (1.0 - (theta * st / (2.0 * (1.0 - ct))))
    lji = np.empty((3, 3))  # SO3 left Jacobian inverse at -omega
    for i in range(3):
        for j in range(3):
            lji[i, j] = beta * (-tangent[3 + i] * -tangent[3 + j] - (inner if i == j else 0.0))
    lji[0, 1] += 0.5 * wz
    lji[0, 2] += -0.5 * wy
    lji[1, 0] += -0.5 * wz
    lji[1, 2] += 0.5 * wx
    lji[2, 0] += 0.5 * wy
    lji[2, 1] += -0.5 * wx
    for i in range(3):
        lji[i, i] += 1.0
    qj, jqj = np.empty((3, 3)), np.empty((3, 3))
    _mat33_mul(qj, q, lji)
    _mat33_mul(jqj, lji, qj)
    for i in range(3):
        for j in range(3):
            jlog[i, j] = lji[i, j]
            jlog[3 + i, 3 + j] = lji[i, j]
            jlog[i, 3 + j] = -jqj[i, j]


@kernel("void(float64[::1], float64[::1], float64[::1])")
def frame_pose(out: np.ndarray, xmat: np.ndarray, xpos: np.ndarray) -> None:
    """A site's pose from MuJoCo's ``site_xmat`` (9) and ``site_xpos`` (3), as mink reads it
    (``xmat_xpos_to_wxyz_xyz``: Shepperd's method, normalised)."""
    r = xmat
    tr = r[0] + r[4] + r[8]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        w, x, y, z = 0.25 * s, (r[7] - r[5]) / s, (r[2] - r[6]) / s, (r[3] - r[1]) / s
    elif r[0] > r[4] and r[0] > r[8]:
        s = math.sqrt(1.0 + r[0] - r[4] - r[8]) * 2.0
        w, x, y, z = (r[7] - r[5]) / s, 0.25 * s, (r[1] + r[3]) / s, (r[2] + r[6]) / s
    elif r[4] > r[8]:
        s = math.sqrt(1.0 + r[4] - r[0] - r[8]) * 2.0
        w, x, y, z = (r[2] - r[6]) / s, (r[1] + r[3]) / s, 0.25 * s, (r[5] + r[7]) / s
    else:
        s = math.sqrt(1.0 + r[8] - r[0] - r[4]) * 2.0
        w, x, y, z = (r[3] - r[1]) / s, (r[2] + r[6]) / s, (r[5] + r[7]) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if n > 0.0:
        inv = 1.0 / n
        w, x, y, z = w * inv, x * inv, y * inv, z * inv
    out[0], out[1], out[2], out[3] = w, x, y, z
    out[4], out[5], out[6] = xpos[0], xpos[1], xpos[2]


@kernel("void(float64[::1], float64[::1], float64[:, ::1], float64[::1], float64, float64[:, ::1], float64[::1])")
def frame_terms(frame: np.ndarray, target: np.ndarray, body_jac: np.ndarray, cost: np.ndarray, gain: float,
                weighted_jac: np.ndarray, c_out: np.ndarray) -> None:
    """mink's ``FrameTask`` toward ``target`` at the frame pose ``frame`` with the body Jacobian
    ``body_jac``: its weighted Jacobian (whose Gram matrix is the task's Hessian) into
    ``weighted_jac`` and its linear term into ``c_out``."""
    n = body_jac.shape[1]
    rel = np.empty(7)
    _se3_inverse_multiply(rel, frame, target)
    error = np.empty(6)
    _se3_log(error, rel)
    _se3_inverse_multiply(rel, target, frame)
    jlog = np.empty((6, 6))
    _se3_jlog(jlog, rel)
    for i in range(6):
        for j in range(n):
            acc = 0.0
            for k in range(6):
                acc += jlog[i, k] * body_jac[k, j]
            weighted_jac[i, j] = cost[i] * -acc
    for j in range(n):
        acc = 0.0
        for i in range(6):
            acc += -(cost[i] * (-gain * error[i])) * weighted_jac[i, j]
        c_out[j] = acc


@kernel("boolean(float64[:, ::1], float64[:, ::1])")
def cholesky_solve(p: np.ndarray, rhs: np.ndarray) -> bool:
    """``rhs <- p^-1 rhs`` (columns of ``rhs``) for a symmetric positive definite ``p`` (Cholesky;
    ``p`` is left unchanged). False, ``rhs`` undefined, when ``p`` is not positive definite."""
    n = p.shape[0]
    low = np.zeros((n, n))
    for j in range(n):
        acc = p[j, j]
        for k in range(j):
            acc -= low[j, k] * low[j, k]
        if not acc > 0.0:
            return False
        low[j, j] = math.sqrt(acc)
        for i in range(j + 1, n):
            acc = p[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            low[i, j] = acc / low[j, j]
    for col in range(rhs.shape[1]):
        for i in range(n):
            acc = rhs[i, col]
            for k in range(i):
                acc -= low[i, k] * rhs[k, col]
            rhs[i, col] = acc / low[i, i]
        for i in range(n - 1, -1, -1):
            acc = rhs[i, col]
            for k in range(i + 1, n):
                acc -= low[k, i] * rhs[k, col]
            rhs[i, col] = acc / low[i, i]
    return True


@kernel("boolean(float64[::1], float64[::1], float64[:, ::1], float64[::1], float64[::1], boolean, "
        "float64[::1], float64, float64[::1], float64, float64[::1], float64[::1], float64, float64, "
        "float64[:, ::1], float64[::1], float64[::1], float64[:, ::1], float64[:, ::1])")
def cartesian_objective(xmat: np.ndarray, xpos: np.ndarray, jac_world: np.ndarray, target: np.ndarray,
                        ref: np.ndarray, with_ref: bool, frame_cost: np.ndarray, frame_gain: float,
                        posture_cost: np.ndarray, posture_gain: float, posture_goal: np.ndarray, q: np.ndarray,
                        damping: float, correction_gain: float, p: np.ndarray, c: np.ndarray, c_frame: np.ndarray,
                        wjac: np.ndarray, d: np.ndarray) -> bool:
    """The Cartesian cycle's QP objective and its unconstrained optimum, in one call.

    ``(p, c)``: mink's ``FrameTask`` (site pose ``xmat``/``xpos``, world Jacobian ``jac_world`` of
    the site, rows linear then angular) toward ``target`` plus mink's ``PostureTask`` toward
    ``posture_goal`` at the joints ``q`` (hinges: the error is ``q - goal``) plus ``damping`` on the diagonal;
    ``c_frame``: the frame task's own linear term. ``d`` (2 x n): row 0 the optimum ``-p^-1 c``;
    with ``with_ref``, row 1 the optimum toward the reference pose ``ref`` (the pull-back), of
    which ``correction_gain`` is this cycle's share (row 0 becomes the line plus that share, row 1
    the share: see ``DifferentialIK.step``); without, row 1 is zero. ``wjac``: scratch (6 x n).
    False if ``p`` is not positive definite (``d`` undefined)."""
    n = jac_world.shape[1]
    frame = np.empty(7)
    frame_pose(frame, xmat, xpos)
    body = np.empty((6, n))  # mink's body Jacobian: the world Jacobian rotated into the site frame
    for half in range(2):
        for i in range(3):
            for j in range(n):
                body[3 * half + i, j] = (xmat[i] * jac_world[3 * half, j] + xmat[3 + i] * jac_world[3 * half + 1, j]
                                         + xmat[6 + i] * jac_world[3 * half + 2, j])
    frame_terms(frame, target, body, frame_cost, frame_gain, wjac, c_frame)
    posture_linear = np.empty(n)
    for i in range(n):
        posture_linear[i] = -(posture_cost[i] * (-posture_gain * (q[i] - posture_goal[i]))) * posture_cost[i]
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(6):
                acc += wjac[k, i] * wjac[k, j]
            p[i, j] = acc
        p[i, i] += posture_cost[i] * posture_cost[i]
        p[i, i] += damping
        c[i] = c_frame[i] + posture_linear[i]
    rhs = np.empty((n, 2))
    c_ref = np.zeros(n)
    if with_ref:
        frame_terms(frame, ref, body, frame_cost, frame_gain, wjac, c_ref)
    for i in range(n):
        rhs[i, 0] = -c[i]
        rhs[i, 1] = -(c_ref[i] + posture_linear[i]) if with_ref else 0.0
    if not cholesky_solve(p, rhs):
        return False
    for i in range(n):
        if with_ref:
            d[0, i] = rhs[i, 0] - rhs[i, 1] * (1.0 - correction_gain)
            d[1, i] = rhs[i, 1] * correction_gain
        else:
            d[0, i] = rhs[i, 0]
            d[1, i] = 0.0
    return True


# --------------------------------------------------------------------------- rows and the line
@kernel("UniTuple(float64, 2)(float64[::1], float64[:, ::1], float64[::1], float64[::1], float64)")
def scale_interval(direction: np.ndarray, g: np.ndarray, h: np.ndarray, shift: np.ndarray, shift_scale: float
                   ) -> tuple[float, float]:
    """The interval of ``s`` with ``g @ (s * direction) <= h - shift_scale * g @ shift`` (the rows are
    linear); ``(nan, nan)`` when empty (also when a row the direction does not move is violated)."""
    tiny = 1e-15
    s_hi, s_lo = math.inf, -math.inf
    m, n = g.shape
    for i in range(m):
        ai = 0.0
        bi = 0.0
        for j in range(n):
            ai += g[i, j] * direction[j]
            bi += g[i, j] * shift[j]
        hi = h[i] - shift_scale * bi if shift_scale != 0.0 else h[i]
        if ai > tiny:
            r = hi / ai
            if r < s_hi:
                s_hi = r
        elif ai < -tiny:
            r = hi / ai
            if r > s_lo:
                s_lo = r
        elif hi < -1e-12:
            return math.nan, math.nan
    if s_lo <= s_hi:
        return s_lo, s_hi
    return math.nan, math.nan


@kernel("int64(float64[:, ::1], float64[::1], float64[::1], int64[::1], int64, int64, boolean[::1], float64, "
        "int64, int64)")
def binding_flags(g: np.ndarray, h: np.ndarray, dq: np.ndarray, row_flags: np.ndarray, accel_lo: int,
                  accel_hi: int, velocity_bound: np.ndarray, tol: float, velocity_flag: int,
                  accel_flag: int) -> int:
    """The flags of the rows ``dq`` binds: slack ``h - g dq`` within ``tol + 1e-6 |h|``, inactive
    rows (``h = inf``) never. An acceleration row (``accel_lo <= i < accel_hi``) whose bound is the
    velocity one raises ``velocity_flag``; ``accel_flag`` stays only if a row bound by acceleration binds."""
    m, n = g.shape
    out = 0
    accel_binds = False
    for i in range(m):
        hv = h[i]
        if not math.isfinite(hv):
            continue
        a = 0.0
        for j in range(n):
            a += g[i, j] * dq[j]
        if hv - a <= tol + 1e-6 * abs(hv):
            out |= row_flags[i]
            if accel_lo <= i < accel_hi:
                if velocity_bound[i - accel_lo]:
                    out |= velocity_flag
                else:
                    accel_binds = True
    if not accel_binds:
        out &= ~accel_flag
    return out


@kernel("void(float64, float64[::1], float64[::1], int64[::1], float64[::1], float64[::1])")
def configuration_limit_rows(gain: float, upper: np.ndarray, lower: np.ndarray, qpos_index: np.ndarray,
                             qpos: np.ndarray, h: np.ndarray) -> None:
    """mink's ``ConfigurationLimit`` bounds: ``gain * (upper - q)``, then ``gain * (q - lower)``."""
    k = len(qpos_index)
    for i in range(k):
        x = qpos[qpos_index[i]]
        h[i] = gain * (upper[i] - x)
        h[k + i] = gain * (x - lower[i])


@kernel("float64(float64[:, ::1], float64[::1], float64[::1], float64[::1])")
def path_rate(c: np.ndarray, brake: np.ndarray, u: np.ndarray, out_u: np.ndarray) -> float:
    """:class:`~servo_app.motion.ik_limits.PathBraking`'s rate along ``u``: ``min_i brake_i / |(C u)_i|``
    over the rows ``C u`` moves (above 1e-12 of the largest); inf when none. ``u`` copied to ``out_u``."""
    n = len(u)
    biggest = 0.0
    uf = np.empty(n)
    for i in range(n):
        acc = 0.0
        for k in range(n):  # the products summed in column order, zeros skipped, as the matrix product
            if c[i, k] != 0.0:
                acc += c[i, k] * u[k]
        uf[i] = abs(acc)
        biggest = max(biggest, uf[i])
        out_u[i] = u[i]
    tiny = 1e-12 * max(biggest, 1e-300)
    rate = math.inf
    for i in range(n):
        if uf[i] > tiny:
            rate = min(rate, brake[i] / uf[i])
    return rate


@kernel("void(float64[:, ::1], float64[::1], float64[::1], float64[::1], float64[::1], boolean[::1])")
def acceleration_rows(c: np.ndarray, dq_prev: np.ndarray, vmax: np.ndarray, da: np.ndarray, h: np.ndarray,
                      velocity_bound: np.ndarray) -> None:
    """:class:`~servo_app.motion.ik_limits.AccelerationLimit`'s 12 bounds into ``h``: for ``p = C dq_prev``
    ``min(max(vmax, p - da), p + da)``, then the same of ``-p``; ``velocity_bound``: the rows whose
    bound is ``vmax`` (the reference's operations in its order: equal to the bit)."""
    n = len(dq_prev)
    for half in range(2):
        sign = 1.0 if half == 0 else -1.0
        for i in range(n):
            p = 0.0
            for k in range(n):
                if c[i, k] != 0.0:
                    p += c[i, k] * dq_prev[k]
            p = sign * p
            hi = p + da[i]
            x = max(vmax[i], p - da[i])
            x = hi if hi < x else x
            h[half * n + i] = x
            velocity_bound[half * n + i] = x < hi


@kernel("void(float64[::1], float64[::1], float64[::1], int64[::1], float64[::1], float64, float64, boolean, "
        "float64[::1], float64, float64, float64[::1], float64[::1])")
def braking_rows(bound: np.ndarray, acc: np.ndarray, brake: np.ndarray, cols: np.ndarray, q: np.ndarray, dt: float,
                 lag: float, with_path: bool, u: np.ndarray, rate: float, floor: float, h: np.ndarray,
                 h_path: np.ndarray) -> None:
    """:class:`~servo_app.motion.ik_limits.BrakingLimit`'s 12 bounds ``dt * braking_speed(distance,
    acc, dt + lag)`` into ``h`` (distance to ``bound``: upper bounds, then lower ones negated), and
    into ``h_path`` the same with the path's deceleration (``with_path``; else ``h``)."""
    n = len(q)
    horizon = dt + lag
    t2 = horizon * horizon
    for i in range(2 * n):
        d = bound[i] - q[i] if i < n else bound[i] + q[i - n]
        d = d if d > 0.0 else 0.0
        a = acc[i]
        h[i] = dt * (a * (math.sqrt(t2 + 2.0 * d / a) - horizon))
        if with_path:
            cap = brake[i % n]
            x = rate * abs(u[cols[i % n]])
            fc = floor * cap
            x = fc if fc > x else x
            a = cap if cap < x else x
            h_path[i] = dt * (a * (math.sqrt(t2 + 2.0 * d / a) - horizon))
        else:
            h_path[i] = h[i]


@kernel("boolean(float64[::1], float64[::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], "
        "float64[::1])")
def collision_drift(q: np.ndarray, q_refresh: np.ndarray, far_weights: np.ndarray, near_q: np.ndarray,
                    near_weights: np.ndarray, far_slack: np.ndarray, drift: np.ndarray) -> bool:
    """The collision cache's bounds (see ``CollisionLimit.fill``): True when a far pair could be within
    detection distance at ``q`` (its slack minus ``far_weights . |q - q_refresh|`` at most 0: refresh);
    else each near pair's drift ``near_weights . |q - near_q|`` into ``drift``."""
    n = len(q)
    for k in range(far_weights.shape[0]):
        acc = 0.0
        for j in range(n):
            acc += far_weights[k, j] * abs(q[j] - q_refresh[j])
        if far_slack[k] - acc <= 0.0:
            return True
    for k in range(near_q.shape[0]):
        acc = 0.0
        for j in range(n):
            acc += abs(q[j] - near_q[k, j]) * near_weights[k, j]
        drift[k] = acc
    return False


@kernel("boolean(float64[::1], float64[::1], float64, float64[::1], float64[::1], float64[::1])")
def step_outputs_into(dq: np.ndarray, q: np.ndarray, dt: float, dq_copy: np.ndarray, q_next: np.ndarray,
                      velocity: np.ndarray) -> bool:
    """A diff-IK step's arrays from its increment ``dq`` at the joints ``q``: ``dq_copy`` (a copy),
    ``q_next`` = ``q + dq``, ``velocity`` = ``dq / dt``; False (nothing written) if ``dq`` is not finite."""
    n = dq.shape[0]
    for i in range(n):
        if not math.isfinite(dq[i]):
            return False
    for i in range(n):
        dq_copy[i] = dq[i]
        q_next[i] = q[i] + dq[i]
        velocity[i] = dq[i] / dt
    return True


@kernel("boolean(float64[::1], float64[::1], float64, float64[:, ::1])")
def step_outputs(dq: np.ndarray, q: np.ndarray, dt: float, out: np.ndarray) -> bool:
    """:func:`step_outputs_into` into the rows of ``out`` (3 x n)."""
    return step_outputs_into(dq, q, dt, out[0], out[1], out[2])


@kernel("void(float64, float64[::1], float64[::1], float64[::1])")
def line_point(s: float, direction: np.ndarray, shift: np.ndarray, out: np.ndarray) -> None:
    """``s * direction + shift`` into ``out``: numpy's two operations per entry, in its order."""
    for i in range(direction.shape[0]):
        out[i] = s * direction[i] + shift[i]


@kernel("float64(float64[::1], float64[::1])")
def dot(a: np.ndarray, b: np.ndarray) -> float:
    """``a @ b``: the products summed in index order, as numpy's dot of two 6-vectors sums them (equal
    to the bit on 200 000 random pairs here; tests/test_ik_kernels.py holds it to numpy within 1e-12)."""
    acc = 0.0
    for i in range(a.shape[0]):
        acc += a[i] * b[i]
    return acc


@kernel("Tuple((float64, int64, boolean))(float64[::1], float64[::1], float64, float64, float64[::1], float64, "
        "float64[:, ::1], float64[::1], int64[::1], int64, int64, boolean[::1], float64, int64, int64, "
        "float64[::1], float64[::1], float64[::1])")
def step_result_into(dq: np.ndarray, d: np.ndarray, s_goal: float, s_sing: float, q: np.ndarray, dt: float,
                     g: np.ndarray, h: np.ndarray, row_flags: np.ndarray, accel_lo: int, accel_hi: int,
                     velocity_bound: np.ndarray, tol: float, velocity_flag: int, accel_flag: int,
                     dq_copy: np.ndarray, q_next: np.ndarray, velocity: np.ndarray) -> tuple[float, int, bool]:
    """The end of a diff-IK step with the increment ``dq``, in one call: (the share of the command ``d``
    delivered, the flags of the rows ``dq`` binds (:func:`binding_flags`), :func:`step_outputs_into`
    ``dq_copy``, ``q_next``, ``velocity``). The share is ``min(max(dq.d / d.d, 0), 1) * s_sing`` when
    ``s_goal`` is 1 and ``d`` is not zero, else 0, with Python's min and max (a NaN stays NaN)."""
    scale = 0.0
    dd = dot(d, d)
    if s_goal == 1.0 and dd > 0.0:
        x = dot(dq, d) / dd
        if x < 0.0:  # max(x, 0.0)
            x = 0.0
        if x > 1.0:  # min(x, 1.0)
            x = 1.0
        scale = x * s_sing
    bits = binding_flags(g, h, dq, row_flags, accel_lo, accel_hi, velocity_bound, tol, velocity_flag, accel_flag)
    return scale, bits, step_outputs_into(dq, q, dt, dq_copy, q_next, velocity)


@kernel("Tuple((float64, int64, boolean))(float64[::1], float64[::1], float64, float64, float64[::1], float64, "
        "float64[:, ::1], float64[::1], int64[::1], int64, int64, boolean[::1], float64, int64, int64, "
        "float64[:, ::1])")
def step_result(dq: np.ndarray, d: np.ndarray, s_goal: float, s_sing: float, q: np.ndarray, dt: float,
                g: np.ndarray, h: np.ndarray, row_flags: np.ndarray, accel_lo: int, accel_hi: int,
                velocity_bound: np.ndarray, tol: float, velocity_flag: int, accel_flag: int,
                out: np.ndarray) -> tuple[float, int, bool]:
    """:func:`step_result_into` into the rows of ``out`` (3 x n)."""
    return step_result_into(dq, d, s_goal, s_sing, q, dt, g, h, row_flags, accel_lo, accel_hi, velocity_bound, tol,
                            velocity_flag, accel_flag, out[0], out[1], out[2])


@kernel("boolean(float64[::1])")
def all_finite(v: np.ndarray) -> bool:
    """``np.isfinite(v).all()`` for a float vector."""
    for x in v:  # noqa: SIM110 - a loop numba compiles (no generator expression)
        if not math.isfinite(x):
            return False
    return True


@kernel("UniTuple(float64, 4)(float64[::1], float64, float64, float64, float64, float64, float64, boolean, "
        "float64, float64, int64, int64, float64[::1])")
def shoulder_row(q: np.ndarray, a1: float, a2: float, a3: float, d4: float, shoulder_m: float, brake_acc: float,
                 top: bool, dt: float, lag: float, col2: int, col3: int, g: np.ndarray
                 ) -> tuple[float, float, float, float]:
    """:class:`~servo_app.motion.ik_limits.ConfigurationGuard`'s row (the wrist centre stays on its side
    of the J1 axis, braking at ``brake_acc``): its coefficients into ``g`` (columns ``col2``, ``col3``
    for q2, q3), and ``(h, distance, grad2, grad3)``: the bound, the distance to the boundary and the
    gradient's two entries (for the path's deceleration). The reference's float operations in its
    order (equal to the bit)."""
    q2, q3 = q[1], q[2]
    phi = q2 - q3
    cphi, sphi = math.cos(phi), math.sin(phi)
    x = a1 + a2 * math.sin(q2) + d4 * cphi + a3 * sphi
    dphi = -d4 * sphi + a3 * cphi
    g1, g2 = a2 * math.cos(q2) + dphi, -dphi
    sign = 1.0 if top else -1.0
    distance = sign * x - shoulder_m
    for i in range(len(g)):
        g[i] = 0.0
    g[col2] = -sign * g1
    g[col3] = -sign * g2
    horizon = dt + lag
    d = distance if distance > 0.0 else 0.0
    h = dt * (brake_acc * (math.sqrt(horizon * horizon + 2.0 * d / brake_acc) - horizon))
    return h, distance, g1, g2


# ------------------------------------------------------------------------ collision broad phase
# Geom shapes the broad phase knows exactly (geom_size as MuJoCo stores it): a sphere or a capsule is
# a segment (half length along the geom's z, 0 for a sphere) swept by its radius; a plane is the
# half-space below its z axis. Any other shape is bounded by its bounding sphere (rbound).
SHAPE_SEGMENT = 0
SHAPE_PLANE = 1
SHAPE_OTHER = 2


@kernel("float64(float64[:, ::1], float64[:, ::1], int64, float64, int64, float64)")
def segment_distance(xpos: np.ndarray, xmat: np.ndarray, g1: int, half1: float, g2: int, half2: float) -> float:
    """Distance between the segments of geoms ``g1`` and ``g2`` (centre ``xpos[g]``, half length
    ``half`` along the z column of ``xmat[g]``): the closest points by clamped parameters (Ericson,
    Real-Time Collision Detection, 5.1.9)."""
    p1x = xpos[g1, 0] - half1 * xmat[g1, 2]
    p1y = xpos[g1, 1] - half1 * xmat[g1, 5]
    p1z = xpos[g1, 2] - half1 * xmat[g1, 8]
    d1x, d1y, d1z = 2.0 * half1 * xmat[g1, 2], 2.0 * half1 * xmat[g1, 5], 2.0 * half1 * xmat[g1, 8]
    p2x = xpos[g2, 0] - half2 * xmat[g2, 2]
    p2y = xpos[g2, 1] - half2 * xmat[g2, 5]
    p2z = xpos[g2, 2] - half2 * xmat[g2, 8]
    d2x, d2y, d2z = 2.0 * half2 * xmat[g2, 2], 2.0 * half2 * xmat[g2, 5], 2.0 * half2 * xmat[g2, 8]
    rx, ry, rz = p1x - p2x, p1y - p2y, p1z - p2z
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    tiny = 1e-300
    s = 0.0
    t = 0.0
    if a <= tiny and e <= tiny:
        pass
    elif a <= tiny:
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = d1x * rx + d1y * ry + d1z * rz
        if e <= tiny:
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = d1x * d2x + d1y * d2y + d1z * d2z
            denom = a * e - b * b
            if denom > 0.0:
                s = min(max((b * f - c * e) / denom, 0.0), 1.0)
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    x = rx + d1x * s - d2x * t
    y = ry + d1y * s - d2y * t
    z = rz + d1z * s - d2z * t
    return math.sqrt(x * x + y * y + z * z)


@kernel("float64(float64[:, ::1], float64[:, ::1], int64, int64, float64)")
def plane_segment_distance(xpos: np.ndarray, xmat: np.ndarray, plane: int, g: int, half: float) -> float:
    """Signed distance from the plane geom ``plane`` (its z axis the normal) to the nearer end of geom
    ``g``'s segment (half length ``half`` along its z axis)."""
    nx, ny, nz = xmat[plane, 2], xmat[plane, 5], xmat[plane, 8]
    centre = (nx * (xpos[g, 0] - xpos[plane, 0]) + ny * (xpos[g, 1] - xpos[plane, 1])
              + nz * (xpos[g, 2] - xpos[plane, 2]))
    along = half * abs(nx * xmat[g, 2] + ny * xmat[g, 5] + nz * xmat[g, 8])
    return centre - along


@kernel("int64(int64[::1], float64[::1], float64[::1], float64[::1], int64[::1], int64[::1], boolean[::1], "
        "float64[:, ::1], float64[:, ::1], float64, float64, float64[::1], int64[::1], float64[:, ::1], float64[::1], "
        "float64[::1])")
def collision_screen(shape: np.ndarray, radius: np.ndarray, half: np.ndarray, rbound: np.ndarray, g1: np.ndarray,
                     g2: np.ndarray, exact: np.ndarray, xpos: np.ndarray, xmat: np.ndarray, tol: float,
                     distmax: float, lower_bound: np.ndarray, candidates: np.ndarray, g: np.ndarray, h: np.ndarray,
                     h_path: np.ndarray) -> int:
    """A lower bound on each geom pair's distance into ``lower_bound``, and the ``exact`` pairs that
    may be within ``distmax`` into ``candidates`` (their count returned). Every pair's row is reset to
    inactive (``g`` row 0, ``h = h_path = inf``) for :func:`collision_rows` to fill.

    ``exact`` pairs (two segments, or a plane and a segment): their distance (segments: radii
    subtracted) less ``tol``, the allowance for the narrow phase's own error. Others: MuJoCo's
    bounding-sphere bound (centre distance less both rbound; with a plane: the other centre's height
    less its rbound), -inf when a geom is unbounded. Per geom: ``shape`` (``SHAPE_*``), segment
    ``radius`` and ``half`` length, ``rbound``; per pair ``g1``, ``g2``; the geoms' world poses ``xpos``
    and ``xmat`` (MuJoCo's ``geom_xpos``, ``geom_xmat``)."""
    count = 0
    for k in range(len(g1)):
        for j in range(g.shape[1]):
            g[k, j] = 0.0
        h[k] = math.inf
        h_path[k] = math.inf
        a, b = g1[k], g2[k]
        if exact[k]:
            if shape[a] == SHAPE_PLANE:
                lb = plane_segment_distance(xpos, xmat, a, b, half[b]) - radius[b]
            elif shape[b] == SHAPE_PLANE:
                lb = plane_segment_distance(xpos, xmat, b, a, half[a]) - radius[a]
            else:
                lb = segment_distance(xpos, xmat, a, half[a], b, half[b]) - radius[a] - radius[b]
            lb -= tol
            if lb <= distmax:
                candidates[count] = k
                count += 1
        elif rbound[a] > 0.0 and rbound[b] > 0.0:
            dx, dy, dz = xpos[a, 0] - xpos[b, 0], xpos[a, 1] - xpos[b, 1], xpos[a, 2] - xpos[b, 2]
            lb = math.sqrt(dx * dx + dy * dy + dz * dz) - rbound[a] - rbound[b]
        elif shape[a] == SHAPE_PLANE and rbound[b] > 0.0:
            lb = plane_segment_distance(xpos, xmat, a, b, 0.0) - rbound[b]
        elif shape[b] == SHAPE_PLANE and rbound[a] > 0.0:
            lb = plane_segment_distance(xpos, xmat, b, a, 0.0) - rbound[a]
        else:
            lb = -math.inf
        lower_bound[k] = lb
    return count


@kernel("void(float64[:, ::1], float64[:, ::1], float64[:, ::1], int64[:, ::1], int64[::1], float64[::1], int64)")
def point_jacobian(out: np.ndarray, cdof: np.ndarray, subtree_com: np.ndarray, tree: np.ndarray,
                   dof_parentid: np.ndarray, point: np.ndarray, body: int) -> None:
    """The translational Jacobian (3 x nv) of the world ``point`` fixed to ``body`` into ``out``, as
    ``mj_jac`` makes it (the same operations: equal to the bit): per dof up the chain,
    ``cdof[3:] + cdof[:3] x (point - subtree_com[root])``. ``cdof`` and ``subtree_com`` from ``mj_comPos``;
    ``tree`` rows (per body): ``body_rootid``, ``body_dofnum``, ``body_dofadr``, ``body_parentid``."""
    for r in range(3):
        for j in range(out.shape[1]):
            out[r, j] = 0.0
    root = tree[0, body]
    ox = point[0] - subtree_com[root, 0]
    oy = point[1] - subtree_com[root, 1]
    oz = point[2] - subtree_com[root, 2]
    while body > 0 and tree[1, body] == 0:  # fixed bodies move with their parent
        body = tree[3, body]
    if body == 0:
        return
    i = tree[2, body] + tree[1, body] - 1
    while i >= 0:
        a0, a1, a2 = cdof[i, 0], cdof[i, 1], cdof[i, 2]
        out[0, i] = cdof[i, 3] + (a1 * oz - a2 * oy)
        out[1, i] = cdof[i, 4] + (a2 * ox - a0 * oz)
        out[2, i] = cdof[i, 5] + (a0 * oy - a1 * ox)
        i = dof_parentid[i]


@kernel("UniTuple(float64, 2)(float64[::1], float64[:, ::1], float64[:, ::1], int64[:, ::1], int64[::1], int64, "
        "int64, float64[:, ::1], float64[:, ::1], float64, float64, float64, float64, float64, float64, float64, "
        "boolean, float64[::1], float64, float64, float64[::1])")
def collision_row(fromto: np.ndarray, cdof: np.ndarray, subtree_com: np.ndarray, tree: np.ndarray,
                  dof_parentid: np.ndarray, body1: int, body2: int, jac1: np.ndarray, jac2: np.ndarray, dist: float,
                  gain: float, min_dist: float, relax: float, brake_acc: float, dt: float, horizon: float,
                  with_path: bool, u: np.ndarray, rate: float, floor: float, row: np.ndarray) -> tuple[float, float]:
    """A collision pair's row from the narrow phase (distance ``dist``, closest points ``fromto``, on
    ``body1`` and ``body2``): the coefficients into ``row``, ``(h, h_path)`` returned (see
    ``CollisionLimit``). ``jac1``, ``jac2``: scratch (3 x nv); the rest as :func:`point_jacobian`.

    The coefficients repeat mink's operations as MuJoCo makes them (``mju_normalize3`` of
    ``to - from``, ``mj_jac`` at both points, ``jac2 - jac1``, the product with the normal summed
    over its rows in order, skipping zero components, as ``mju_mulMatTVec``), so they equal mink's
    to the bit; the bounds are the float arithmetic of ``braking_speed_scalar`` and
    ``PathBraking.decel_scalar``."""
    nx, ny, nz = fromto[3] - fromto[0], fromto[4] - fromto[1], fromto[5] - fromto[2]
    nx, ny, nz, _ = _normalize3(nx, ny, nz)
    point_jacobian(jac2, cdof, subtree_com, tree, dof_parentid, fromto[3:], body2)
    point_jacobian(jac1, cdof, subtree_com, tree, dof_parentid, fromto[:3], body1)
    flip = dist >= 0.0  # mink's sign: the distance must not shrink (penetrating: must grow)
    along = 0.0
    for j in range(row.shape[0]):
        acc = 0.0
        if nx != 0.0:
            acc += (jac2[0, j] - jac1[0, j]) * nx
        if ny != 0.0:
            acc += (jac2[1, j] - jac1[1, j]) * ny
        if nz != 0.0:
            acc += (jac2[2, j] - jac1[2, j]) * nz
        row[j] = -acc if flip else acc
        along += row[j] * u[j]
    h0 = (gain * (dist - min_dist) / 1.0) + relax if dist > min_dist else relax
    gap = (h0 - relax) / gain
    t2 = horizon * horizon
    d = gap if gap > 0.0 else 0.0
    h = min(h0, dt * (brake_acc * (math.sqrt(t2 + 2.0 * d / brake_acc) - horizon)) + relax)
    if not with_path:
        return h, h0
    acc = min(brake_acc, max(rate * abs(along), floor * brake_acc))
    return h, min(h0, dt * (acc * (math.sqrt(t2 + 2.0 * d / acc) - horizon)) + relax)


@kernel("void(int64, int64[::1], float64[::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], int64[:, ::1], "
        "int64[::1], int64[::1], int64[::1], float64[:, ::1], float64[:, ::1], float64, float64, float64, float64, "
        "float64, float64, boolean, float64[::1], float64, float64, float64[:, ::1], float64[::1], float64[::1])")
def collision_rows(count: int, pairs: np.ndarray, dists: np.ndarray, fromtos: np.ndarray, cdof: np.ndarray,
                   subtree_com: np.ndarray, tree: np.ndarray, dof_parentid: np.ndarray, body1: np.ndarray,
                   body2: np.ndarray, jac1: np.ndarray, jac2: np.ndarray, gain: float, min_dist: float, relax: float,
                   brake_acc: float, dt: float, horizon: float, with_path: bool, u: np.ndarray, rate: float,
                   floor: float, g: np.ndarray, h: np.ndarray, h_path: np.ndarray) -> None:
    """:func:`collision_row` for the first ``count`` of ``pairs`` (their narrow phases' ``dists`` and
    ``fromtos``; bodies per pair ``body1``, ``body2``), into their rows of ``g``, ``h`` and ``h_path``."""
    for k in range(count):
        idx = pairs[k]
        h[idx], h_path[idx] = collision_row(fromtos[k], cdof, subtree_com, tree, dof_parentid, body1[idx],
                                            body2[idx], jac1, jac2, dists[k], gain, min_dist, relax, brake_acc, dt,
                                            horizon, with_path, u, rate, floor, g[idx])


@kernel("boolean(float64[:, ::1], float64[:, ::1], int64[:, ::1], int64[::1], int64, float64[:, ::1], "
        "float64[:, ::1], int64, float64[:, ::1], float64[::1], float64[::1], boolean, float64[::1], float64, "
        "float64[::1], float64, float64[::1], float64[::1], float64, float64, float64[:, ::1], float64[::1], "
        "float64[::1], float64[:, ::1], float64[:, ::1])")
def site_objective(cdof: np.ndarray, subtree_com: np.ndarray, tree: np.ndarray, dof_parentid: np.ndarray,
                   body: int, site_xmat: np.ndarray, site_xpos: np.ndarray, site: int, jac_world: np.ndarray,
                   target: np.ndarray, ref: np.ndarray, with_ref: bool, frame_cost: np.ndarray, frame_gain: float,
                   posture_cost: np.ndarray, posture_gain: float, posture_goal: np.ndarray, q: np.ndarray,
                   damping: float, correction_gain: float, p: np.ndarray, c: np.ndarray, c_frame: np.ndarray,
                   wjac: np.ndarray, d: np.ndarray) -> bool:
    """:func:`cartesian_objective` of the frame task on ``site`` (of ``body``), its world Jacobian made
    here into ``jac_world`` as ``mj_jacSite`` makes it (:func:`point_jacobian` at the site for the
    linear rows, ``cdof``'s angular part for the angular rows: equal to the bit)."""
    point_jacobian(jac_world[:3], cdof, subtree_com, tree, dof_parentid, site_xpos[site], body)
    for j in range(jac_world.shape[1]):
        jac_world[3, j] = 0.0
        jac_world[4, j] = 0.0
        jac_world[5, j] = 0.0
    b = body
    while b > 0 and tree[1, b] == 0:
        b = tree[3, b]
    if b > 0:
        i = tree[2, b] + tree[1, b] - 1
        while i >= 0:
            jac_world[3, i] = cdof[i, 0]
            jac_world[4, i] = cdof[i, 1]
            jac_world[5, i] = cdof[i, 2]
            i = dof_parentid[i]
    return cartesian_objective(site_xmat[site], site_xpos[site], jac_world, target, ref, with_ref, frame_cost,
                               frame_gain, posture_cost, posture_gain, posture_goal, q, damping, correction_gain,
                               p, c, c_frame, wjac, d)


# ------------------------------------------------------------------------------------- QP data
@kernel("boolean(float64[:, ::1], float64[::1], float64[:, ::1], float64[::1], float64, float64, float64[::1], "
        "float64[::1])")
def scaled_qp_data(p: np.ndarray, q: np.ndarray, g: np.ndarray, h: np.ndarray, scale: float, cap: float,
                   q_out: np.ndarray, h_out: np.ndarray) -> bool:
    """:class:`~servo_app.motion.qp.PersistentQP`'s data in the solver's units: ``q / scale`` into
    ``q_out``, ``min(h / scale, cap)`` into ``h_out`` (``+inf`` rows: the solver's infinity ``cap``).
    False when ``p``, ``q`` or ``g`` has a non-finite entry or ``h`` a NaN (outputs then undefined)."""
    for i in range(p.shape[0]):
        for j in range(p.shape[1]):
            if not math.isfinite(p[i, j]):
                return False
    for i in range(g.shape[0]):
        for j in range(g.shape[1]):
            if not math.isfinite(g[i, j]):
                return False
    for i in range(len(q)):
        x = q[i] / scale
        if not math.isfinite(x):
            return False
        q_out[i] = x
    for i in range(len(h)):
        x = h[i] / scale
        if math.isnan(x):
            return False
        h_out[i] = cap if cap < x else x
    return True


# ------------------------------------------------------------------------------ all limit rows
@kernel("void(float64[::1], float64, "
        "float64, float64[::1], float64[::1], int64[::1], "
        "float64[:, ::1], float64[::1], float64[::1], float64[::1], boolean[::1], "
        "float64[::1], float64[::1], float64[::1], int64[::1], float64, "
        "boolean, float64[::1], float64, float64, "
        "float64[::1], float64, float64, boolean, float64, int64[::1], float64[::1], "
        "int64[::1], float64[::1], float64[::1])")
def limit_rows(q: np.ndarray, dt: float,
               cfg_gain: float, cfg_upper: np.ndarray, cfg_lower: np.ndarray, cfg_qpos: np.ndarray,
               c: np.ndarray, dq_prev: np.ndarray, vmax: np.ndarray, da: np.ndarray, velocity_bound: np.ndarray,
               bound: np.ndarray, brake_acc2: np.ndarray, brake: np.ndarray, cols: np.ndarray, brake_lag: float,
               with_path: bool, u: np.ndarray, rate: float, floor: float,
               arm: np.ndarray, shoulder_m: float, shoulder_acc: float, top: bool, guard_lag: float,
               guard_cols: np.ndarray, g_guard: np.ndarray,
               starts: np.ndarray, h: np.ndarray, h_path: np.ndarray) -> None:
    """Every limit row of the diff-IK's QP but the collision rows, in one call, into ``h`` and
    ``h_path`` (the whole arrays; ``starts``: the acceleration block's first row, the braking block's,
    the configuration guard's row) and the guard's coefficients into ``g_guard``:

    - mink's ``ConfigurationLimit`` bounds from row 0 (:func:`configuration_limit_rows`);
    - ``AccelerationLimit`` (:func:`acceleration_rows`), ``BrakingLimit`` (:func:`braking_rows`, with
      the path's deceleration ``with_path``: direction ``u``, ``rate``, ``floor``);
    - ``ConfigurationGuard``'s row (:func:`shoulder_row`; ``arm``: a1, a2, a3, d4; ``guard_cols``: the
      dof columns of q2 and q3), its path bound as ``PathBraking.decel_scalar`` and
      ``braking_speed_scalar`` give it;
    - ``h_path = h`` on the rows before the braking block (they have no path version).

    The same kernels the limits' own ``fill`` call, so the same numbers to the bit."""
    k = len(cfg_qpos)
    acc_at, brk_at, guard_at = starts[0], starts[1], starts[2]
    n = len(dq_prev)
    configuration_limit_rows(cfg_gain, cfg_upper, cfg_lower, cfg_qpos, q, h[: 2 * k])
    acceleration_rows(c, dq_prev, vmax, da, h[acc_at: acc_at + 2 * n], velocity_bound)
    braking_rows(bound, brake_acc2, brake, cols, q, dt, brake_lag, with_path, u if with_path else q, rate, floor,
                 h[brk_at: brk_at + 2 * n], h_path[brk_at: brk_at + 2 * n])
    col2, col3 = guard_cols[0], guard_cols[1]
    hg, distance, g1, g2 = shoulder_row(q, arm[0], arm[1], arm[2], arm[3], shoulder_m, shoulder_acc, top, dt,
                                        guard_lag, col2, col3, g_guard)
    h[guard_at] = hg
    if with_path:
        x = rate * abs(g1 * u[col2] + g2 * u[col3])
        fc = floor * shoulder_acc
        acc = min(shoulder_acc, max(x, fc))
        horizon = dt + guard_lag
        d = distance if distance > 0.0 else 0.0
        h_path[guard_at] = dt * (acc * (math.sqrt(horizon * horizon + 2.0 * d / acc) - horizon))
    else:
        h_path[guard_at] = hg
    for i in range(brk_at):
        h_path[i] = h[i]


# ---------------------------------------------------------------- the rows with their narrow phases
@kernel("int64(int64, int64, float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[:, ::1], int64[:, ::1], "
        "int64[::1], int64[::1], float64[::1], float64[::1], float64[::1], int64[::1], int64[::1], boolean[::1], "
        "int64[::1], int64[::1], float64[::1], int64[::1], int64[::1], float64[::1], float64[:, ::1], "
        "float64[:, ::1], float64[:, ::1], float64[::1], boolean, float64[::1], float64, float64, "
        "float64[:, ::1], float64[::1], float64[::1])")
def collision_fill(model: int, data: int, geom_xpos: np.ndarray, geom_xmat: np.ndarray, cdof: np.ndarray,
                   subtree_com: np.ndarray, tree: np.ndarray, dof_parentid: np.ndarray, shape: np.ndarray,
                   radius: np.ndarray, half: np.ndarray, rbound: np.ndarray, g1: np.ndarray, g2: np.ndarray,
                   exact: np.ndarray, body1: np.ndarray, body2: np.ndarray, lower_bound: np.ndarray,
                   candidates: np.ndarray, row_pairs: np.ndarray, dists: np.ndarray, fromtos: np.ndarray,
                   jac1: np.ndarray, jac2: np.ndarray, params: np.ndarray, with_path: bool, u: np.ndarray,
                   rate: float, floor: float, g: np.ndarray, h: np.ndarray, h_path: np.ndarray) -> int:
    """``CollisionLimit.fill`` for a limit with no cached pairs (every pair exact), in one call: the
    screen (:func:`collision_screen`), MuJoCo's narrow phase (``mj_geomDistance``, the reference's call,
    through its C function) on the pairs it leaves, and their rows (:func:`collision_rows`); the
    number of rows returned. ``model``, ``data``: the structs' addresses; ``params``: the screen
    tolerance, the detection distance, gain, minimum distance, bound relaxation, braking deceleration,
    dt and ``lag_s``."""
    tol, distmax, gain, min_dist, relax, brake_acc, dt, lag = (params[0], params[1], params[2], params[3],
                                                               params[4], params[5], params[6], params[7])
    count = collision_screen(shape, radius, half, rbound, g1, g2, exact, geom_xpos, geom_xmat, tol, distmax,
                             lower_bound, candidates, g, h, h_path)
    m, d = address(model), address(data)
    rows = 0
    for k in range(count):
        idx = candidates[k]
        dist = mj_geomDistance(m, d, np.int32(g1[idx]), np.int32(g2[idx]), distmax, doubles(fromtos[rows]))
        if abs(dist - distmax) >= 1e-12:
            row_pairs[rows] = idx
            dists[rows] = dist
            rows += 1
    if rows:
        collision_rows(rows, row_pairs, dists, fromtos, cdof, subtree_com, tree, dof_parentid, body1, body2, jac1,
                       jac2, gain, min_dist, relax, brake_acc, dt, dt + lag, with_path, u, rate, floor, g, h, h_path)
    return rows


# ------------------------------------------------------------------- the Cartesian step in one call
# What cartesian_step is asked to do (DifferentialIK.step_owned's command), and what it returns
# besides its outputs: the step done (STEP_DONE, with the bits below), or why it left the step to
# the Python code (which then does the whole step: nothing the IK keeps was changed).
TWIST_BASE, TWIST_TOOL, CARTESIAN_STOP = 0, 1, 2
STEP_NOT_CARTESIAN = -1  # a stop that is not braking along a Cartesian line
STEP_SINGULARITY = -2  # the singularity factor is needed (condition above singularity_slow, the command moves)
STEP_OFF_LINE = -3  # no scale fits the path-keeping rows: blend, QP or braking
STEP_NOT_DEFINITE = -4  # the objective's Hessian is not positive definite (the Python code raises)
LAST_XI_KEPT, LAST_XI_NEW, LAST_XI_CLEARED = 0, 1, 2  # the IK's last line: as it was, this twist, none
STEP_FINITE = 4  # bit: the increment is finite (else the Python code's defensive branch)
# cartesian_step's state bits: a reference pose and a last line are given, the Cartesian mode changes,
# the mode is (stays) "twist", the configuration to keep is Top.
STATE_HAS_REF, STATE_HAS_LAST_XI, STATE_MODE_CHANGED, STATE_TWIST_MODE, STATE_TOP = 1, 2, 4, 8, 16


@kernel("float64(float64, float64, float64)")
def _nearest(goal: float, lo: float, hi: float) -> float:
    """``min(max(goal, lo), hi)`` with Python's min and max (``_path_scale``'s), NaN when not finite."""
    s = goal
    if lo > s:
        s = lo
    if hi < s:
        s = hi
    return s if math.isfinite(s) else math.nan



# cartesian_step's arrays that stay (constants, the MjData's arrays, scratch, the rows), reached through
# one table of addresses (row k: ``ctypes.data``, then the shape; DifferentialIK builds it in this
# order, checking each array's kind: f float64, i int64, b bool, its dimensions and that it is
# C-contiguous): the kernel then takes 14 arguments instead of 76 (numba's dispatch types and unboxes
# each: ~60 ns in a tight loop, several times that cold). The owners keep the arrays alive.
CARTESIAN_ARRAYS: tuple[tuple[str, str, int], ...] = (
    ("consts", "f", 1), ("ints", "i", 1), ("track_weights", "f", 1), ("qpos", "f", 1), ("cdof", "f", 2),
    ("subtree_com", "f", 2), ("site_xmat", "f", 2), ("site_xpos", "f", 2), ("geom_xpos", "f", 2),
    ("geom_xmat", "f", 2), ("tree", "i", 2), ("dof_parentid", "i", 1), ("jac_flange", "f", 2), ("cond_work", "f", 2),
    ("jac_world", "f", 2), ("frame_cost", "f", 1), ("posture_cost", "f", 1), ("p", "f", 2), ("c", "f", 1),
    ("c_frame", "f", 1), ("wjac", "f", 2), ("d", "f", 2), ("rate_c", "f", 2), ("path_brake", "f", 1),
    ("path_u", "f", 1), ("cfg_upper", "f", 1), ("cfg_lower", "f", 1), ("cfg_qpos", "i", 1), ("vmax", "f", 1),
    ("da", "f", 1), ("velocity_bound", "b", 1), ("brake_acc2", "f", 1), ("brake", "f", 1), ("cols", "i", 1),
    ("arm", "f", 1), ("guard_cols", "i", 1), ("g_guard", "f", 1), ("starts", "i", 1), ("g", "f", 2), ("h", "f", 1),
    ("h_path", "f", 1), ("row_flags", "i", 1), ("shape", "i", 1), ("radius", "f", 1), ("half", "f", 1),
    ("rbound", "f", 1), ("g1", "i", 1), ("g2", "i", 1), ("exact", "b", 1), ("body1", "i", 1), ("body2", "i", 1),
    ("lower_bound", "f", 1), ("candidates", "i", 1), ("row_pairs", "i", 1), ("dists", "f", 1), ("fromtos", "f", 2),
    ("jac1", "f", 2), ("jac2", "f", 2), ("col_params", "f", 1), ("g_col", "f", 2), ("h_col", "f", 1),
    ("h_path_col", "f", 1),
)


@kernel("void(float64[::1], float64[::1], boolean, boolean, float64, int64[:, ::1])")
def table_rows(dq_prev: np.ndarray, bound: np.ndarray, top: bool, with_path: bool, rate: float,
               table: np.ndarray) -> None:
    """``DifferentialIK._rows`` in one call, its arrays through ``table`` (``CARTESIAN_ARRAYS``): every
    limit row (:func:`limit_rows`) and the collision rows with their narrow phases
    (:func:`collision_fill`), at the configuration's joints. Per call: the acceleration rows' last
    increment ``dq_prev``, the braking rows' ``bound``, the side ``top`` of the configuration guard,
    and the path (``with_path``: its direction is the table's ``path_u``, ``rate``)."""
    consts, ints = table_f1(table, 0), table_i1(table, 1)
    qpos, cdof, subtree_com = table_f1(table, 3), table_f2(table, 4), table_f2(table, 5)
    path_u = table_f1(table, 24)
    u = path_u if with_path else qpos
    path_rate_used = rate if with_path else 0.0
    floor = consts[11]
    limit_rows(qpos, consts[0], consts[9], table_f1(table, 25), table_f1(table, 26), table_i1(table, 27),
               table_f2(table, 22), dq_prev, table_f1(table, 28), table_f1(table, 29), table_b1(table, 30),
               bound, table_f1(table, 31), table_f1(table, 32), table_i1(table, 33), consts[10], with_path, u,
               path_rate_used, floor, table_f1(table, 34), consts[12], consts[13], top, consts[14],
               table_i1(table, 35), table_f1(table, 36), table_i1(table, 37), table_f1(table, 39),
               table_f1(table, 40))
    if ints[8]:
        col_u = path_u if with_path else np.zeros(qpos.shape[0])
        collision_fill(ints[0], ints[1], table_f2(table, 8), table_f2(table, 9), cdof, subtree_com,
                       table_i2(table, 10), table_i1(table, 11), table_i1(table, 42), table_f1(table, 43),
                       table_f1(table, 44), table_f1(table, 45), table_i1(table, 46), table_i1(table, 47),
                       table_b1(table, 48), table_i1(table, 49), table_i1(table, 50), table_f1(table, 51),
                       table_i1(table, 52), table_i1(table, 53), table_f1(table, 54), table_f2(table, 55),
                       table_f2(table, 56), table_f2(table, 57), table_f1(table, 58), with_path, col_u,
                       path_rate_used, floor, table_f2(table, 59), table_f1(table, 60), table_f1(table, 61))


@kernel("boolean(float64[::1], float64[::1], float64[::1], float64[::1], boolean, boolean, float64, int64[:, ::1])")
def table_problem(target: np.ndarray, posture_goal: np.ndarray, dq_prev: np.ndarray, bound: np.ndarray, top: bool,
                  with_path: bool, rate: float, table: np.ndarray) -> bool:
    """``DifferentialIK.qp_problem`` in one call: the objective toward ``target`` (:func:`site_objective`,
    no reference) and :func:`table_rows`; False if the Hessian is not positive definite."""
    consts, ints = table_f1(table, 0), table_i1(table, 1)
    site_xmat, site_xpos = table_f2(table, 6), table_f2(table, 7)
    if not site_objective(table_f2(table, 4), table_f2(table, 5), table_i2(table, 10), table_i1(table, 11),
                          ints[4], site_xmat, site_xpos, ints[3], table_f2(table, 14), target, target, False,
                          table_f1(table, 15), consts[6], table_f1(table, 16), consts[7], posture_goal,
                          table_f1(table, 3), consts[4], consts[5], table_f2(table, 17), table_f1(table, 18),
                          table_f1(table, 19), table_f2(table, 20), table_f2(table, 21)):
        return False
    table_rows(dq_prev, bound, top, with_path, rate, table)
    return True


@kernel("Tuple((int64, int64, float64, float64, float64))(int64, UniTuple(float64, 3), UniTuple(float64, 3), "
        "float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], int64, int64[:, ::1], "
        "float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1])")
def cartesian_step(kind: int, linear: tuple[float, float, float], angular: tuple[float, float, float],
                   q: np.ndarray, dq_prev: np.ndarray, ref: np.ndarray, last_xi: np.ndarray, posture_goal: np.ndarray,
                   bound: np.ndarray, state: int, table: np.ndarray, new_ref: np.ndarray, target: np.ndarray,
                   xi: np.ndarray, dq: np.ndarray, dq_next: np.ndarray, q_next: np.ndarray,
                   velocity: np.ndarray) -> tuple[int, int, float, float, float]:
    """``DifferentialIK.step_owned`` for a twist (``kind`` ``TWIST_BASE`` / ``TWIST_TOOL``: ``linear``
    mm/s, ``angular`` deg/s) or a stop braking along the last Cartesian line (``CARTESIAN_STOP``), when
    the step stays on the line, in one call: the same operations in the same order as the Python
    step (MuJoCo's through their C functions; the rows :func:`table_rows`), so the same bits.

    Per call: the joints ``q``, last cycle's increment ``dq_prev``, the reference pose ``ref`` and the
    last line ``last_xi`` (when ``state`` says there are), the posture goal, the braking rows' bounds
    ``bound`` (``BrakingLimit.row_data``), ``state``'s bits (``STATE_*``); the rest through ``table``
    (``CARTESIAN_ARRAYS``). ``consts``: dt, reach, singularity_slow, reference_tolerance_m, damping,
    the correction gain, the frame task's gain, the posture gain, binding_tol, ConfigurationLimit's
    gain, the braking rows' lag, the path's floor, the shoulder margin, its braking deceleration, the
    configuration guard's lag. ``ints``: the model's and data's addresses, the flange site, the TCP
    site and its body, the acceleration rows' first and end row, the model's equality count,
    collision rows (1/0), the flag bits VELOCITY_LIMIT, ACCEL_LIMIT, NEAR_SINGULARITY, NO_COMMAND.
    The others as :func:`site_objective`, :func:`limit_rows`, :func:`collision_fill` and
    :func:`step_result` take them.

    Returns ``(status, flags, condition, scale, path rate)``; ``status`` < 0 (``STEP_*``): the step is
    the Python code's (the IK's kept state untouched: only scratch, the MjData and the rows were
    written). Else the ``LAST_XI_*`` code plus ``STEP_FINITE``; ``new_ref``, ``target``: the new
    reference and the frame target; ``xi``: this step's twist (m/s, rad/s); ``dq``: the increment,
    ``dq_next`` its copy (next cycle's ``dq_prev``), ``q_next`` = ``q + dq``, ``velocity`` = ``dq / dt``
    (each its own array: the IK's result and kept state hold them); ``path_u`` and the path rate: the
    path's braking direction (``PathBraking``'s)."""
    consts = table_f1(table, 0)
    ints = table_i1(table, 1)
    track_weights = table_f1(table, 2)
    qpos = table_f1(table, 3)
    cdof = table_f2(table, 4)
    subtree_com = table_f2(table, 5)
    site_xmat = table_f2(table, 6)
    site_xpos = table_f2(table, 7)
    tree = table_i2(table, 10)
    dof_parentid = table_i1(table, 11)
    jac_flange = table_f2(table, 12)
    cond_work = table_f2(table, 13)
    jac_world = table_f2(table, 14)
    frame_cost = table_f1(table, 15)
    posture_cost = table_f1(table, 16)
    p = table_f2(table, 17)
    c = table_f1(table, 18)
    c_frame = table_f1(table, 19)
    wjac = table_f2(table, 20)
    d = table_f2(table, 21)
    rate_c = table_f2(table, 22)
    path_brake = table_f1(table, 23)
    path_u = table_f1(table, 24)
    velocity_bound = table_b1(table, 30)
    g = table_f2(table, 38)
    h = table_f1(table, 39)
    h_path = table_f1(table, 40)
    row_flags = table_i1(table, 41)
    has_ref, has_last_xi = (state & STATE_HAS_REF) != 0, (state & STATE_HAS_LAST_XI) != 0
    mode_changed, twist_mode = (state & STATE_MODE_CHANGED) != 0, (state & STATE_TWIST_MODE) != 0
    top = (state & STATE_TOP) != 0
    n = q.shape[0]
    dt, reach, sing_slow, ref_tol = consts[0], consts[1], consts[2], consts[3]
    for i in range(n):  # the configuration at q (model order is qpos order)
        qpos[i] = q[i]
    m, dd = address(ints[0]), address(ints[1])
    mj_kinematics(m, dd)
    mj_comPos(m, dd)
    if ints[7] > 0:
        mj_makeConstraint(m, dd)
    mj_jacSite(m, dd, doubles(jac_flange[:3]), doubles(jac_flange[3:]), np.int32(ints[2]))
    kappa = condition_number(jac_flange, reach, cond_work)
    flags = ints[11] if kappa > sing_slow else 0
    moving = any_nonzero(dq_prev)
    if kind == CARTESIAN_STOP and not (has_last_xi and moving):
        return STEP_NOT_CARTESIAN, 0, kappa, 0.0, 0.0
    sid = ints[3]
    tcp = np.empty(7)
    mju_mat2Quat(doubles(tcp[:4]), doubles(site_xmat[sid]))
    for i in range(3):
        tcp[4 + i] = site_xpos[sid, i]
    if kind == CARTESIAN_STOP:
        for i in range(6):
            xi[i] = 0.0
        xi_moves = False
        flags |= ints[12]
    else:
        xi_moves = twist_si(linear, angular, xi)
        if kind == TWIST_TOOL:
            part = np.empty(3)
            for at in (0, 3):
                for i in range(3):
                    part[i] = xi[at + i]
                mju_rotVecQuat(doubles(xi[at: at + 3]), doubles(part), doubles(tcp[:4]))
            xi_moves = any_nonzero(xi)
    if mode_changed or not has_ref or not poses_near(ref, tcp, ref_tol, reach):
        new_ref[:] = tcp
    elif not (twist_mode and has_last_xi and along_track(new_ref, ref, tcp, last_xi, track_weights)):
        new_ref[:] = ref
    if xi_moves:
        if kappa > sing_slow:
            return STEP_SINGULARITY, 0, kappa, 0.0, 0.0
        line, s_goal, asks_motion, last_code = xi, 1.0, True, LAST_XI_NEW
    elif has_last_xi and moving:
        line, s_goal, asks_motion, last_code = last_xi, 0.0, any_nonzero(last_xi), LAST_XI_KEPT
    else:
        line, s_goal, asks_motion, last_code = xi, 0.0, False, LAST_XI_CLEARED
    advance(target, new_ref, line, 1.0, dt)
    toward = new_ref if asks_motion else target
    if not site_objective(cdof, subtree_com, tree, dof_parentid, ints[4], site_xmat, site_xpos, sid, jac_world,
                          target, toward, asks_motion, frame_cost, consts[6],
                          posture_cost, consts[7], posture_goal, qpos, consts[4], consts[5], p, c, c_frame, wjac,
                          d):
        return STEP_NOT_DEFINITE, 0, kappa, 0.0, 0.0
    direction = np.empty(n)
    for i in range(n):
        direction[i] = d[0, i] - d[1, i] if asks_motion else dq_prev[i]
    rate = path_rate(rate_c, path_brake, direction, path_u)
    with_path = not math.isinf(rate)
    table_rows(dq_prev, bound, top, with_path, rate, table)
    correction = d[1]
    lo, hi = scale_interval(direction, g, h_path, correction, 1.0)
    s = math.nan
    if not math.isnan(lo):
        s = _nearest(s_goal, lo, hi)
    if not math.isfinite(s) and any_nonzero(correction):
        correction = np.zeros(n)  # the correction does not fit this cycle: the line alone
        lo, hi = scale_interval(direction, g, h_path, direction, 0.0)
        if not math.isnan(lo):
            s = _nearest(s_goal, lo, hi)
    if not math.isfinite(s):
        return STEP_OFF_LINE, 0, kappa, 0.0, rate
    line_point(s, direction, correction, dq)
    if asks_motion:  # the reference follows what was achieved
        before = new_ref.copy()
        advance(new_ref, before, line, s, dt)
    if s_goal == 0.0 and s == 0.0:
        last_code = LAST_XI_CLEARED  # at rest
    scale, bits, finite = step_result_into(dq, d[0], s_goal, 1.0, q, dt, g, h, row_flags, ints[5], ints[6],
                                           velocity_bound, consts[8], ints[9], ints[10], dq_next, q_next, velocity)
    return last_code + (STEP_FINITE if finite else 0), flags | bits, kappa, scale, rate
