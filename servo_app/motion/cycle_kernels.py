"""Compiled kernels of the servo cycle's guards (numba): the stop-point search, the joint-line reach
search, the jog target and the flange-speed prediction of :class:`~servo_app.motion.servo.ServoCycle`.

Each was a loop of numpy calls on 6-vectors (``linspace``, ``outer``, conversions, the region test on
16-24 points, several rounds): ~150 us of a joint-jog cycle here, where one kernel call costs about
0.5 us. Each kernel repeats the numpy reading's arithmetic in the same order (``np.linspace``'s
values included), so the searches land on the same samples; tests/test_cycle_kernels.py compares them
with that reading. Joints are FANUC degrees; regions are packed (:func:`servo_app.robots.kernels.pack_region`).
"""

from __future__ import annotations

import numpy as np

from servo_app.jit import kernel
from servo_app.robots.kernels import (
    DEG_TO_RAD,
    RAD_TO_DEG,
    fanuc_deg_in_region,
    fanuc_deg_to_model_rad_into,
    flange_distance_mm,
)

STOP_SEARCH_ROUNDS, STOP_SEARCH_SAMPLES = 2, 16  # two rounds of 16: ~0.4 % resolution
REACH_SEARCH_ROUNDS = 3


@kernel("float64(float64, float64, int64, int64)")
def linspace_at(lo: float, hi: float, num: int, i: int) -> float:
    """``np.linspace(lo, hi, num)[i]``, computed as numpy does (the last one is ``hi`` itself)."""
    if i == num - 1:
        return hi
    div = num - 1
    delta = hi - lo
    step = delta / div
    if step == 0.0:
        return i / div * delta + lo
    return i * step + lo


@kernel("float64(float64[::1], float64[::1], float64, float64[::1], float64, float64[::1], float64[::1])")
def stoppable_scale(q: np.ndarray, v: np.ndarray, lag: float, brake: np.ndarray, j23_factor: float,
                    region: np.ndarray, point: np.ndarray) -> float:
    """Largest share s of ``v`` (searched on a grid) whose stopping point ``q + w lag + w |w| / (2 brake)``
    (w = s v) lies in the region; 1.0 if the whole of ``v`` does. ``point``: scratch, len(q)."""
    n = q.shape[0]
    for j in range(n):
        w = v[j]
        point[j] = q[j] + w * lag + w * abs(w) / (2.0 * brake[j])
    if fanuc_deg_in_region(point, j23_factor, region):
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(STOP_SEARCH_ROUNDS):
        first_bad = -1
        for i in range(1, STOP_SEARCH_SAMPLES + 1):
            s = linspace_at(lo, hi, STOP_SEARCH_SAMPLES + 1, i)
            for j in range(n):
                w = s * v[j]
                point[j] = q[j] + w * lag + w * abs(w) / (2.0 * brake[j])
            if not fanuc_deg_in_region(point, j23_factor, region):
                first_bad = i
                break
        if first_bad < 0:
            lo = hi
            break
        new_hi = linspace_at(lo, hi, STOP_SEARCH_SAMPLES + 1, first_bad)
        if first_bad > 1:
            lo = linspace_at(lo, hi, STOP_SEARCH_SAMPLES + 1, first_bad - 1)
        hi = new_hi
    return lo


@kernel("void(float64[::1], float64[::1], float64, float64, float64[::1], float64[::1])")
def ik_start(q: np.ndarray, v: np.ndarray, j23_factor: float, dt: float, q_model: np.ndarray,
             dq_model: np.ndarray) -> None:
    """The IK's start from the shaper's state (FANUC deg, deg/s): the position in the model convention
    (rad) and the step the shaper delivers this cycle (model rad). Joint rates convert as positions do
    (``fanuc_rate_matrix``'s inverse), so this is ``c_inv @ radians(v) * dt`` to the bit."""
    fanuc_deg_to_model_rad_into(q, j23_factor, q_model)
    fanuc_deg_to_model_rad_into(v, j23_factor, dq_model)
    for j in range(dq_model.shape[0]):
        dq_model[j] = dq_model[j] * dt


@kernel("float64(float64[::1], float64[::1], float64[::1], float64, float64[::1], float64, float64[::1], "
        "float64, float64[::1], float64[::1])")
def guard_ik_velocity(q: np.ndarray, velocity_model: np.ndarray, v_now: np.ndarray, lag: float, brake: np.ndarray,
                      j23_factor: float, region: np.ndarray, creep: float, point: np.ndarray, v: np.ndarray) -> float:
    """The IK's joint velocity (model rad/s) in FANUC deg/s into ``v`` (as ``velocity_fanuc_deg_s``),
    cut to the share the arm can still stop from (:func:`stoppable_scale`), and to zero when it and
    the current velocity ``v_now`` are both a creep (every axis below ``creep``). Returns the share."""
    n = q.shape[0]
    for j in range(n):
        v[j] = velocity_model[j]
    if n >= 3:
        v[2] = v[2] - j23_factor * v[1]
    for j in range(n):
        v[j] = v[j] * RAD_TO_DEG
    scale = stoppable_scale(q, v, lag, brake, j23_factor, region, point)
    creeping = True
    for j in range(n):
        v[j] = v[j] * scale
        creeping = creeping and abs(v[j]) < creep and abs(v_now[j]) < creep
    if creeping:
        for j in range(n):
            v[j] = 0.0
    return scale


@kernel("float64(float64[::1], float64[::1], int64, float64, float64[::1], float64[::1])")
def config_keeping_reach(q0: np.ndarray, q1: np.ndarray, samples: int, j23_factor: float, region: np.ndarray,
                         point: np.ndarray) -> float:
    """Share of the joint line q0 -> q1 that stays in the region: ``samples`` points a round, each
    round searching between the last good and the first bad one. ``point``: scratch, len(q0)."""
    n = q0.shape[0]
    lo, hi = 0.0, 1.0
    for _ in range(REACH_SEARCH_ROUNDS):
        first_bad = -1
        for i in range(1, samples + 1):
            f = linspace_at(lo, hi, samples + 1, i)
            for j in range(n):
                point[j] = q0[j] + f * (q1[j] - q0[j])
            if not fanuc_deg_in_region(point, j23_factor, region):
                first_bad = i
                break
        if first_bad < 0:
            return hi if hi == 1.0 else lo
        new_hi = linspace_at(lo, hi, samples + 1, first_bad)
        if first_bad > 1:
            lo = linspace_at(lo, hi, samples + 1, first_bad - 1)
        hi = new_hi
    return lo


@kernel("void(float64[::1], float64, float64[::1], float64[::1], float64[::1])")
def clip_to_range(q_fanuc_deg: np.ndarray, j23_factor: float, lo_model_deg: np.ndarray, hi_model_deg: np.ndarray,
                  out: np.ndarray) -> None:
    """``q`` clipped to the joint ranges, which are given in the model convention (deg), into ``out``
    (may be ``q``): the round trip of ``fanuc_deg_to_model_rad`` and back, as numpy computes it."""
    n = q_fanuc_deg.shape[0]
    q1_model_rad = q_fanuc_deg[1] * DEG_TO_RAD
    for j in range(n):
        r = q_fanuc_deg[j] * DEG_TO_RAD
        if j == 2:
            r = r + j23_factor * q1_model_rad
        m = r * RAD_TO_DEG
        if m < lo_model_deg[j]:
            m = lo_model_deg[j]
        elif m > hi_model_deg[j]:
            m = hi_model_deg[j]
        out[j] = m * DEG_TO_RAD
    clipped_q1 = out[1]
    for j in range(n):
        r = out[j]
        if j == 2:
            r = r - j23_factor * clipped_q1
        out[j] = r * RAD_TO_DEG


@kernel("float64(float64[::1], float64[::1], float64, float64[::1], float64, float64, float64[::1], float64[::1], "
        "float64[::1], float64[::1], float64[::1])")
def jog_target(q: np.ndarray, v: np.ndarray, speed_scale: float, vmax: np.ndarray, horizon: float, j23_factor: float,
               lo_model_deg: np.ndarray, hi_model_deg: np.ndarray, region: np.ndarray, point: np.ndarray,
               out: np.ndarray) -> float:
    """A joint jog at ``v * speed_scale``: returns its speed as a share of ``vmax`` (the fastest axis'),
    and if that is above 1e-9 writes into ``out`` the target ``horizon`` seconds ahead, clipped to the
    ranges and cut where the line would leave the region.

    Clipping turns the line: the share is then the one at which no jogged joint runs faster than asked
    along it. The fastest axis' share of the unclipped line ran the others past their speeds once one
    neared its limit (J5 -100 deg/s with J6 30: J6 at 184 deg/s, and the flange 977 mm/s under a 947
    cap, past the share ServoCycle._cap_share took at the jog's speed)."""
    n = q.shape[0]
    scale = -np.inf
    for j in range(n):
        scale = max(scale, abs(v[j] * speed_scale) / vmax[j])
    if scale <= 1e-9:
        return scale
    for j in range(n):
        out[j] = q[j] + v[j] * speed_scale * horizon
    clip_to_range(out, j23_factor, lo_model_deg, hi_model_deg, out)
    # Along the clipped line (rates: share of the line per second): the fastest each jogged joint allows
    # at its asked speed, over the fastest the shaper's limits allow.
    asked, allowed = np.inf, np.inf
    for j in range(n):
        d = abs(out[j] - q[j])
        if d > 0.0:
            allowed = min(allowed, vmax[j] / d)
            if v[j] != 0.0:
                asked = min(asked, abs(v[j] * speed_scale) / d)
    if asked < np.inf and allowed < np.inf:
        scale = min(scale, asked / allowed)
    # The target no further than the jog runs in ``horizon`` (share of the line per second: min(scale, 1)
    # x allowed): a slowed line's clipped end was not. J2 -33 deg/s, J3 1e-5 ran J2 into J3's model range,
    # the line needed 4.9 deg of J3: 27 deg at 0.0035 deg/s, over ruckig's 7.6e3 s plan (its error -101).
    ahead = min(scale, 1.0) * allowed * horizon
    if ahead < 1.0:
        for j in range(n):
            out[j] = q[j] + (out[j] - q[j]) * ahead
    reach = config_keeping_reach(q, out, 24, j23_factor, region, point)
    for j in range(n):
        out[j] = q[j] + (out[j] - q[j]) * reach
    return scale


@kernel("float64(float64[::1], float64[::1], float64[::1], float64, float64, float64[::1], float64[::1])")
def predicted_flange_speed(q: np.ndarray, v: np.ndarray, a: np.ndarray, dt: float, j23_factor: float,
                           dims: np.ndarray, ahead: np.ndarray) -> float:
    """Flange speed (mm/s) over the next four cycles from position ``q``, velocity ``v`` and acceleration
    ``a`` (FANUC deg, /s, /s^2). ``ahead``: scratch, len(q)."""
    for j in range(q.shape[0]):
        ahead[j] = q[j] + (v[j] + a[j] * 4 * dt) * 4 * dt
    return flange_distance_mm(q, ahead, j23_factor, dims) / (4 * dt)
