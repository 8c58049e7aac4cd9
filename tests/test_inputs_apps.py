"""Application building blocks: admittance law, stand-off controller, pose extrapolation, tracking error."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from servo_app.inputs import Measurement, PoseSample, TwistSample
from servo_app.inputs.apps.admittance import Admittance, AdmittanceParams
from servo_app.inputs.apps.standoff import StandoffController, StandoffParams
from servo_app.inputs.apps.tracking import (
    PoseExtrapolator,
    TrackingErrorMonitor,
    pose_error,
    wpr_matrix,
    wrap_deg,
)

EXACT = AdmittanceParams(lowpass_hz=None)


# -- admittance ------------------------------------------------------------------------------------

def test_admittance_deadband_gain_and_direction_keeping_limit() -> None:
    a = Admittance(EXACT)
    assert a.step([1.5, -1.9, 0, 0.1, 0, -0.15], 0.0) == ((0, 0, 0), (0, 0, 0))
    lin, ang = a.step([12.0, 0, -4.0, 0, 0.7, 0], 0.008)
    assert lin == pytest.approx((20.0, 0.0, -4.0)) and ang == pytest.approx((0.0, 2.5, 0.0))
    lin, _ = a.step([100.0, 100.0, 0, 0, 0, 0], 0.016)  # 196 mm/s per axis requested, 50 mm/s allowed
    assert math.hypot(*lin) == pytest.approx(50.0) and lin[0] == pytest.approx(lin[1])
    only_z = Admittance(AdmittanceParams(lowpass_hz=None, axes=(False, False, True, False, False, False)))
    lin, ang = only_z.step([30, 30, 30, 3, 3, 3], 0.0)
    assert lin[:2] == (0, 0) and lin[2] > 0 and ang == (0, 0, 0)


def test_admittance_bias_zeroing_on_request() -> None:
    a = Admittance(EXACT)
    offset = [5.0, -3.0, -10.0, 0.4, 0.0, 0.3]  # the tool's weight and the sensor's drift
    assert a.step(offset, 0.0)[0] != (0, 0, 0)  # unzeroed, the offset would move the robot
    a.request_bias(3)
    for i in range(3):
        assert a.biasing
        assert a.step([o + 0.01 * i for o in offset], 0.01 * i) == ((0, 0, 0), (0, 0, 0))
    assert not a.biasing and a.bias[0] == pytest.approx(5.01)
    assert a.step(offset, 0.1) == ((0, 0, 0), (0, 0, 0))
    lin, _ = a.step([offset[0] + 12.01, *offset[1:]], 0.11)
    assert lin[0] == pytest.approx(20.0)


def test_admittance_lowpass_uses_sample_stamps() -> None:
    a = Admittance(AdmittanceParams(lowpass_hz=5.0, force_deadband_n=0.0, linear_gain=1.0, max_linear_mm_s=1e9))
    a.step([0.0] * 6, 0.0)
    outs = [a.step([10.0, 0, 0, 0, 0, 0], 0.01 * k)[0][0] for k in range(1, 60)]
    assert all(b > c for b, c in zip(outs[1:], outs, strict=False)) and 0 < outs[0] < 10 and outs[-1] > 9.5
    tau = 1 / (2 * math.pi * 5.0)
    assert outs[0] == pytest.approx(10 * 0.01 / (tau + 0.01))
    b = Admittance(AdmittanceParams(lowpass_hz=5.0, force_deadband_n=0.0, linear_gain=1.0))
    b.step([0.0] * 6, 0.0)
    assert b.step([10.0, 0, 0, 0, 0, 0], 0.0)[0][0] == 0.0  # no time passed: no change


def test_admittance_from_dbc_measurement_and_sensor_rotation() -> None:
    flip_x = ((1, 0, 0), (0, -1, 0), (0, 0, -1))  # sensor mounted upside down about X
    a = Admittance(AdmittanceParams(lowpass_hz=None, keys=("Fx", "Fy", "Fz", "Tx", "Ty", "Tz"), sensor_rotation=flip_x))
    m = Measurement({"Fx": 0, "Fy": 0, "Fz": 12.0, "Tx": 0, "Ty": 0, "Tz": 0}, 3.0, "ft")
    t = a.twist(m)
    assert isinstance(t, TwistSample) and t.linear == pytest.approx((0, 0, -20.0)) and t.frame == "tool"
    assert t.stamp == 3.0
    with pytest.raises(KeyError, match="has no 'Fy'"):
        a.twist(Measurement({"Fx": 1.0}, 3.0, "ft"))


# -- stand-off -------------------------------------------------------------------------------------

def test_standoff_p_control_limits_and_stale_reading() -> None:
    c = StandoffController(StandoffParams(target_mm=100.0, kp=2.0, max_speed_mm_s=20.0, deadband_mm=0.5))
    assert c.step(105.0, 1.0, 1.0) == pytest.approx(9.0)  # too far: approach along +tool z
    assert c.step(99.8, 1.01, 1.01) == 0.0  # inside the deadband
    assert c.step(40.0, 1.02, 1.02) == -20.0  # too close: back off, at the speed limit
    assert c.step(105.0, 1.0, 1.5) == 0.0 and c.error_mm is None  # reading 0.5 s old: ignore
    assert c.step(None, None, 1.6) == 0.0
    flipped = StandoffController(StandoffParams(target_mm=100.0, direction=-1))
    assert flipped.step(110.0, 0.0, 0.0) < 0


def test_standoff_pi_follows_a_receding_surface_without_windup() -> None:
    p = StandoffParams(target_mm=100.0, kp=4.0, ki=8.0, max_speed_mm_s=50.0, integral_limit_mm_s=30.0)
    c = StandoffController(p)
    dt, surface, tool = 0.008, 250.0, 0.0  # positions along tool z; the sensor reads surface - tool
    for k in range(1500):
        t = k * dt
        surface += 10.0 * dt  # the part moves away at 10 mm/s
        vz = c.step(surface - tool, t, t)
        assert abs(vz) <= 50.0
        assert abs(c.integral) <= 30.0  # bounded even while saturated at the start
        tool += vz * dt
    assert c.error_mm == pytest.approx(0.0, abs=0.01)  # no steady-state lag, thanks to the integral
    assert c.integral == pytest.approx(10.0, abs=0.1)


def test_standoff_combines_with_operator_twist() -> None:
    c = StandoffController(StandoffParams(target_mm=50.0))
    op = TwistSample((10.0, -5.0, 99.0), (0.0, 0.0, 3.0), "tool", 2.0, "spacemouse")
    out = c.combine(op, 7.0, now=2.004)
    assert out.linear == (10.0, -5.0, 7.0) and out.angular == (0.0, 0.0, 3.0) and out.stamp == 2.0
    assert c.combine(None, 7.0, now=3.0).linear == (0.0, 0.0, 7.0)
    with pytest.raises(ValueError, match="tool-frame"):
        c.combine(TwistSample((1, 0, 0), (0, 0, 0), "base", 2.0, "x"), 7.0, now=2.0)


# -- tracking --------------------------------------------------------------------------------------

def moving_target(t: float) -> tuple[float, ...]:
    return (400 + 100 * t, 50 - 20 * t, 300.0, 180.0, 0.0, wrap_deg(170 + 30 * t))


def test_extrapolation_compensates_latency_within_horizon() -> None:
    ex = PoseExtrapolator(max_horizon_s=0.1, window=3)
    for k in range(10):
        assert ex.add(PoseSample(moving_target(0.033 * k), 0.033 * k, "vision"))
    last = 0.033 * 9
    p = ex.predict(last + 0.06)
    assert p is not None and p.stamp == pytest.approx(last + 0.06)
    assert p.xyzwpr == pytest.approx(moving_target(last + 0.06), abs=1e-6)  # crosses R = 180 on the way
    capped = ex.predict(last + 0.3)  # older than the horizon: move forward by 0.1 s only
    assert capped.stamp == pytest.approx(last + 0.1) and capped.xyzwpr[0] == pytest.approx(moving_target(last + 0.1)[0])
    assert ex.predict(last + 1.0) is None  # the stream stopped
    assert not ex.add(PoseSample(moving_target(0.0), 0.1, "vision"))  # late packet ignored


def test_extrapolation_after_a_gap_holds_the_pose() -> None:
    ex = PoseExtrapolator(max_horizon_s=0.1, max_gap_s=0.2)
    ex.add(PoseSample(moving_target(0.0), 0.0, "v"))
    ex.add(PoseSample(moving_target(0.03), 0.03, "v"))
    ex.add(PoseSample(moving_target(1.0), 1.0, "v"))  # after a 1 s gap: velocity unknown
    assert ex.velocity() is None
    assert ex.predict(1.05).xyzwpr == pytest.approx(moving_target(1.0))


@given(st.lists(st.floats(-500, 500), min_size=3, max_size=3), st.lists(st.floats(-2000, 2000), min_size=3,
       max_size=3), st.floats(0.0, 0.1), st.floats(0.005, 0.05))
def test_extrapolation_exact_for_constant_velocity(p0: list[float], v: list[float], latency: float,
                                                   period: float) -> None:
    ex = PoseExtrapolator(max_horizon_s=0.1, window=4, max_gap_s=1.0)
    for k in range(5):
        t = k * period
        ex.add(PoseSample((*[p0[i] + v[i] * t for i in range(3)], 0, 0, 0), t, "v"))
    now = 4 * period + latency
    p = ex.predict(now)
    assert p.xyzwpr[:3] == pytest.approx([p0[i] + v[i] * now for i in range(3)], abs=1e-6)


def test_pose_error_and_monitor() -> None:
    assert pose_error((0, 0, 0, 0, 0, 0), (3, 4, 0, 0, 0, 0)) == pytest.approx((5.0, 0.0))
    assert pose_error((0, 0, 0, 0, 0, 175), (0, 0, 0, 0, 0, -175))[1] == pytest.approx(10.0)
    assert pose_error((0, 0, 0, 180, 0, 0), (0, 0, 0, -180, 0, 0))[1] == pytest.approx(0.0, abs=1e-5)
    r = wpr_matrix(0, 90, 0)  # about fixed Y: X goes to -Z
    assert r @ [1, 0, 0] == pytest.approx([0, 0, -1])
    m = TrackingErrorMonitor(window=3)
    assert m.report() is None
    target = PoseSample((0, 0, 0, 0, 0, 0), 10.0, "vision")
    for dx, now in ((1.0, 10.01), (3.0, 10.02), (4.0, 10.03), (2.0, 10.04)):
        m.update(target, (dx, 0, 0, 0, 0, 0), now=now)
    rep = m.report()
    assert rep.samples == 3 and rep.position_mm_last == 2.0 and rep.position_mm_max == 4.0
    assert rep.position_mm_rms == pytest.approx(math.sqrt((9 + 16 + 4) / 3))
    assert rep.target_age_s_max == pytest.approx(0.04) and rep.angle_deg_max == 0.0
