"""Each compiled kernel of the IK cycle (servo_app.motion.ik_kernels) against a plain numpy / MuJoCo /
mink oracle on random inputs: the limit rows to the bit, the rest within rounding."""

from __future__ import annotations

import math

import mink
import mujoco
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from servo_app.motion import ik_kernels as k
from servo_app.motion.diffik import DifferentialIK
from servo_app.motion.ik_limits import braking_speed, fanuc_rate_matrix
from servo_app.robots.profile import load_profile

PROFILE = load_profile("lrmate200id")
finite = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)
vec6 = arrays(np.float64, 6, elements=finite)
mat6 = arrays(np.float64, (6, 6), elements=finite)


def unit_quat(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-3 else np.array([1.0, 0.0, 0.0, 0.0])


poses = st.builds(lambda q, p: np.concatenate([unit_quat(q), p]),
                  arrays(np.float64, 4, elements=finite), arrays(np.float64, 3, elements=finite))


@given(a=poses, b=poses)
def test_quaternion_product_and_rotation_between_match_mujoco(a: np.ndarray, b: np.ndarray) -> None:
    out, ref = np.empty(4), np.empty(4)
    k.quat_mul(out, a[:4].copy(), b[:4].copy())
    mujoco.mju_mulQuat(ref, a[:4], b[:4])
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-15)
    b_inv, diff, w = np.empty(4), np.empty(4), np.empty(3)
    mujoco.mju_negQuat(b_inv, b[:4])
    mujoco.mju_mulQuat(diff, a[:4], b_inv)
    mujoco.mju_quat2Vel(w, diff, 1.0)
    rot = np.empty(3)
    k.rotation_between(rot, a, b)
    np.testing.assert_allclose(rot, w, rtol=1e-9, atol=1e-12)


speeds3 = st.tuples(*[st.one_of(st.floats(-4000.0, 4000.0, allow_nan=False), st.just(0.0), st.just(-0.0))] * 3)


@given(linear=speeds3, angular=speeds3)
def test_twist_in_si_units_is_numpys_to_the_bit(linear: tuple[float, float, float],
                                                angular: tuple[float, float, float]) -> None:
    ref = np.array((*linear, *angular), dtype=float)  # the reading the kernel replaced
    ref[:3] /= 1000.0
    np.radians(ref[3:], out=ref[3:])
    out = np.empty(6)
    moves = k.twist_si(linear, angular, out)
    assert out.tobytes() == ref.tobytes()
    assert moves == bool(ref.any())


@given(dq=arrays(np.float64, 6, elements=st.floats(-1e3, 1e3)), q=vec6, dt=st.sampled_from([0.004, 0.008, 0.1]),
       bad=st.sampled_from([None, math.nan, math.inf, -math.inf]), at=st.integers(0, 5))
def test_step_outputs_are_numpys_to_the_bit_and_refuse_non_finite(dq: np.ndarray, q: np.ndarray, dt: float,
                                                                  bad: float | None, at: int) -> None:
    if bad is not None:
        dq[at] = bad
    out = np.full((3, 6), 7.0)
    ok = k.step_outputs(dq, q, dt, out)
    if bad is not None:
        assert not ok and (out == 7.0).all()  # untouched
        return
    assert ok
    assert out.tobytes() == np.array([dq, q + dq, dq / dt]).tobytes()
    apart = [np.full(6, 7.0) for _ in range(3)]  # the form the one-call Cartesian step writes
    assert k.step_outputs_into(dq, q, dt, *apart)
    assert b"".join(x.tobytes() for x in apart) == out.tobytes()


@given(pose=poses, xi=vec6, s=st.floats(-2.0, 2.0), dt=st.sampled_from([0.004, 0.008, 1.0]))
def test_advance_matches_mujoco(pose: np.ndarray, xi: np.ndarray, s: float, dt: float) -> None:
    xi_dt = s * xi * dt
    turn, ref = np.array([1.0, 0.0, 0.0, 0.0]), np.empty(7)
    mujoco.mju_quatIntegrate(turn, xi_dt[3:], 1.0)
    mujoco.mju_mulQuat(ref[:4], turn, pose[:4])
    ref[4:] = pose[4:] + xi_dt[:3]
    out = np.empty(7)
    k.advance(out, pose, xi, s, dt)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-14)


@given(ref=poses, xi=vec6, step=vec6)
def test_along_track_and_near_match_numpy(ref: np.ndarray, xi: np.ndarray, step: np.ndarray) -> None:
    tcp = np.empty(7)
    k.advance(tcp, ref, step, 1.0, 0.01)
    w = np.array([1.0] * 3 + [0.09] * 3)
    rot = np.empty(3)
    k.rotation_between(rot, tcp, ref)
    err = np.concatenate([tcp[4:] - ref[4:], rot])
    norm = float(xi @ (w * xi))
    out = np.empty(7)
    moved = k.along_track(out, ref, tcp, xi, w)
    assert moved == (norm > 0.0)
    if moved:
        expected = np.empty(7)
        k.advance(expected, ref, xi, float(err @ (w * xi)) / norm, 1.0)
        np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-12)
    near = np.linalg.norm(tcp[4:] - ref[4:]) <= 1e-2 and np.linalg.norm(rot) * 0.7 <= 1e-2
    assert k.poses_near(tcp, ref, 1e-2, 0.7) == near


@given(ref=poses, to_goal=vec6, step=vec6)
def test_along_track_to_moves_each_part_along_its_line_to_the_goal(ref: np.ndarray, to_goal: np.ndarray,
                                                                   step: np.ndarray) -> None:
    tcp, goal = np.empty(7), np.empty(7)
    k.advance(tcp, ref, step, 1.0, 0.01)
    k.advance(goal, ref, to_goal, 1.0, 0.1)
    line, err = np.empty(6), np.empty(6)
    line[:3], err[:3] = goal[4:] - ref[4:], tcp[4:] - ref[4:]
    k.rotation_between(line[3:], goal, ref)
    k.rotation_between(err[3:], tcp, ref)
    norms = float(line[:3] @ line[:3]), float(line[3:] @ line[3:])
    out = np.empty(7)
    moved = k.along_track_to(out, ref, tcp, goal)
    assert moved == (max(norms) > 0.0)
    if not moved:
        return
    shift = np.zeros(6)
    for part, norm in ((slice(0, 3), norms[0]), (slice(3, 6), norms[1])):
        if norm > 0.0:
            shift[part] = float(err[part] @ line[part]) / norm * line[part]
    expected = np.empty(7)
    k.advance(expected, ref, shift, 1.0, 1.0)
    np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-12)
    # Still on the line to the goal, and the position error left is across it (the pull-back never
    # pushes along it).
    assert np.linalg.norm(np.cross(out[4:] - ref[4:], line[:3])) <= 1e-12 * (1.0 + norms[0])
    assert abs(float((tcp[4:] - out[4:]) @ line[:3])) <= 1e-12 * (1.0 + norms[0])


@given(prev=vec6, direction=vec6, dq_prev=vec6, lim=arrays(np.float64, 6, elements=st.floats(1e-6, 1.0)))
def test_turn_cap_is_the_speed_at_which_the_turn_fits(prev: np.ndarray, direction: np.ndarray, dq_prev: np.ndarray,
                                                      lim: np.ndarray) -> None:
    c = fanuc_rate_matrix(PROFILE.j23_factor)
    out = np.empty(6)
    prev0 = prev.copy()
    cap = k.turn_cap(prev, direction, c, dq_prev, lim, out)
    u = c @ direction
    np.testing.assert_allclose(out, u, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(prev, prev0)  # read only: the caller keeps it for undo
    nu, npv = float(np.linalg.norm(u)), float(np.linalg.norm(prev))
    share = float(np.linalg.norm(c @ dq_prev)) / npv if npv > 0.0 else 0.0
    if nu == 0.0 or npv == 0.0 or share < 0.01:
        assert cap == math.inf
        return
    # Per unit of path, the full-speed increment turns by `turn`; at the share cap, cap**2 * turn is
    # within lim on every axis, and on one of them at it.
    turn = np.abs(u - prev * (nu / npv)) / share
    if not (turn > 0.0).any():
        assert cap == math.inf
        return
    assert np.all(cap * cap * turn <= lim * (1.0 + 1e-9))
    assert np.any(cap * cap * turn >= lim * (1.0 - 1e-9))


@given(jac=mat6, reach=st.floats(0.1, 2.0))
def test_condition_number_matches_the_svd(jac: np.ndarray, reach: float) -> None:
    scaled = jac.copy()
    scaled[:3] /= reach
    sv = np.linalg.svd(scaled, compute_uv=False)
    expected = sv[0] / sv[-1] if sv[-1] > 1e-12 * sv[0] else 1e12
    got = k.condition_number(jac, reach, np.empty((6, 6)))
    if expected < 1e8:  # well inside the cap: the same value to rounding (relative error ~ eps * kappa)
        assert math.isclose(got, expected, rel_tol=1e-12 * max(1.0, expected))
    else:
        assert got > 1e7


@given(a=mat6, rhs=arrays(np.float64, (6, 2), elements=finite))
def test_cholesky_solve_matches_numpy(a: np.ndarray, rhs: np.ndarray) -> None:
    p = a.T @ a + 0.1 * np.eye(6)
    x = rhs.copy()
    assert k.cholesky_solve(p, x)
    np.testing.assert_allclose(x, np.linalg.solve(p, rhs), rtol=1e-9, atol=1e-9)
    assert not k.cholesky_solve(-p, rhs.copy())


IK = DifferentialIK(PROFILE, 0.008)


@settings(max_examples=60, deadline=None)
@given(u=arrays(np.float64, 6, elements=st.floats(0.05, 0.95)), xi=vec6, goal=vec6, with_ref=st.booleans())
def test_cartesian_objective_matches_minks_tasks(u: np.ndarray, xi: np.ndarray, goal: np.ndarray,
                                                 with_ref: bool) -> None:
    lo, hi = np.radians(PROFILE.joint_min_deg), np.radians(PROFILE.joint_max_deg)
    q = lo + u * (hi - lo)
    IK.configuration.update(q)
    IK.posture_task.set_target(q + 0.1 * goal)
    tcp = IK.configuration.get_transform_frame_to_world(IK.site, "site")
    target = (tcp @ mink.SE3.exp(xi * 0.01)).wxyz_xyz.copy()
    ref = (tcp @ mink.SE3.exp(-xi * 0.003)).wxyz_xyz.copy()
    p, c = IK._cartesian_objective(target, ref if with_ref else None)
    IK.frame_task.set_target(mink.SE3(target))
    p_ref, c_ref = IK.objective([IK.frame_task, IK.posture_task])
    np.testing.assert_allclose(p, p_ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(c, c_ref, rtol=1e-9, atol=1e-14)
    d = np.linalg.solve(p_ref, -c_ref)
    if with_ref:
        IK.frame_task.set_target(mink.SE3(ref))
        _, c_back = IK.objective([IK.frame_task, IK.posture_task])
        d_corr = np.linalg.solve(p_ref, -c_back)
        gain = IK._correction_gain
        np.testing.assert_allclose(IK._d[0], d - d_corr * (1.0 - gain), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(IK._d[1], d_corr * gain, rtol=1e-9, atol=1e-12)
    else:
        np.testing.assert_allclose(IK._d[0], d, rtol=1e-9, atol=1e-12)
        assert not IK._d[1].any()


rows = st.integers(1, 30).flatmap(lambda m: st.tuples(
    arrays(np.float64, (m, 6), elements=finite),
    arrays(np.float64, m, elements=st.one_of(st.floats(-1.0, 5.0), st.just(math.inf)))))


@given(gh=rows, direction=vec6, shift=vec6, with_shift=st.booleans())
def test_scale_interval_matches_numpy(gh: tuple[np.ndarray, np.ndarray], direction: np.ndarray, shift: np.ndarray,
                                      with_shift: bool) -> None:
    g, h = gh
    hs = h - g @ shift if with_shift else h
    a = g @ direction
    lo = max((hs[a < -1e-15] / a[a < -1e-15]).tolist(), default=-math.inf)
    hi = min((hs[a > 1e-15] / a[a > 1e-15]).tolist(), default=math.inf)
    still = np.abs(a) <= 1e-15
    empty = bool(np.any(hs[still] < -1e-12)) or lo > hi
    got = k.scale_interval(direction, g, h, shift, 1.0 if with_shift else 0.0)
    if empty:
        # Only a rounding-level tie may differ (g @ x summed in another order).
        assert math.isnan(got[0]) or got[0] >= got[1] - 1e-9 * max(1.0, abs(got[1]))
    else:
        assert not math.isnan(got[0])
        np.testing.assert_allclose(got, (lo, hi), rtol=1e-9, atol=1e-12)


@given(gh=rows, dq=vec6, vb=arrays(np.bool_, 12))
def test_binding_flags_match_numpy(gh: tuple[np.ndarray, np.ndarray], dq: np.ndarray, vb: np.ndarray) -> None:
    g, h = gh
    m = len(h)
    flags = (1 << (np.arange(m) % 5)).astype(np.int64)
    lo, hi = min(2, m), min(14, m)
    slack = h - g @ dq
    binds = np.isfinite(h) & (slack <= 1e-9 + 1e-6 * np.abs(h))
    expected = 0
    accel = False
    for i in np.flatnonzero(binds):
        expected |= int(flags[i])
        if lo <= i < hi:
            if vb[i - lo]:
                expected |= 1 << 6
            else:
                accel = True
    if not accel:
        expected &= ~(1 << 7)
    with np.errstate(invalid="ignore"):  # inf - inf on inactive rows
        tie = np.isfinite(h) & (np.abs(slack - (1e-9 + 1e-6 * np.abs(h))) < 1e-12)
    if not tie.any():  # away from a tie at the tolerance (rounding of g @ dq)
        assert k.binding_flags(g, h, dq, flags, lo, hi, vb, 1e-9, 1 << 6, 1 << 7) == expected


@given(s=st.floats(-1e3, 1e3), direction=vec6, shift=vec6)
def test_line_point_is_numpys_to_the_bit(s: float, direction: np.ndarray, shift: np.ndarray) -> None:
    out = np.empty(6)
    k.line_point(s, direction, shift, out)
    assert out.tobytes() == (s * direction + shift).tobytes()


@given(a=arrays(np.float64, 6, elements=st.floats(-1e6, 1e6)), b=arrays(np.float64, 6, elements=st.floats(-1e6, 1e6)))
def test_dot_sums_in_index_order_like_numpy(a: np.ndarray, b: np.ndarray) -> None:
    in_order = 0.0
    for x, y in zip(a.tolist(), b.tolist(), strict=True):  # Python floats: IEEE, no fused multiply-add
        in_order += x * y
    assert k.dot(a, b) == in_order
    assert math.isclose(k.dot(a, b), float(a @ b), rel_tol=1e-12, abs_tol=1e-300)  # numpy's (BLAS) dot


@given(gh=rows, dq=vec6, d=vec6, s_goal=st.sampled_from([0.0, 1.0]), s_sing=st.floats(0.0, 1.0), q=vec6,
       dt=st.sampled_from([0.004, 0.008]), vb=arrays(np.bool_, 12))
def test_step_result_is_the_steps_own_arithmetic(gh: tuple[np.ndarray, np.ndarray], dq: np.ndarray, d: np.ndarray,
                                                 s_goal: float, s_sing: float, q: np.ndarray, dt: float,
                                                 vb: np.ndarray) -> None:
    """The reading step_result replaced: Python's min/max over the dots, and the two kernels it calls."""
    g, h = gh
    flags = (1 << (np.arange(len(h)) % 5)).astype(np.int64)
    lo, hi = min(2, len(h)), min(14, len(h))
    dd = k.dot(d, d)
    expected = min(max(k.dot(dq, d) / dd, 0.0), 1.0) * s_sing if s_goal == 1.0 and dd > 0.0 else 0.0
    out, ref = np.empty((3, 6)), np.empty((3, 6))
    scale, bits, finite = k.step_result(dq, d, s_goal, s_sing, q, dt, g, h, flags, lo, hi, vb, 1e-9, 1 << 6, 1 << 7,
                                        out)
    assert scale == expected or (math.isnan(scale) and math.isnan(expected))
    assert bits == k.binding_flags(g, h, dq, flags, lo, hi, vb, 1e-9, 1 << 6, 1 << 7)
    assert finite == k.step_outputs(dq, q, dt, ref) and out.tobytes() == ref.tobytes()


@given(prev=vec6, j23=st.floats(-1.0, 1.0), dt=st.sampled_from([0.004, 0.008]))
def test_acceleration_rows_equal_the_numpy_formula(prev: np.ndarray, j23: float, dt: float) -> None:
    c = fanuc_rate_matrix(j23)
    vel, acc = np.radians(PROFILE.vel_limit), np.radians(PROFILE.acc_limit)
    p, vmax, da = c @ prev, vel * dt, acc * dt * dt
    upper = np.minimum(np.maximum(vmax, p - da), p + da)
    lower = np.maximum(np.minimum(-vmax, p + da), p - da)
    h, bound = np.empty(12), np.empty(12, dtype=bool)
    k.acceleration_rows(c, prev, vmax, da, h, bound)
    np.testing.assert_array_equal(h, np.concatenate([upper, -lower]))
    np.testing.assert_array_equal(bound, np.concatenate([upper < p + da, lower > p - da]))


@given(q=vec6, bound=arrays(np.float64, 12, elements=st.floats(-3.0, 3.0)), u=vec6,
       with_path=st.booleans(), lag=st.floats(0.0, 0.1))
def test_braking_rows_and_path_rate_equal_the_numpy_formula(q: np.ndarray, bound: np.ndarray, u: np.ndarray,
                                                            with_path: bool, lag: float) -> None:
    dt = 0.008
    brake = np.radians(PROFILE.acc_limit) * 0.4
    acc = np.concatenate([brake, brake])
    c = fanuc_rate_matrix(PROFILE.j23_factor)
    u_copy = np.empty(6)
    rate = k.path_rate(c, brake, u, u_copy)
    uf = np.abs(c @ u)
    moved = uf > 1e-12 * max(float(uf.max()), 1e-300)
    with np.errstate(over="ignore"):  # a direction of a few 1e-308 gives an infinite rate, in the kernel too
        expected = np.min(brake[moved] / uf[moved]) if moved.any() else math.inf
    assert rate == expected
    np.testing.assert_array_equal(u_copy, u)
    distance = bound - np.concatenate([q, -q])
    h, hp = np.empty(12), np.empty(12)
    cols = np.arange(6, dtype=np.int64)
    k.braking_rows(bound, acc, brake, cols, q, dt, lag, with_path, u, rate if math.isfinite(rate) else 0.0, 0.05,
                   h, hp)
    np.testing.assert_array_equal(h, dt * braking_speed(distance, acc, dt + lag))
    if with_path:
        r = rate if math.isfinite(rate) else 0.0
        decel = np.minimum(brake, np.maximum(r * np.abs(u), 0.05 * brake))
        np.testing.assert_array_equal(hp, dt * braking_speed(distance, np.concatenate([decel, decel]), dt + lag))
    else:
        np.testing.assert_array_equal(hp, h)


@given(q=vec6, q0=vec6, near=arrays(np.float64, (4, 6), elements=finite),
       wf=arrays(np.float64, (3, 6), elements=st.floats(0.0, 1.0)),
       wn=arrays(np.float64, (4, 6), elements=st.floats(0.0, 1.0)),
       slack=arrays(np.float64, 3, elements=st.floats(-0.1, 5.0)))
def test_collision_drift_matches_numpy(q, q0, near, wf, wn, slack) -> None:
    drift = np.empty(4)
    refresh = k.collision_drift(q, q0, wf, near, wn, slack, drift)
    assert refresh == bool((slack - wf @ np.abs(q - q0)).min() <= 0.0)
    if not refresh:
        np.testing.assert_allclose(drift, (np.abs(q - near) * wn).sum(axis=1), rtol=1e-12, atol=1e-15)


@given(v=vec6, bad=st.sampled_from([math.nan, math.inf, -math.inf]), at=st.integers(0, 5))
def test_any_nonzero_and_all_finite_match_numpy(v: np.ndarray, bad: float, at: int) -> None:
    assert k.any_nonzero(v) == bool(v.any())
    assert not k.any_nonzero(np.zeros(6))
    assert k.all_finite(v)
    v[at] = bad
    assert not k.all_finite(v)


sparse = st.lists(st.sampled_from([0.0, -0.0, 1e-300, -2.5, math.nan, math.inf]), min_size=6, max_size=6).map(np.array)


@given(a=sparse, b=sparse)
def test_any_nonzero2_is_numpys_any_of_both(a: np.ndarray, b: np.ndarray) -> None:
    assert k.any_nonzero2(a, b) == bool(a.any() or b.any())
