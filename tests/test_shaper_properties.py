"""Joint shaper properties: whatever the command sequence, the float32 positions it emits have finite
differences (the controller's check) within the limits, and the guard alone keeps any candidate
sequence within them."""

from __future__ import annotations

import os

import numpy as np
from hypothesis import HealthCheck, event, given, note, settings
from hypothesis import strategies as st
from test_shaper import RAW, assert_within, finite_differences

from servo_app.motion.shaper import DiscreteGuard, Envelope, JointShaper, ShaperLimits, to_f32

# SHAPER_EXAMPLES=2000 for a long hunt; the default keeps the suite short.
SETTINGS = settings(max_examples=int(os.environ.get("SHAPER_EXAMPLES", "50")), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
POS_MAX = 360.0

unit = st.floats(-1.0, 1.0, allow_nan=False)
joints = st.lists(st.floats(-170.0, 170.0, allow_nan=False), min_size=6, max_size=6).map(np.array)
scales = st.lists(st.floats(0.3, 1.0), min_size=6, max_size=6).map(np.array)


@st.composite
def commands(draw: st.DrawFn) -> tuple:
    kind = draw(st.sampled_from(["target", "target", "velocity", "stop-soft", "stop-fast", "hold"]))
    cycles = draw(st.integers(1, 60))
    if kind == "target":
        return kind, cycles, draw(joints), (draw(st.sampled_from([1.0, 1.0, 0.5, 0.05])), draw(st.booleans()))
    if kind == "velocity":
        # components in [-1.3, 1.3] x the limit, some exactly zero (single-axis jog)
        v = np.array([draw(st.sampled_from([0.0, draw(unit) * 1.3])) for _ in range(6)])
        return kind, cycles, v, 1.0
    return kind, cycles, None, 1.0


@st.composite
def scenarios(draw: st.DrawFn) -> tuple:
    dt = draw(st.sampled_from([0.008, 0.004]))
    # Appendix B tables lower acceleration and jerk with speed and payload: vary them per axis.
    lim = ShaperLimits(RAW[0] * draw(st.floats(0.5, 1.0)), RAW[1] * draw(scales), RAW[2] * draw(scales),
                       fraction=draw(st.sampled_from([0.9, 0.9, 0.7])), pos_abs_max=POS_MAX)
    q0 = draw(joints) * 0.5
    return dt, lim, q0, draw(st.lists(commands(), min_size=1, max_size=8))


def drive(sh: JointShaper, cmds: list[tuple]) -> tuple[list[np.ndarray], int | None]:
    """Run the commands, then a soft stop to rest; the outputs and the cycle of the first fast stop."""
    out = [sh.step()]
    first_fast = None
    for kind, cycles, arg, scale in cmds:
        if kind == "target":
            sh.set_target(arg, *scale)
        elif kind == "velocity":
            sh.set_velocity(arg * sh.check_limits()[0])
        elif kind.startswith("stop"):
            sh.stop(kind[5:])
            if kind == "stop-fast" and first_fast is None:
                first_fast = len(out)
        out += [sh.step() for _ in range(cycles)]
    sh.stop("soft")
    while not sh.at_rest:
        out.append(sh.step())
        assert len(out) < 20000
    return out, first_fast


@SETTINGS
@given(scenarios())
def test_emitted_finite_differences_never_exceed_the_limits(scenario: tuple) -> None:
    dt, lim, q0, cmds = scenario
    note(f"dt={dt} cmds={[(c[0], c[1]) for c in cmds]}")
    sh = JointShaper(lim, dt, q0)
    out, first_fast = drive(sh, cmds)
    qs = np.array(out)
    in_range = bool(np.all(np.abs(qs) <= POS_MAX))
    event(f"in range: {in_range}, fast stop: {first_fast is not None}")
    if not in_range:
        # Out of contract (velocity mode ran past the range the float32 margins were sized for):
        # the guard keeps any excess at the float32 resolution.
        q = float(np.spacing(np.float32(np.abs(qs).max())))
        soft = sh.check_limits("fast")
        assert_within(qs, dt, (soft[0] + q / dt, soft[1] + 2 * q / dt**2, soft[2] + 4 * q / dt**3))
        return
    assert sh.guard.failures == 0 and sh.guard.relaxed == 0
    if sh.planning_errors:  # ruckig raised on a numerical edge case (seen once in ~10^4 runs)
        event("ruckig error, fallback plan")
        note(sh.last_planning_error)
    assert_within(qs, dt, sh.check_limits("fast"))
    # Up to the first fast stop, the normal (fraction) limits hold, from ruckig alone.
    assert_within(qs[: first_fast], dt, sh.check_limits("soft"))
    if first_fast is None and not sh.planning_errors:
        assert sh.guard.interventions == 0
    assert np.array_equal(qs[-1], qs[-2]) and np.array_equal(qs[-2], qs[-3])


@SETTINGS
@given(st.sampled_from([0.008, 0.004]), scales, st.floats(0.05, 1.0), st.sampled_from(["soft", "fast"]),
       st.integers(5, 120))
def test_stop_from_any_state_is_near_time_optimal(dt: float, acc_scale: np.ndarray, speed: float, mode: str,
                                                   cycles: int) -> None:
    sh = JointShaper(ShaperLimits(RAW[0], RAW[1] * acc_scale, RAW[2]), dt, np.zeros(6))
    direction = np.array([1.0, -0.5, 0.8, -1.0, 0.3, 0.6])
    sh.set_velocity(direction * speed * sh.check_limits()[0])
    out = [sh.step() for _ in range(cycles)]  # anywhere in the acceleration phase or cruising
    sh.set_velocity(-direction * speed * sh.check_limits()[0])
    out += [sh.step() for _ in range(cycles // 3)]  # mid-reversal: acceleration and velocity opposed
    t_opt = sh.optimal_stop_duration(mode)  # type: ignore[arg-type]
    t_planned = sh.optimal_stop_duration(mode, planned=True)  # type: ignore[arg-type]
    sh.stop(mode)  # type: ignore[arg-type]
    n = 0
    while not sh.at_rest:
        out.append(sh.step())
        n += 1
    moving = (n - 2) * dt  # the last two cycles repeat the rest position
    # Synchronizing the axes costs nothing: the stop ends in the cycle of the slowest axis' optimum
    # within the limits ruckig is given. Against the checked limits (1-14% more jerk: the float32
    # margins) the optimum is discontinuous where the lower jerk no longer brakes the acceleration
    # before the velocity crosses zero (up to 58% longer seen mid-reversal at 4 ms), so that ratio is
    # checked from cruising in test_shaper.py, not here.
    assert moving <= t_planned + dt + 1e-9, (moving, t_planned)
    assert t_planned >= t_opt - 1e-9
    assert_within(np.array(out), dt, sh.check_limits(mode))  # type: ignore[arg-type]


@st.composite
def guard_runs(draw: st.DrawFn) -> tuple:
    dt = draw(st.sampled_from([0.008, 0.004]))
    env = Envelope.build(RAW[0] * 0.9 * draw(scales), RAW[1] * 0.9 * draw(scales), RAW[2] * 0.9,
                         np.full(6, POS_MAX), dt)
    jumps = draw(st.lists(st.tuples(st.integers(1, 40), st.lists(st.floats(-300, 300), min_size=6,
                                                                  max_size=6)), min_size=1, max_size=6))
    return dt, env, jumps


@SETTINGS
@given(guard_runs())
def test_guard_keeps_any_candidate_sequence_within_the_limits(run: tuple) -> None:
    dt, env, jumps = run
    g = DiscreteGuard(dt, np.zeros(6))
    out = [g.s1.copy()]
    for cycles, target in jumps:  # candidates jumping to far positions: everything violates
        for _ in range(cycles):
            r, _ = g.filter(np.array(target), env)
            out.append(r)
    qs = np.array(out)
    assert g.failures == 0 and g.relaxed == 0
    assert_within(qs, dt, (env.vel, env.acc, env.jerk))
    v, a, _ = finite_differences(qs, dt)
    assert np.all(np.isfinite(v)) and np.all(np.isfinite(a))


@SETTINGS
@given(st.sampled_from([0.008, 0.004]), joints, joints, st.integers(1, 80))
def test_target_switch_mid_move_still_arrives(dt: float, a: np.ndarray, b: np.ndarray, switch: int) -> None:
    sh = JointShaper(ShaperLimits(*RAW), dt, np.zeros(6))
    sh.set_target(a)
    out = [sh.step() for _ in range(switch)]
    sh.set_target(b)
    while not sh.at_rest:
        out.append(sh.step())
    assert np.array_equal(out[-1], to_f32(b))
    assert_within(np.array(out), dt, sh.check_limits())


@SETTINGS
@given(st.sampled_from([0.008, 0.004]), joints, st.lists(unit, min_size=6, max_size=6).map(np.array),
       st.lists(unit, min_size=6, max_size=6).map(np.array), st.floats(1e-6, 0.05),
       st.lists(st.booleans(), min_size=6, max_size=6).map(np.array), st.floats(0.05, 1.0), st.integers(2, 40),
       st.floats(0.05, 20.0), st.floats(0.02, 1.0))
def test_a_target_set_on_line_from_a_motion_nearly_along_it_runs_straight(
        dt: float, q0: np.ndarray, way: np.ndarray, skew: np.ndarray, skew_size: float, still: np.ndarray,
        speed: float, cycles: int, length: float, scale: float) -> None:
    """``set_target_on_line`` from a motion nearly along the line (as the differential IK hands a pose
    target's finish over): the positions sent run on the straight line to the target (float32 rounding
    only) and within the limits, with nothing for the guard to correct, or it refuses and the motion goes
    on as it was. Without it (set_target): the move curves (ruckig's time synchronisation), and an axis
    with nothing to cover but 1e-15 deg/s went out by 0.15 deg and back."""
    way = np.where(still, 0.0, way)  # (some axes with nothing to cover)
    if np.linalg.norm(way) < 0.1:
        return
    u = way / np.linalg.norm(way)
    sh = JointShaper(ShaperLimits(*RAW, pos_abs_max=POS_MAX), dt, q0 * 0.5)
    sh.step()
    vel = sh.check_limits()[0]
    sh.set_velocity((u + skew * skew_size) * speed * float(np.min(vel / (np.abs(u) + skew_size))) * 0.5)
    sent = [sh.step() for _ in range(cycles)]
    p, v, a = sh.state
    q = p + u * length
    interventions = sh.guard.interventions
    if not sh.set_target_on_line(q, scale):
        event("refused")
        assert sh.mode == "velocity" and all(np.array_equal(x, y) for x, y in zip(sh.state, (p, v, a), strict=True))
        return
    event("straight")
    start = len(sent)
    for _ in range(5000):
        sent.append(sh.step())
        if sh.at_rest:
            break
    qs = np.vstack(sent)
    assert sh.at_rest and np.array_equal(qs[-1], to_f32(q))
    assert_within(qs, dt, sh.check_limits(), start)
    assert sh.guard.interventions == interventions
    h = float(np.spacing(np.float32(POS_MAX))) / 2.0
    d = qs[start:] - p
    off = np.linalg.norm(d - np.outer(d @ u, u), axis=1)
    note(f"off the line: {off.max():.2e} deg")
    assert off.max() <= np.sqrt(6.0) * h
