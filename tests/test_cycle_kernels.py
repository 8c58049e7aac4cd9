"""The servo cycle's compiled guards (servo_app.motion.cycle_kernels) against the numpy readings they
replace: the same searches must land on the same samples, bit for bit."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_robots_kernels import DIMS, KIN, PROFILE, contains_oracle, fanuc_joints, region_around, unit_offsets

from servo_app.motion import cycle_kernels as ck
from servo_app.motion.diffik import DifferentialIK
from servo_app.robots.configuration import ConfigurationRegion
from servo_app.robots.conventions import fanuc_deg_to_model_rad, model_rad_to_fanuc_deg

J23 = PROFILE.j23_factor
RANGE_LO = np.degrees(PROFILE.joint_min_rad) + 0.5  # model deg, as ServoCycle keeps them
RANGE_HI = np.degrees(PROFILE.joint_max_rad) - 0.5
START = np.array([0.0, 10.0, -10.0, 0.0, -70.0, 0.0])
IK = DifferentialIK(PROFILE, 0.008)  # its rate conversions: velocity_fanuc_deg_s, c_inv
VMAX = np.array([370.0, 310.0, 410.0, 550.0, 545.0, 1000.0]) * 0.9

velocities = st.lists(st.floats(-400.0, 400.0), min_size=6, max_size=6).map(np.array)


def safe_oracle(region: ConfigurationRegion, q_fanuc_deg: np.ndarray) -> np.ndarray:
    return contains_oracle(region, fanuc_deg_to_model_rad(q_fanuc_deg, J23))


def stoppable_scale_oracle(region, q, v, lag, brake):
    """ServoCycle._stoppable_scale's search as numpy ran it."""
    def stop_points(scales):
        w = np.outer(scales, v)
        return q + w * lag + w * np.abs(w) / (2 * brake)

    if safe_oracle(region, stop_points(np.ones(1)))[0]:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(2):
        scales = np.linspace(lo, hi, 17)[1:]
        ok = safe_oracle(region, stop_points(scales))
        first_bad = int(np.argmin(ok)) if not ok.all() else len(ok)
        if first_bad == len(ok):
            lo = hi
            break
        lo, hi = (scales[first_bad - 1] if first_bad else lo), scales[first_bad]
    return lo


def reach_oracle(region, q0, q1, samples=24):
    """ServoCycle._config_keeping_reach as numpy ran it."""
    lo, hi = 0.0, 1.0
    for _ in range(3):
        f = np.linspace(lo, hi, samples + 1)[1:]
        ok = safe_oracle(region, q0 + np.outer(f, q1 - q0))
        if ok.all():
            return hi if hi == 1.0 else lo
        first_bad = int(np.argmin(ok))
        lo, hi = (f[first_bad - 1] if first_bad else lo), f[first_bad]
    return lo


def clip_oracle(q):
    q_model = np.degrees(fanuc_deg_to_model_rad(q, J23))
    return model_rad_to_fanuc_deg(np.radians(np.clip(q_model, RANGE_LO, RANGE_HI)), J23)


@settings(max_examples=300, deadline=None)
@given(st.floats(-10.0, 10.0), st.floats(-10.0, 10.0), st.integers(2, 30))
def test_linspace_values_are_numpys(lo, hi, num):
    expected = np.linspace(lo, hi, num)
    assert [ck.linspace_at(lo, hi, num, i) for i in range(num)] == expected.tolist()


def test_linspace_of_a_vanishing_interval_is_numpys():
    lo, hi = 0.3, math.nextafter(0.3, 1.0)
    assert [ck.linspace_at(lo, hi, 17, i) for i in range(17)] == np.linspace(lo, hi, 17).tolist()


@settings(max_examples=400, deadline=None)
@given(fanuc_joints, unit_offsets, velocities, st.floats(0.01, 0.3), st.floats(50.0, 2000.0))
def test_stoppable_scale_matches_numpy(start, offset, v, lag, brake_scale):
    """From points near a region's boundaries at speeds up to the limits: the same scale."""
    region = region_around(start)
    q = start + 20.0 * offset
    brake = brake_scale * np.array([1.0, 0.8, 1.2, 2.0, 2.0, 3.0])
    scratch = np.empty(6)
    got = ck.stoppable_scale(q, v, lag, brake, J23, region.packed, scratch)
    assert got == stoppable_scale_oracle(region, q, v, lag, brake)


def test_stoppable_scale_takes_each_branch():
    """Not vacuous: all of v, a share of it, and none of it (the stop point is outside at any share)."""
    region = region_around(START)
    brake, scratch = np.full(6, 500.0), np.empty(6)
    slow, towards_flip = np.zeros(6), np.array([0.0, 0.0, 0.0, 0.0, 300.0, 0.0])
    assert ck.stoppable_scale(START, slow, 0.1, brake, J23, region.packed, scratch) == 1.0
    share = ck.stoppable_scale(START, towards_flip, 0.1, brake, J23, region.packed, scratch)
    assert 0.0 < share < 1.0
    assert share == stoppable_scale_oracle(region, START, towards_flip, 0.1, brake)
    outside = START + np.array([0.0, 0.0, 0.0, 0.0, 75.0, 0.0])  # J5 past 0: flipped already
    assert ck.stoppable_scale(outside, towards_flip, 0.1, brake, J23, region.packed, scratch) == 0.0


@settings(max_examples=400, deadline=None)
@given(fanuc_joints, unit_offsets, unit_offsets, st.floats(1.0, 300.0), st.integers(2, 30))
def test_config_keeping_reach_matches_numpy(start, offset0, offset1, length, samples):
    region = region_around(start)
    q0, q1 = start + 5.0 * offset0, start + length * offset1
    got = ck.config_keeping_reach(q0, q1, samples, J23, region.packed, np.empty(6))
    assert got == reach_oracle(region, q0, q1, samples)


def test_config_keeping_reach_takes_each_branch():
    region = region_around(START)
    scratch = np.empty(6)
    assert ck.config_keeping_reach(START, START + 5.0, 24, J23, region.packed, scratch) == 1.0
    across = START + np.array([0.0, 0.0, 0.0, 0.0, 140.0, 0.0])  # J5 from -70 to +70: flips halfway
    reach = ck.config_keeping_reach(START, across, 24, J23, region.packed, scratch)
    assert 0.4 < reach < 0.5
    assert reach == reach_oracle(region, START, across)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-400.0, 400.0), min_size=6, max_size=6).map(np.array))
def test_clip_to_range_matches_numpy(q):
    out = np.empty(6)
    ck.clip_to_range(q, J23, RANGE_LO, RANGE_HI, out)
    assert out.tolist() == clip_oracle(q).tolist()
    ck.clip_to_range(q, J23, RANGE_LO, RANGE_HI, q)  # in place, as the jog kernel does
    assert q.tolist() == out.tolist()


@settings(max_examples=300, deadline=None)
@given(fanuc_joints, unit_offsets, velocities.map(lambda v: v * (np.abs(v) > 200.0)), st.floats(0.05, 1.0),
       st.floats(0.1, 2.0))
def test_jog_target_matches_numpy(start, offset, v, speed_scale, horizon):
    """ServoCycle._steer_jog's target: ahead by the horizon, clipped, cut at the configuration."""
    region = region_around(start)
    q = start + 5.0 * offset
    out = np.empty(6)
    scale = ck.jog_target(q, v, speed_scale, VMAX, horizon, J23, RANGE_LO, RANGE_HI, region.packed, np.empty(6), out)
    share = float(np.max(np.abs(v * speed_scale) / VMAX))
    if share <= 1e-9:
        assert scale == share
        return  # held: no target
    ahead = clip_oracle(q + v * speed_scale * horizon)
    # Along the clipped line, at the share where no jogged joint runs faster than asked.
    d = np.abs(ahead - q)
    moving, jogged = d > 0.0, (d > 0.0) & (v != 0.0)
    if jogged.any():
        with np.errstate(over="ignore"):  # (a joint a rounding step from its limit: inf, as in the kernel)
            share = min(share, float(np.min(np.abs(v[jogged] * speed_scale) / d[jogged]))
                        / float(np.min(VMAX[moving] / d[moving])))
    assert scale == pytest.approx(share, rel=1e-12)
    if moving.any():  # no further than the jog runs in the horizon (the kernel's own scale: bit for bit)
        with np.errstate(over="ignore"):
            frac = min(scale, 1.0) * float(np.min(VMAX[moving] / d[moving])) * horizon
        if frac < 1.0:
            ahead = q + (ahead - q) * frac
    assert out.tolist() == (q + (ahead - q) * reach_oracle(region, q, ahead)).tolist()


def test_jog_target_of_a_still_jog_is_none():
    out = np.full(6, 7.0)
    assert ck.jog_target(START, np.zeros(6), 1.0, VMAX, 0.5, J23, RANGE_LO, RANGE_HI, region_around(START).packed,
                         np.empty(6), out) == 0.0
    assert out.tolist() == [7.0] * 6


@settings(max_examples=300, deadline=None)
@given(fanuc_joints, velocities, st.lists(st.floats(-3000.0, 3000.0), min_size=6, max_size=6).map(np.array),
       st.sampled_from([0.004, 0.008]))
def test_predicted_flange_speed_matches_numpy(q, v, a, dt):
    ahead = q + (v + a * 4 * dt) * 4 * dt
    expected = float(np.linalg.norm(KIN.flange_xyz_mm_fanuc_deg(ahead) - KIN.flange_xyz_mm_fanuc_deg(q))) / (4 * dt)
    got = ck.predicted_flange_speed(q, v, a, dt, J23, DIMS, np.empty(6))
    assert math.isclose(got, expected, rel_tol=1e-13, abs_tol=1e-9)


@settings(max_examples=300, deadline=None)
@given(fanuc_joints, unit_offsets, velocities, velocities, st.sampled_from([1.0, 1e-3, 1e-5]))
def test_ik_velocity_guard_matches_numpy(start, offset, v_model, v_now, size):
    """ServoCycle._steer_ik's cut: the IK's velocity in FANUC deg/s (velocity_fanuc_deg_s), the
    stoppable share, then zero below a creep (1e-3 deg/s)."""
    region = region_around(start)
    q, brake, creep = start + 20.0 * offset, np.full(6, 700.0), 1e-3
    v_model, v_now = np.radians(v_model) * size, v_now * size
    v = IK.velocity_fanuc_deg_s(v_model)
    scale = stoppable_scale_oracle(region, q, v, 0.1, brake)
    expected = v * scale
    if (np.abs(expected) < creep).all() and (np.abs(v_now) < creep).all():
        expected = np.zeros_like(expected)
    got = np.empty(6)
    assert ck.guard_ik_velocity(q, v_model, v_now, 0.1, brake, J23, region.packed, creep, np.empty(6), got) == scale
    assert got.tolist() == expected.tolist()


@settings(max_examples=300, deadline=None)
@given(fanuc_joints, velocities, st.sampled_from([0.004, 0.008]))
def test_ik_start_matches_numpy(q, v, dt):
    """The IK's start: fanuc_deg_to_model_rad and the IK's own rate conversion (c_inv), bit for bit."""
    q_m, dq = np.empty(6), np.empty(6)
    ck.ik_start(q, v, J23, dt, q_m, dq)
    assert q_m.tolist() == fanuc_deg_to_model_rad(q, J23).tolist()
    assert dq.tolist() == (IK.c_inv @ np.radians(v) * dt).tolist()


def test_ik_velocity_guard_holds_a_creep_still():
    region = region_around(START)
    slow, v = np.radians(np.full(6, 5e-4)), np.empty(6)
    ck.guard_ik_velocity(START, slow, np.zeros(6), 0.1, np.full(6, 700.0), J23, region.packed, 1e-3, np.empty(6), v)
    assert not v.any()
    ck.guard_ik_velocity(START, slow, np.full(6, 0.1), 0.1, np.full(6, 700.0), J23, region.packed, 1e-3, np.empty(6), v)
    assert v.tolist() == IK.velocity_fanuc_deg_s(slow).tolist()  # still moving faster: braked by the shaper
