"""Compiled kernels of the shaper's per-cycle work (numba): the guard's check of the float32 candidate
and the straight-line planning limits of :class:`~servo_app.motion.shaper.JointShaper`.

The guard's check ran on Python floats and the line limits as a dozen numpy calls (a jog sets a new
target every cycle): about 40 us of a joint-jog cycle here, one kernel call each now. The arithmetic
follows the readings they replace operation for operation (the float32 rounding, the finite
differences exactly as the controller computes them, the braking peak), so the guard passes and
commits the same positions; tests/test_shaper_kernels.py compares both with those readings.
"""

from __future__ import annotations

import math

import numpy as np

from servo_app.jit import kernel

# Rows of an envelope's check table (Envelope.table): per axis.
CHECK_VEL, CHECK_ACC, CHECK_JERK, CHECK_BRAKE_VEL, CHECK_BRAKE_STEP = 0, 1, 2, 3, 4


@kernel("boolean(float64[::1], float64[::1], float64[::1], float64[::1], float64[:, ::1], float64, float64[::1])")
def emit_if_passes(candidate: np.ndarray, s: np.ndarray, v: np.ndarray, a: np.ndarray, table: np.ndarray,
                   dt: float, r: np.ndarray) -> bool:
    """Round ``candidate`` to float32 into ``r`` (which may be ``candidate`` itself: each entry is read
    before it is written); if emitting it keeps every axis' finite differences
    within ``table`` with a braking-feasible future, commit it (``s``, ``v``, ``a`` updated in place:
    the emitted position, velocity and acceleration) and return True; else change nothing else."""
    n = s.shape[0]
    for i in range(n):
        r[i] = np.float64(np.float32(candidate[i]))
    for i in range(n):
        vi = (r[i] - s[i]) / dt
        ai = (vi - v[i]) / dt
        ji = (ai - a[i]) / dt
        if abs(vi) > table[CHECK_VEL, i] or abs(ai) > table[CHECK_ACC, i] or abs(ji) > table[CHECK_JERK, i]:
            return False
        c, vb = table[CHECK_BRAKE_STEP, i], table[CHECK_BRAKE_VEL, i]
        # velocity still gained while |a| ramps down by c per cycle (see shaper._brake_peaks)
        k = math.floor(abs(ai) / c)
        peak = vi + dt * (k * ai - math.copysign(c * k * (k + 1.0) / 2.0, ai))
        if abs(vi) > vb or abs(peak) > vb:
            return False
    for i in range(n):
        vi = (r[i] - s[i]) / dt
        a[i] = (vi - v[i]) / dt
        v[i] = vi
        s[i] = r[i]
    return True


@kernel("boolean(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], "
        "float64[::1], float64, float64[:, ::1])")
def line_limits(p: np.ndarray, v: np.ndarray, a: np.ndarray, q: np.ndarray, plan_vel: np.ndarray,
                plan_acc: np.ndarray, plan_jerk: np.ndarray, vel_scale: float, out: np.ndarray) -> bool:
    """The planning limits (rows: velocity, acceleration, jerk) for a move from state (p, v, a) to ``q``
    into ``out``; True if the move can be a straight line (from rest, or with velocity and
    acceleration along the displacement): the limits are then scaled to each axis' share of the
    displacement, else they are the plain ones (velocity times ``vel_scale``)."""
    n = p.shape[0]
    for i in range(n):
        out[0, i] = plan_vel[i] * vel_scale
        out[1, i] = plan_acc[i]
        out[2, i] = plan_jerk[i]
    size = 0.0
    for i in range(n):
        size = max(size, abs(q[i] - p[i]))
    if size < 1e-6:  # deg: nothing to keep straight, and no limits scaled by a vanishing share
        return False
    norm_u = 0.0
    for i in range(n):
        d = q[i] - p[i]
        if abs(d) >= 1e-9 * size:  # numerically not moving otherwise: left out of the direction
            norm_u += d * d
    norm_u = math.sqrt(norm_u)
    for x in (v, a):
        along, norm_x = 0.0, 0.0
        for i in range(n):
            d = q[i] - p[i]
            u = d / norm_u if abs(d) >= 1e-9 * size else 0.0
            along += x[i] * u
            norm_x += x[i] * x[i]
        norm_off = 0.0
        for i in range(n):
            d = q[i] - p[i]
            u = d / norm_u if abs(d) >= 1e-9 * size else 0.0
            off = x[i] - along * u  # the part of the state across the line
            norm_off += off * off
        if math.sqrt(norm_off) > 1e-9 * (math.sqrt(norm_x) + 1e-12):
            return False
    # An axis numerically not moving (under 1e-9 of the line) gets the limits of 1e-9 of it, not its own:
    # with its own, ruckig's synchronization sent J3 4.6e-13 deg from its target 0.0019 deg off in one
    # cycle, at 0.71 deg/s (a jog of J2 120, J4 -115, J5 195 deg/s with J3 asked 1e-12).
    floor = 1e-9 * size
    for k in range(3):
        rate = np.inf
        for i in range(n):
            rate = min(rate, out[k, i] / max(abs(q[i] - p[i]), floor))
        for i in range(n):
            out[k, i] = max(abs(q[i] - p[i]), floor) * rate
    return True


@kernel("boolean(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], "
        "float64[:, ::1], float64[::1])")
def velocity_share_limits(v: np.ndarray, a: np.ndarray, target: np.ndarray, plan_vel: np.ndarray,
                          plan_acc: np.ndarray, plan_jerk: np.ndarray, out: np.ndarray, aim: np.ndarray) -> bool:
    """The planning limits (rows: velocity, acceleration, jerk) for a change of velocity from (v, a) to
    ``target`` into ``out``, and the velocity to give ruckig this cycle into ``aim``. True when the axes
    run one profile scaled (:func:`line_limits` for a velocity), the velocity on a straight line:

    - the acceleration along the change (none, within ~8 deg of it, or a remnant that changes the
      velocity by under a thousandth of the change): ``aim`` is ``target``, acceleration and jerk scaled
      to each axis' share of the change, each at least what ends its present acceleration as soon as
      the profile does and without passing its target;
    - the acceleration against the change (the turn from speeding up to braking, or a target reached
      while still accelerating): every axis ends its acceleration in the same time, the slowest one's
      at its jerk limit (each jerk in proportion to its acceleration), ``aim`` the velocity that
      reaches: the velocity goes on along the acceleration, then (a later cycle, from no acceleration)
      straight to the target.

    False (``aim`` is ``target``, the plain limits): an acceleration off the change but not against it
    (ending it along its own line there ran twists off by up to +14 %: the joints whose motions cancel
    went on the old way), a turn whose velocity would leave the velocity limits, nothing to change.

    Why: ruckig keeps the axes in phase only for a change exactly along the acceleration; the IK's
    target moves a little every cycle of a ramp, and time synchronisation then stretched an axis with
    little to change over the slowest one's time, its own way (J3 stalled at 0.3 of its target while
    J2 reached it): the TCP, the sum of joint motions that partly cancel, ran 2-5 % over its speed. At
    the turn from speeding up to braking each axis ended its acceleration at its own jerk limit (J3
    ~7 ms before J5 at 4 ms): a pose target's turn ran +2.1 %."""
    n = v.shape[0]
    size, dot, na, nd, k = 0.0, 0.0, 0.0, 0.0, np.inf
    for i in range(n):
        out[0, i] = plan_vel[i]
        out[1, i] = plan_acc[i]
        out[2, i] = plan_jerk[i]
        aim[i] = target[i]
        d = target[i] - v[i]
        size = max(size, abs(d))
        dot += a[i] * d
        na += a[i] * a[i]
        nd += d * d
        if a[i] != 0.0:
            k = min(k, plan_jerk[i] / abs(a[i]))  # every axis ends its acceleration in 1/k (the turn)
    turn = 0.0  # the most an axis' velocity still changes in the turn
    for i in range(n):
        turn = max(turn, abs(a[i]) / (2.0 * k))
    if turn <= 0.0 and size <= 0.0:
        return False
    # (an acceleration whose turn is a thousandth of the change, a remnant: the change goes first)
    if size > 0.0 and (dot >= 0.99 * math.sqrt(na * nd) or turn <= 1e-3 * size):
        floor = 1e-6 * size  # an axis with (almost) nothing to change: a share of 1e-6, not a vanishing one
        ka, kj = np.inf, np.inf
        for i in range(n):
            share = max(abs(target[i] - v[i]), floor)
            ka = min(ka, plan_acc[i] / share)
            kj = min(kj, plan_jerk[i] / share)
        for i in range(n):
            d = target[i] - v[i]
            share = max(abs(d), floor)
            acc = max(ka * share, abs(a[i]) * 1.0001)  # (its present acceleration within its limit)
            jerk = max(kj * share, abs(a[i]) * kj / ka)  # its acceleration ended within the profile's time
            if a[i] * d > 0.0:
                jerk = max(jerk, 1.01 * a[i] * a[i] / (2.0 * share))  # ... before it passes the target
            out[1, i] = min(plan_acc[i], acc)
            out[2, i] = min(plan_jerk[i], jerk)
        return True
    if dot > 0.0:  # an acceleration off the change but not against it: ruckig's own limits (see above)
        return False
    # The turn: every axis ends its acceleration in 1/k, the slowest at its jerk limit.
    floor = 2.0 * k * turn * 1e-6  # (of the largest acceleration: an axis with none keeps its velocity)
    for i in range(n):
        # (a hair further than the slowest axis' jerk reaches, a hair more jerk for the others: ruckig's
        # time synchronisation failed on two axes that end together to the last digit)
        aim[i] = v[i] + a[i] * (1.0 + 1e-9) / (2.0 * k)
        out[1, i] = min(plan_acc[i], max(abs(a[i]), floor) * 1.0001)
        out[2, i] = min(plan_jerk[i], k * max(abs(a[i]), floor) * (1.0 + 1e-6))
        if abs(aim[i]) > plan_vel[i]:
            for j in range(n):
                out[1, j] = plan_acc[j]
                out[2, j] = plan_jerk[j]
                aim[j] = target[j]
            return False
    return True


@kernel("float64(float64[::1], float64[::1], float64[::1])")
def velocity_within(v: np.ndarray, vmax: np.ndarray, out: np.ndarray) -> float:
    """``v`` scaled by one factor so that no axis exceeds ``vmax`` (keeps the direction), into ``out``.
    Returns max |v| / vmax (the factor when above 1), or -1.0 if ``v`` is not finite."""
    n = v.shape[0]
    over = -np.inf
    for i in range(n):
        if not math.isfinite(v[i]):
            return -1.0
        over = max(over, abs(v[i]) / vmax[i])
    for i in range(n):
        out[i] = v[i] / over if over > 1.0 else v[i]
    return over

