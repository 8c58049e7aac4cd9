"""The shaper's compiled kernels (servo_app.motion.shaper_kernels) against the readings they replace:
the guard's check on Python floats and the straight-line limits in numpy; the velocity share limits
against ruckig itself."""

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from servo_app.motion.shaper import Envelope, ShaperLimits
from servo_app.motion.shaper_kernels import emit_if_passes, line_limits, velocity_share_limits, velocity_within

DT = 0.008
LIMITS = ShaperLimits(np.array([370.0, 310.0, 410.0, 550.0, 545.0, 1000.0]),
                      np.array([1500.0, 1300.0, 1700.0, 2300.0, 2300.0, 4200.0]),
                      np.array([9000.0, 8000.0, 10000.0, 14000.0, 14000.0, 25000.0]))
ENV = Envelope.build(*LIMITS.scaled(), LIMITS.pos_abs_max, DT)  # type: ignore[arg-type]

six = st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6).map(np.array)


def passes_oracle(r, s, v1, a1, env):
    """DiscreteGuard._fast_ok as it ran on Python floats."""
    rows = zip(*(x.tolist() for x in (env.vel, env.acc, env.jerk, env.brake_vel, env.brake_jerk * DT)), strict=True)
    for x, s0, v0, a0, (vmax, amax, jmax, vb, c) in zip(r, s, v1, a1, rows, strict=True):
        v = (x - s0) / DT
        a = (v - v0) / DT
        j = (a - a0) / DT
        if abs(v) > vmax or abs(a) > amax or abs(j) > jmax:
            return False
        n = (abs(a) / c) // 1.0
        peak = v + DT * (n * a - math.copysign(c * n * (n + 1.0) / 2.0, a))
        if abs(v) > vb or abs(peak) > vb:
            return False
    return True


@st.composite
def guard_states(draw):
    """A reachable emitted state (s, v, a) and a candidate around its continuation, some far off."""
    s = np.asarray((draw(six) * 300.0).astype(np.float32), dtype=np.float64)
    v = draw(six) * ENV.vel
    a = draw(six) * ENV.acc
    spread = draw(st.sampled_from([1e-7, 1e-5, 1e-3, 1e-1]))
    candidate = s + DT * (v + DT * a) + draw(six) * spread * ENV.jerk * DT**3 / 1e-3
    return s, v, a, candidate


@settings(max_examples=500, deadline=None)
@given(guard_states())
def test_guard_check_matches_python_floats(state):
    s, v, a, candidate = state
    r_list = np.asarray(candidate, dtype=np.float32).tolist()
    expected = passes_oracle(r_list, s.tolist(), v.tolist(), a.tolist(), ENV)
    s_k, v_k, a_k, r = s.copy(), v.copy(), a.copy(), np.empty(6)
    assert emit_if_passes(candidate, s_k, v_k, a_k, ENV.table, DT, r) == expected
    assert r.tolist() == r_list
    if expected:  # committed: the controller's finite differences, as DiscreteGuard.commit took them
        v_new = [(x - s0) / DT for x, s0 in zip(r_list, s.tolist(), strict=True)]
        a_new = [(vn - v0) / DT for vn, v0 in zip(v_new, v.tolist(), strict=True)]
        assert (s_k.tolist(), v_k.tolist(), a_k.tolist()) == (r_list, v_new, a_new)
    else:
        assert (s_k.tolist(), v_k.tolist(), a_k.tolist()) == (s.tolist(), v.tolist(), a.tolist())


@settings(max_examples=300, deadline=None)
@given(guard_states())
def test_guard_check_rounds_the_candidate_in_place_alike(state):
    """DiscreteGuard.filter hands the kernel one array as candidate and output: the same answer, the
    same rounded position and the same committed state as with two arrays."""
    s, v, a, candidate = state
    apart = [x.copy() for x in (s, v, a)] + [np.empty(6)]
    inplace = [x.copy() for x in (s, v, a)] + [candidate.copy()]
    ok_apart = emit_if_passes(candidate, *apart[:3], ENV.table, DT, apart[3])
    ok_inplace = emit_if_passes(inplace[3], *inplace[:3], ENV.table, DT, inplace[3])
    assert ok_apart == ok_inplace
    assert [x.tobytes() for x in apart] == [x.tobytes() for x in inplace]


def test_guard_check_has_both_answers():
    s, v, a, r = np.zeros(6), np.zeros(6), np.zeros(6), np.empty(6)
    assert emit_if_passes(np.full(6, 1e-6), s, v, a, ENV.table, DT, r)
    assert not emit_if_passes(np.full(6, 1.0), s, v, a, ENV.table, DT, r)  # 125 deg/s from rest in one cycle


def line_limits_oracle(p, v, a, q, env, vel_scale):
    """JointShaper._line_to and _apply_plan_limits as numpy ran them."""
    limits = [env.plan_vel * vel_scale, env.plan_acc, env.plan_jerk]
    d = q - p
    size = np.max(np.abs(d))
    if size < 1e-6:
        return False, limits
    line = np.abs(d)
    line[line < 1e-9 * size] = 0.0
    u = np.where(line > 0.0, d, 0.0)
    u /= np.linalg.norm(u)
    for x in (v, a):
        off = x - (x @ u) * u
        if np.linalg.norm(off) > 1e-9 * (np.linalg.norm(x) + 1e-12):
            return False, limits
    share = np.maximum(np.abs(d), 1e-9 * size)  # (an axis not moving: the limits of 1e-9 of the line)
    for k, lim in enumerate(limits):
        rate = np.min(lim / share)
        limits[k] = share * rate
    return True, limits


@st.composite
def moves(draw):
    """A state and a target: at rest, moving along the line to the target, or across it."""
    p = draw(six) * 170.0
    d = draw(six) * draw(st.sampled_from([1e-7, 1e-3, 1.0, 100.0]))
    if draw(st.booleans()):
        d[draw(st.integers(0, 5))] = 0.0  # an axis that does not move
    kind = draw(st.sampled_from(["rest", "along", "across"]))
    if kind == "rest":
        v, a = np.zeros(6), np.zeros(6)
    elif kind == "along":
        v, a = d * draw(st.floats(0.1, 10.0)), d * draw(st.floats(-10.0, 10.0))
    else:
        v, a = draw(six) * 100.0, draw(six) * 1000.0
    return p, v, a, p + d, draw(st.floats(0.01, 1.0))


@settings(max_examples=500, deadline=None)
@given(moves())
def test_line_limits_match_numpy(move):
    p, v, a, q, vel_scale = move
    straight, expected = line_limits_oracle(p, v, a, q, ENV, vel_scale)
    out = np.empty((3, 6))
    assert line_limits(p, v, a, q, ENV.plan_vel, ENV.plan_acc, ENV.plan_jerk, vel_scale, out) == straight
    # The rate is a minimum of quotients and the limits are products: bit for bit. (The decision above
    # sums dot products in the kernel's order, numpy's BLAS may differ in the last bit: thresholds only.)
    assert out.tolist() == [x.tolist() for x in expected]


def test_line_limits_take_each_branch():
    out = np.empty((3, 6))
    p, q = np.zeros(6), np.array([10.0, 5.0, 0.0, 0.0, 0.0, 0.0])
    args = (ENV.plan_vel, ENV.plan_acc, ENV.plan_jerk, 1.0, out)
    assert line_limits(p, np.zeros(6), np.zeros(6), q, *args)
    assert out[0, 1] / out[0, 0] == 0.5 and math.isclose(out[0, 2], 1e-9 * out[0, 0], rel_tol=1e-12)
    assert not line_limits(p, np.array([0.0, 0.0, 1.0, 0, 0, 0]), np.zeros(6), q, *args)  # moving across
    assert not line_limits(p, np.zeros(6), np.zeros(6), p + 1e-8, *args)  # nothing to keep straight


@settings(max_examples=300, deadline=None)
@given(six, st.sampled_from([1.0, 100.0, 1000.0, 1e5]))
def test_velocity_cap_matches_numpy(v, size):
    """JointShaper.set_velocity's cap: all axes scaled by one factor above the limit."""
    v = v * size
    over = np.max(np.abs(v) / ENV.plan_vel)
    out = np.empty(6)
    assert velocity_within(v, ENV.plan_vel, out) == over
    assert out.tolist() == (v / over if over > 1.0 else v).tolist()


def test_velocity_cap_refuses_what_is_not_finite():
    out = np.empty(6)
    assert velocity_within(np.array([0.0, np.nan, 0, 0, 0, 0]), ENV.plan_vel, out) < 0.0
    assert velocity_within(np.array([0.0, 0, 0, 0, 0, -np.inf]), ENV.plan_vel, out) < 0.0



def _velocity_plan(v0: np.ndarray, a0: np.ndarray, target: np.ndarray, lim: np.ndarray) -> list[np.ndarray]:
    """ruckig's velocities, cycle by cycle, from (v0, a0) to ``target`` within the limits ``lim``, as the
    shaper asks it (velocity interface, phase synchronisation falling back to time)."""
    from ruckig import ControlInterface, InputParameter, Result, Ruckig, Synchronization, Trajectory

    inp = InputParameter(6)
    inp.control_interface, inp.synchronization = ControlInterface.Velocity, Synchronization.Phase
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0] * 6, v0.tolist(), a0.tolist()
    inp.target_velocity, inp.target_acceleration = target.tolist(), [0.0] * 6
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = lim.tolist()
    traj = Trajectory(6)
    assert Ruckig(6).calculate(inp, traj) in (Result.Working, Result.Finished)
    return [np.array(traj.at_time(k * DT)[1]) for k in range(int(traj.duration / DT) + 2)]


@settings(max_examples=200, deadline=None)
@given(six, six, st.floats(0.0, 0.5), st.sampled_from([1.0, 1e-3, 0.0]))
def test_velocity_share_limits_keep_the_axes_in_proportion(v, dv, along, rest):
    """With the acceleration along the change (none, or some of it), ruckig's velocities under the share
    limits stay on the straight line from the present velocity to the target (each axis in proportion,
    none past its target), within the plain limits: the TCP keeps its line and speed while it ramps.
    With the plain limits (time synchronisation) an axis with little to change lagged the others."""
    plain = LIMITS.scaled()
    v0 = v * plain[0] * 0.5
    target = v0 + dv * rest * plain[0] * 0.5
    d = target - v0
    moving = np.abs(d) > 0.0
    # An acceleration along the change that each axis can still end before its target (else no plan can).
    reach = np.minimum(plain[1], np.sqrt(2.0 * plain[2] * np.abs(d))) / np.where(moving, np.abs(d), 1.0)
    a0 = d * along * float(np.min(reach[moving])) if moving.any() else np.zeros(6)
    lim = np.empty((3, 6))
    aim = np.empty(6)
    ok = velocity_share_limits(v0, a0, target, *plain, lim, aim)
    assert aim.tolist() == target.tolist()
    assert np.all(lim <= np.stack(plain)) and np.all(lim[0] == plain[0])
    if not moving.any():
        assert not ok
        return
    assert ok and np.all(lim > 0.0)
    scale = float(np.max(np.abs(d)))
    for vk in _velocity_plan(v0, a0, target, lim):
        share = float((vk - v0) / scale @ (d / scale) / ((d / scale) @ (d / scale)))  # (d @ d underflows at 1e-275)
        assert -1e-9 <= share <= 1.0 + 1e-9
        assert np.max(np.abs(vk - v0 - share * d)) <= 1e-6 * scale, (vk - v0) / np.where(moving, d, 1.0)


def test_velocity_share_limits_leave_an_acceleration_across_the_change_to_ruckig():
    plain = LIMITS.scaled()
    lim, aim = np.empty((3, 6)), np.empty(6)
    v0, target = np.zeros(6), np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert not velocity_share_limits(v0, np.array([5.0, 50.0, 0.0, 0.0, 0.0, 0.0]), target, *plain, lim, aim)
    assert np.all(lim == np.stack(plain)) and aim.tolist() == target.tolist()


@settings(max_examples=200, deadline=None)
@given(six, six, six, st.floats(0.01, 1.0), st.booleans())
def test_velocity_share_limits_turn_the_axes_to_braking_in_proportion(v, a, dv, size, against):
    """An acceleration against the change (the turn from speeding up to braking, or a target reached while
    still accelerating): ruckig's velocities under the turn's limits go on along the acceleration, every
    axis ending it together (the slowest at its jerk limit), to ``aim``, within the plain limits; the
    next cycle heads from there. Each axis at its own jerk limit (the plain limits) ended its acceleration
    at its own time: a pose target's TCP turned +2.1 % over its angular speed there."""
    plain = LIMITS.scaled()
    v0 = v * plain[0] * 0.3
    a0 = np.where(np.abs(a) < 1e-6, 0.0, a) * plain[1] * size  # (no subnormal accelerations)
    d = dv * plain[0] * 0.3
    assume(np.any(a0))
    d = d - (d @ a0) / (a0 @ a0) * a0 - a0 * (0.01 if against else 1e-6)  # against, or across (a hair back)
    k = float(np.min(plain[2][a0 != 0.0] / np.abs(a0[a0 != 0.0])))
    assume(np.max(np.abs(a0)) / (2.0 * k) > 1e-3 * np.max(np.abs(d)))  # (not a remnant: see the kernel)
    lim, aim = np.empty((3, 6)), np.empty(6)
    ok = velocity_share_limits(v0, a0, v0 + d, *plain, lim, aim)
    assert np.all(lim <= np.stack(plain)) and np.all(lim[0] == plain[0])
    assert ok == bool(np.all(np.abs(v0 + a0 / (2.0 * k)) <= plain[0]))
    if not ok:
        assert aim.tolist() == (v0 + d).tolist() and np.all(lim == np.stack(plain))
        return
    assert np.allclose(aim - v0, a0 / (2.0 * k), rtol=1e-8, atol=1e-12 * float(np.max(np.abs(aim - v0))))
    u = (aim - v0) / float(np.linalg.norm(aim - v0))
    plan = _velocity_plan(v0, a0, aim, lim)
    for vk in plan:
        s = float((vk - v0) @ u)
        assert np.max(np.abs(vk - v0 - s * u)) <= 1e-6 * float(np.max(np.abs(aim - v0))) + 1e-9
    # The acceleration ends together: in 1/k, within a cycle.
    assert len(plan) * DT <= 1.0 / k + 3 * DT
