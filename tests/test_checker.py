"""ControllerLimitChecker: finite differences, Appendix B windows, notes 2-3, 617, position, warnings.

Hand-computed cases use synthetic tables, dt = 10 ms and a flange function that moves 10 mm (or
100 mm) per degree of J1, so the flange speed is simply 10 * |v1| mm/s:

- Vmax = 2000 mm/s, Vmax/20 = 100 mm/s;
- acceleration stage i (1..20) = 1000 - 25 (i - 1) deg/s^2 at max payload (twice that at none);
- jerk stage i = 100000 - 2500 (i - 1) deg/s^3 (same shape, large so acc cases stay pure);
- velocity 100 deg/s, constant.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.fanuc.alarms import format_violation
from servo_app.motion.checker import ControllerLimitChecker, Violation, check_trajectory
from servo_app.motion.limit_tables import ACC, JERK, VEL, AxisTable, LimitTables
from servo_app.robots.profile import load_profile

DT = 0.01
N = 20


def make_tables(acc1: float = 1000.0, jrk1: float = 100000.0, vel: float = 100.0, vmax: float = 2000.0,
                check_time_s: float = 5.0) -> LimitTables:
    def falling(top: float) -> AxisTable:
        mx = tuple(top * (1.0 - 0.025 * i) for i in range(N))
        return AxisTable(tuple(2 * v for v in mx), mx)

    vel_t = tuple(AxisTable((vel,) * N, (vel,) * N) for _ in range(6))
    acc_t = tuple(falling(acc1) for _ in range(6))
    jrk_t = tuple(falling(jrk1) for _ in range(6))
    return LimitTables(vmax=vmax, check_time_s=check_time_s, max_payload_kg=10.0, tables=(vel_t, acc_t, jrk_t))


def flange_j1(scale_mm_per_deg: float = 10.0):
    def f(q: np.ndarray) -> np.ndarray:
        return np.array([q[0] * scale_mm_per_deg, 0.0, 0.0])

    return f


def from_acc(acc: list[float], axis: int = 0, q0: float = 0.0) -> np.ndarray:
    """Rows whose finite-difference acceleration on ``axis`` is exactly ``acc`` (after 1 resting row)."""
    rows = [np.zeros(6)]
    rows[0][axis] = q0
    v = 0.0
    for a in acc:
        v += a * DT
        r = rows[-1].copy()
        r[axis] += v * DT
        rows.append(r)
    return np.array(rows)


def run(checker: ControllerLimitChecker, rows: np.ndarray) -> list[Violation]:
    checker.reset()
    return check_trajectory(checker, rows)


def alarms(found: list[Violation]) -> list[Violation]:
    return [v for v in found if not v.warning]


def checker(**kw) -> ControllerLimitChecker:
    tables = kw.pop("tables", None) or make_tables()
    flange = kw.pop("flange", flange_j1())
    kw.setdefault("check_max_spd", False)
    return ControllerLimitChecker(tables, DT, flange, **kw)


# ---- finite differences ---------------------------------------------------------------------------

def test_first_command_has_zero_derivatives_and_then_plain_differences() -> None:
    c = checker()
    assert c.step([10, 0, 0, 0, 0, 0], 1) == []  # far from zero: the history is padded with it (FAQ)
    assert np.allclose(c.velocity, 0) and np.allclose(c.acceleration, 0) and np.allclose(c.jerk, 0)
    c.step([10.001, 0, 0, 0, 0, 0], 2)
    assert c.velocity[0] == pytest.approx(0.1)
    assert c.acceleration[0] == pytest.approx(10.0)
    assert c.jerk[0] == pytest.approx(1000.0)
    c.step([10.003, 0, 0, 0, 0, 0], 3)
    assert (c.velocity[0], c.acceleration[0], c.jerk[0]) == pytest.approx((0.2, 10.0, 0.0), abs=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.floats(-0.05, 0.05), min_size=6, max_size=6), min_size=1, max_size=30))
def test_derivatives_equal_padded_numpy_differences(steps: list[list[float]]) -> None:
    rows = np.cumsum(np.array(steps), axis=0)
    c = checker(tables=make_tables(acc1=1e12, jrk1=1e15, vel=1e9), flange=None)
    c.reset()
    for i, r in enumerate(rows):
        c.step(r, i + 1)
    padded = np.vstack([np.repeat(rows[:1], 3, axis=0), rows])
    v = np.diff(padded, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    j = np.diff(a, axis=0) / DT
    assert np.allclose(c.velocity, v[-1]) and np.allclose(c.acceleration, a[-1])
    assert np.allclose(c.jerk, j[-1], atol=1e-6 * max(1.0, float(np.abs(j).max())))
    assert np.allclose(c.usage.peak[VEL], np.abs(v).max(axis=0))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.floats(-0.03, 0.03), min_size=6, max_size=6), min_size=2, max_size=25))
def test_first_alarm_is_where_the_reference_first_exceeds_a_stage1_limit(steps: list[list[float]]) -> None:
    """Without a flange function every sample is judged at stage 1: alarm <=> some ratio > 1."""
    rows = np.cumsum(np.array(steps), axis=0)
    tables = make_tables(acc1=80.0, jrk1=8000.0, vel=2.0)
    c = ControllerLimitChecker(tables, DT, None, check_max_spd=False)
    found = alarms(run(c, rows))
    padded = np.vstack([np.repeat(rows[:1], 3, axis=0), rows])
    v = np.diff(padded, axis=0) / DT
    a = np.diff(v, axis=0) / DT
    j = np.diff(a, axis=0) / DT
    lims = [c.vel_lim, c.acc1, c.jrk1]
    ratios = np.stack([np.abs(x[-len(rows):]) / lim for x, lim in zip((v, a, j), lims, strict=True)])
    over = ratios.max(axis=(0, 2)) > 1.0 + 1e-9
    under = ratios.max(axis=(0, 2)) <= 1.0 - 1e-9
    if under.all():
        assert found == []
    elif over.any():
        first = int(np.argmax(over)) + 1
        assert found and found[0].seq == first
        kind, axis = np.unravel_index(np.argmax(ratios[:, first - 1, :]), (3, 6))
        if ratios[:, first - 1, :].max() > 1.0 + 1e-9:  # note 3: the largest excess is the one reported
            assert found[0].code == ("MOTN-609", "MOTN-610", "MOTN-611")[kind]
            assert found[0].axis == axis + 1


@settings(max_examples=25, deadline=None)
@given(st.floats(0.1, 3.0), st.integers(10, 60))
def test_usage_scales_linearly_with_amplitude(scale: float, n: int) -> None:
    t = np.linspace(0.0, 1.0, n)
    s = t**3 * (10 - 15 * t + 6 * t * t)
    base = np.outer(s, [1.0, -0.5, 0.3, 0.0, 0.2, 0.1])
    c = ControllerLimitChecker(make_tables(), DT, None, check_max_spd=False)
    run(c, base)
    u1 = c.usage.ratio.copy()
    run(c, base * scale)
    assert np.allclose(c.usage.ratio, u1 * scale, rtol=1e-9, atol=1e-12)


# ---- velocity ---------------------------------------------------------------------------------------

def test_velocity_alarm_609_and_edge_triggered_612_warning() -> None:
    c = checker(tables=make_tables(acc1=1e9, jrk1=1e12), flange=None)
    v = [50, 85, 85, 85, 50, 85, 110]  # deg/s on J2, limit 100, warning above 80
    rows = np.vstack([np.zeros(6), np.cumsum([[0, x * DT, 0, 0, 0, 0] for x in v], axis=0)])
    found = run(c, rows)
    warns = [f for f in found if f.code == "MOTN-612"]
    assert [(w.axis, w.seq) for w in warns] == [(2, 3), (2, 7)]  # once per excursion above 80 %
    assert warns[0].value == pytest.approx(85.0) and warns[0].limit == pytest.approx(100.0)
    (alarm,) = alarms(found)
    assert (alarm.code, alarm.axis, alarm.seq) == ("MOTN-609", 2, 8)
    assert alarm.value == pytest.approx(110.0) and alarm.excess == pytest.approx(1.1)
    assert format_violation(alarm) == "MOTN-609 ST:Exceeded Jnt Velocity Limit.(A:2,Sq.8)"


def test_note3_only_the_largest_excess_is_reported() -> None:
    c = checker(tables=make_tables(acc1=1e9, jrk1=1e12), flange=None)
    rows = np.array([np.zeros(6), [0, 1.1 * DT * 100, 1.3 * DT * 100, 0, 0, 0]])
    (alarm,) = alarms(run(c, rows))
    assert (alarm.code, alarm.axis) == ("MOTN-609", 3)
    # Acceleration 15x its limit beats velocity 1.3x.
    c = checker(tables=make_tables(acc1=1000.0, jrk1=1e12), flange=None)
    rows = np.array([np.zeros(6), [0, 0, 1.3, 0, 0, 0]])  # v = 130, a = 13000 (13x), immediate (stage 1)
    (alarm,) = alarms(run(c, rows))
    assert (alarm.code, alarm.axis, alarm.seq) == ("MOTN-610", 3, 2)


# ---- Appendix B -----------------------------------------------------------------------------------------

def accel_cruise_decel(a: float, n_acc: int, n_cruise: int) -> list[float]:
    return [0.0] * 2 + [a] * n_acc + [0.0] * n_cruise + [-a] * n_acc + [0.0] * 3


# A single distinct maximum (no float ties): v = 9, 18, 27.5, 36.5, 45.5, 54.7 deg/s (flange 547 mm/s).
PEAKED = [0.0] * 2 + [900.0, 900.0, 950.0, 900.0, 900.0, 920.0]
PEAK_ROW = 6  # row (= seq) of the 950 sample: acc index 4 -> row 4 + 2
PEAKED_LIMIT = 900.0 * 0.53 + 875.0 * 0.47  # Vpeak 547 -> x = 5.47 -> 888.25


def peaked(n_cruise: int) -> list[float]:
    return PEAKED + [0.0] * n_cruise + [-900.0] * 6 + [-70.0] + [0.0] * 3


def window_rows(rows: np.ndarray) -> tuple[int, int]:
    """(first row inside the window, row that closes it), 1-based, for the 10 mm/deg flange."""
    speeds = np.abs(np.diff(rows[:, 0], prepend=rows[0, 0])) / DT * 10.0
    first = int(np.argmax(speeds > 100.0))
    closing = first + int(np.argmax(speeds[first:] <= 100.0))
    return first + 1, closing + 1


def test_window_judged_at_vpeak_when_speed_falls_back_with_lag() -> None:
    # The window holds the samples above 100 mm/s; Vpeak 547 -> limit 888.25 < 950 (stage 1 is 1000,
    # so nothing is seen until the speed falls back: note 1, "time lag").
    rows = from_acc(peaked(3))
    found = run(checker(warn_lim_pct=100.0), rows)
    (alarm,) = alarms(found)
    assert alarm.code == "MOTN-610" and alarm.axis == 1
    assert alarm.limit == pytest.approx(PEAKED_LIMIT)
    assert alarm.value == pytest.approx(950.0)
    assert alarm.flange_speed == pytest.approx(547.0)
    first, closing = window_rows(rows)
    assert first < PEAK_ROW
    assert alarm.seq == PEAK_ROW
    assert alarm.detected_seq == closing > PEAK_ROW + 6


def test_same_acceleration_passes_with_a_lower_vpeak() -> None:
    # 3 cycles: Vpeak 285 mm/s -> x = 2.85 -> limit 975 * 0.15 + 950 * 0.85 = 953.75 > 950.
    c = checker(warn_lim_pct=100.0)
    assert alarms(run(c, from_acc(accel_cruise_decel(950.0, 3, 3)))) == []
    assert c.usage.ratio[ACC, 0] == pytest.approx(950.0 / 953.75)
    assert c.limits_at(285.0)[1][0] == pytest.approx(953.75)


def test_limit_extrapolates_above_vmax() -> None:
    # 100 mm per degree: a = 450 for 6 cycles -> v = 27 deg/s -> Vpeak 2700 mm/s, x = 27:
    # limit = 525 + (525 - 550) * 7 = 350 < 450; clamping at Vmax (525) would have passed it.
    c = checker(flange=flange_j1(100.0), warn_lim_pct=100.0)
    assert c.limits_at(2700.0)[1][0] == pytest.approx(350.0)
    (alarm,) = alarms(run(c, from_acc(accel_cruise_decel(450.0, 6, 2))))
    assert alarm.code == "MOTN-610" and alarm.limit == pytest.approx(350.0)
    assert alarm.flange_speed == pytest.approx(2700.0)


def test_below_vmax_over_20_the_stage1_limit_applies_immediately() -> None:
    # J2 does not move the flange in this model: speed 0, every sample judged at once at stage 1.
    rows = from_acc([0, 0, 990, 1010, 0], axis=1)
    alarm = alarms(run(checker(warn_lim_pct=100.0), rows))[0]
    assert (alarm.code, alarm.axis, alarm.seq, alarm.detected_seq) == ("MOTN-610", 2, 5, 5)
    assert alarm.limit == pytest.approx(1000.0)


def test_note2_stage1_excess_inside_a_window_stops_at_once_and_is_not_repeated() -> None:
    acc = [0, 0, 500, 500, 500, 1100, 0, 0, -500, -500, -500, -1100, 0, 0, 0]
    found = run(checker(warn_lim_pct=100.0), from_acc(acc))
    first = alarms(found)[0]
    assert (first.code, first.seq, first.detected_seq) == ("MOTN-610", 7, 7)  # 1100 > 1000 at row 7
    assert first.flange_speed is None
    assert not [f for f in alarms(found) if f.seq == 7 and f.detected_seq != 7]


def test_intermediate_check_judges_an_open_window_every_check_time() -> None:
    # Same excess as the lag test, but the window stays open for 100 cycles; check time 0.1 s =
    # 10 cycles: tentative judgments at window samples 10, 20, ... The first finds 950 > limit(Vpeak).
    rows = from_acc(peaked(100))
    first, _ = window_rows(rows)
    (alarm,) = alarms(run(checker(tables=make_tables(check_time_s=0.1), warn_lim_pct=100.0), rows))
    assert alarm.seq == PEAK_ROW
    assert alarm.detected_seq == first + 9  # the 10th sample of the window
    assert alarm.flange_speed == pytest.approx(547.0)
    # With the usual 5 s check time the same stream is only judged when the window closes.
    (late,) = alarms(run(checker(warn_lim_pct=100.0), rows))
    assert late.detected_seq == window_rows(rows)[1] > 100


def test_tentative_judgment_passes_then_a_later_one_catches_the_new_maximum() -> None:
    # Accelerate gently (500, within every limit) to 500 mm/s, cruise, then a smooth 950 bump while
    # still fast: Vpeak 775 -> limit 850 * 0.25 + 825 * 0.75 = 831.25 < 950 < 1000 (stage 1).
    bump = [300.0, 600.0, 950.0, 600.0, 300.0, -300.0, -600.0, -950.0, -600.0, -300.0]
    acc = [0.0] * 2 + [500.0] * 10 + [0.0] * 25 + bump + [0.0] * 30 + [-500.0] * 10 + [0.0] * 3
    rows = from_acc(acc)
    c = checker(tables=make_tables(check_time_s=0.1), warn_lim_pct=100.0)
    found = alarms(run(c, rows))
    bump_row = 2 + 10 + 25 + 2 + 2  # row of the +950 sample
    assert found[0].code == "MOTN-610" and found[0].seq == bump_row
    assert found[0].limit == pytest.approx(831.25)
    assert found[0].detected_seq is not None and bump_row <= found[0].detected_seq < bump_row + 10


def test_payload_interpolates_between_the_two_tables() -> None:
    rows = from_acc([0, 0, 1200, 0], axis=1)  # J2: stage 1 applies
    assert alarms(run(checker(warn_lim_pct=100.0), rows))  # max payload (default): 1000
    assert not alarms(run(checker(warn_lim_pct=100.0, payload_kg=5.0), rows))  # 1500 at half payload


def test_acceleration_and_jerk_warnings_at_warn_lim() -> None:
    rows = from_acc([0, 0, 850, 850, 0, 0], axis=1)
    found = run(checker(), rows)
    assert not alarms(found)
    assert [(w.code, w.seq) for w in found if w.code == "MOTN-613"] == [("MOTN-613", 4)]
    jrows = from_acc([0, 0, 850, 850], axis=1)
    c = checker(tables=make_tables(jrk1=100000.0))  # j = 85000 at row 4: 85 % of stage 1
    assert [w.code for w in run(c, jrows) if w.warning and w.code == "MOTN-614"] == ["MOTN-614"]


# ---- 617, positions, flange speed, NaN ------------------------------------------------------------------

def test_617_first_command_far_from_the_command_position() -> None:
    c = checker()
    c.reset(start_q_deg=np.zeros(6))
    (alarm,) = c.step([0, 0, 0, 0, 1.01 * 100 * DT, 0], 7)  # more than one cycle at 100 deg/s
    assert (alarm.code, alarm.axis, alarm.seq) == ("MOTN-617", 5, 7)
    assert format_violation(alarm) == "MOTN-617 ST:Discontinous command.(Sq.7)"
    c.reset(start_q_deg=np.zeros(6))
    assert c.step([0, 0, 0, 0, 0.99 * 100 * DT, 0], 7) == []


def test_617_later_jump_beyond_two_cycles_at_velocity_limit_else_609() -> None:
    tables = make_tables(acc1=1e12, jrk1=1e15)
    c = ControllerLimitChecker(tables, DT, None, check_max_spd=False)
    (alarm,) = alarms(run(c, np.array([np.zeros(6), [0, 0, 0, 2.5 * 100 * DT, 0, 0]])))
    assert (alarm.code, alarm.axis, alarm.seq) == ("MOTN-617", 4, 2)
    (alarm,) = alarms(run(c, np.array([np.zeros(6), [0, 0, 0, 1.5 * 100 * DT, 0, 0]])))
    assert alarm.code == "MOTN-609"


def test_joint_range_in_model_convention_after_j2_j3_conversion() -> None:
    profile = load_profile("lrmate200id")  # J3 model range -70..205
    c = ControllerLimitChecker.for_profile(profile, None, tables=make_tables(vel=1e6, acc1=1e12, jrk1=1e15),
                                           interval_s=DT, check_max_spd=False)
    c.reset()
    assert c.step([0, 100, 100, 0, 0, 0], 1) == []  # model J3 = 200
    (alarm,) = alarms(c.step([0, 100, 106, 0, 0, 0], 2))  # model J3 = 206 > 205, FANUC J3 only 106
    assert (alarm.code, alarm.axis, alarm.value, alarm.limit) == ("MOTN-017", 3, 206.0, 205.0)
    assert format_violation(alarm).startswith("MOTN-017 Limit error")


def test_flange_speed_above_max_spd_is_an_offline_violation() -> None:
    rows = from_acc([0, 0, 500, 500, 500, 500, 500, 0, 0], axis=0)  # v up to 25 -> 2500 mm/s at 100 mm/deg
    found = run(checker(flange=flange_j1(100.0), check_max_spd=True, tables=make_tables(acc1=1e9, jrk1=1e12)),
                rows)
    spd = [f for f in found if f.code == "CHK-001"]
    assert len(spd) == 1 and spd[0].value > 2000.0 and spd[0].limit == 2000.0
    assert "above $MAX_SPD 2000" in format_violation(spd[0])
    quiet = run(checker(flange=flange_j1(100.0), check_max_spd=False, tables=make_tables(acc1=1e9, jrk1=1e12)),
                rows)
    assert not [f for f in quiet if f.code == "CHK-001"]


def test_nan_is_reported_with_axis_and_leaves_the_state() -> None:
    c = checker()
    c.reset()
    c.step(np.zeros(6), 1)
    (alarm,) = c.step([0, 0, math.nan, 0, 0, 0], 2)
    assert (alarm.code, alarm.axis, alarm.seq) == ("MOTN-605", 3, 2)
    assert np.allclose(c.velocity, 0.0)


def test_finish_judges_a_window_left_open() -> None:
    c = checker(warn_lim_pct=100.0)
    c.reset()
    for i, r in enumerate(from_acc([0, 0] + [950.0] * 6), start=1):
        assert not alarms(c.step(r, i))
    (alarm,) = c.finish(9)
    assert alarm.code == "MOTN-610" and alarm.detected_seq == 9


def test_step_cost_is_small_enough_for_a_4ms_cycle() -> None:
    """Not a speed assertion: just that a step is a handful of small-array operations (no growth)."""
    profile = load_profile("lrmate200id")
    from servo_app.robots.kinematics import ArmKinematics

    c = ControllerLimitChecker.for_profile(profile, ArmKinematics(profile).flange_xyz_mm_fanuc_deg)
    c.reset()
    q = np.zeros(6)
    for i in range(500):
        t = i / 499
        q[0] = 30.0 * t**3 * (10 - 15 * t + 6 * t * t)  # quintic: smooth start and end
        c.step(q, i)
    assert c.usage.steps == 500
    assert c.usage.ratio[JERK].max() < 1.0
