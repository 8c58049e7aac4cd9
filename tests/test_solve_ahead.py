"""ServoCycle.solve_ahead: the next command's IK solved between status packets makes the same commands.

Two cycles get the same commands; one solves ahead before every command (as the FANUC servo process
does after its housekeeping), the other solves only when the command is made. Whatever changes
between the ahead solve and the command (a new twist, a stop, a jog, a pose target) must give the
command the cycle without it gives: the ahead solve is used only for the same motion, and solved
again from the same start otherwise.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.motion.commands import PoseTarget, Twist
from servo_app.motion.servo import ServoCycle
from servo_app.robots.conventions import matrix_to_xyzwpr
from servo_app.robots.profile import load_profile

PROFILE = load_profile("lrmate200id")
HOME = np.array([0.0, 10.0, -10.0, 0.0, -70.0, 0.0])
DT = 0.008
# The two cycles' IK runs warm-start DAQP from different solutions when an ahead solve is solved again
# (as a late input's solve is): equal within the solver's tolerance, then rounded to float32 by the shaper.
TOL_DEG = 1e-5


def _pair() -> tuple[ServoCycle, ServoCycle]:
    a, b = ServoCycle(PROFILE, DT), ServoCycle(PROFILE, DT)
    for c in (a, b):
        c.begin(HOME, None)
    return a, b


def _twist(x: float, z: float = 0.0, frame: str = "base") -> Twist:
    return Twist(source="test", stamp=0.0, frame=frame, linear=(x, 0.0, z), angular=(0.0, 0.0, 0.0))  # type: ignore[arg-type]


ACTIONS = st.lists(st.one_of(
    st.tuples(st.just("twist"), st.sampled_from([-40.0, -15.0, 0.0, 25.0, 40.0]), st.sampled_from(["base", "tool"])),
    st.tuples(st.just("renew"), st.none(), st.none()),
    st.tuples(st.just("stop"), st.booleans(), st.none()),
    st.tuples(st.just("resume"), st.none(), st.none()),
    st.tuples(st.just("jog"), st.sampled_from([-5.0, 5.0]), st.none()),
    st.tuples(st.just("pose"), st.sampled_from([-20.0, 20.0]), st.none()),
    st.tuples(st.just("wait"), st.integers(1, 25), st.none()),
), min_size=3, max_size=12)


def _apply(c: ServoCycle, kind: str, arg: object, cmd: Twist | None) -> None:
    if kind in ("twist", "renew"):
        assert cmd is not None
        c.twist(cmd)
    elif kind == "stop":
        c.stop(fast=bool(arg))
    elif kind == "resume":
        c.resume()
    elif kind == "jog":
        v = np.zeros(6)
        v[0] = float(arg)  # type: ignore[arg-type]
        c.jog_joints(v)
    elif kind == "pose":  # the TCP moved along X from where it is
        assert c.shaper is not None
        xyzwpr = list(matrix_to_xyzwpr(c.kin.fk_fanuc_deg(c.shaper.state[0])))
        xyzwpr[0] += float(arg)  # type: ignore[arg-type]
        c.pose_target(PoseTarget(source="test", stamp=0.0, xyzwpr=tuple(xyzwpr),  # type: ignore[arg-type]
                                 linear_speed=40.0, angular_speed=30.0))


@settings(max_examples=15, deadline=None)
@given(ACTIONS, st.lists(st.booleans(), min_size=1, max_size=8))
def test_ahead_commands_equal_commands_solved_on_the_status(actions: list[tuple[str, object, object]],
                                                            ahead_pattern: list[bool]) -> None:
    """The actions land between the ahead solve and the command (as an input or the safety machine's
    stop does on a status packet), and the ahead solve is skipped now and then."""
    ahead, plain = _pair()
    last = _twist(40.0)
    for c in (ahead, plain):
        c.twist(last)
    n = 0
    for kind, arg, arg2 in [("wait", 10, None), *actions, ("wait", 40, None)]:
        steps = int(arg) if kind == "wait" else 1  # type: ignore[call-overload]
        if kind != "wait":
            if ahead_pattern[n % len(ahead_pattern)]:
                ahead.solve_ahead()
            if kind == "twist":
                last = _twist(float(arg), frame=str(arg2))  # type: ignore[arg-type]
            elif kind == "renew":  # the same twist again: a new object, a new stamp
                last = Twist(source="test", stamp=1.0, frame=last.frame, linear=last.linear, angular=last.angular)
            for c in (ahead, plain):
                _apply(c, kind, arg, last)
        for _ in range(steps):
            if ahead_pattern[n % len(ahead_pattern)]:
                ahead.solve_ahead()
            n += 1
            qa, qp = ahead.next_command(None), plain.next_command(None)
            assert np.allclose(qa, qp, rtol=0.0, atol=TOL_DEG), (kind, qa - qp)
            assert ahead.ik_active == plain.ik_active
    assert ahead.ahead_used + ahead.ahead_dropped <= n


def test_a_steady_twist_uses_every_ahead_solve() -> None:
    """Jogging at one twist (renewed with new stamps): every command uses its ahead solve, and the
    commands are the ones solved on the status."""
    ahead, plain = _pair()
    for i in range(200):
        cmd = Twist(source="test", stamp=float(i), frame="base", linear=(40.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0))
        if i % 6 == 0:  # renewals at ~20 Hz
            ahead.twist(cmd)
            plain.twist(cmd)
        assert ahead.solve_ahead()
        np.testing.assert_allclose(ahead.next_command(None), plain.next_command(None), rtol=0.0, atol=TOL_DEG)
    assert (ahead.ahead_used, ahead.ahead_dropped) == (200, 0)
    assert plain.ahead_used == 0


def test_a_change_after_the_ahead_solve_is_solved_again() -> None:
    """A stop or a new twist that lands after the ahead solve: the command is solved afresh for it."""
    ahead, plain = _pair()
    for c in (ahead, plain):
        c.twist(_twist(40.0))
    for _ in range(30):
        ahead.solve_ahead()
        np.testing.assert_allclose(ahead.next_command(None), plain.next_command(None), rtol=0.0, atol=TOL_DEG)
    assert ahead.solve_ahead()
    for c in (ahead, plain):
        c.twist(_twist(-40.0))
    np.testing.assert_allclose(ahead.next_command(None), plain.next_command(None), rtol=0.0, atol=TOL_DEG)
    assert ahead.ahead_dropped == 1
    assert ahead.solve_ahead()
    for c in (ahead, plain):
        c.stop(fast=True)  # the IK is no longer asked: its ahead solve is forgotten
    np.testing.assert_allclose(ahead.next_command(None), plain.next_command(None), rtol=0.0, atol=TOL_DEG)
    assert ahead.ahead_dropped == 2
    assert not ahead.solve_ahead()  # no Cartesian motion: nothing to solve ahead
    for _ in range(60):
        np.testing.assert_allclose(ahead.next_command(None), plain.next_command(None), rtol=0.0, atol=TOL_DEG)
    assert ahead.at_rest() and plain.at_rest()


def test_an_ahead_solve_no_command_used_is_forgotten() -> None:
    """A fast stop lands after the ahead solve (the IK is not asked for that command), and the twist
    comes back on the next: the commands stay those of the cycle that never solved ahead."""
    ahead, plain = _pair()
    for c in (ahead, plain):
        c.twist(_twist(40.0, 20.0))
    for _ in range(40):
        ahead.solve_ahead()
        np.testing.assert_allclose(ahead.next_command(None), plain.next_command(None), rtol=0.0, atol=TOL_DEG)
    assert ahead.solve_ahead()
    for c in (ahead, plain):
        c.stop(fast=True)
    np.testing.assert_allclose(ahead.next_command(None), plain.next_command(None), rtol=0.0, atol=TOL_DEG)
    for c in (ahead, plain):
        c.twist(_twist(40.0, 20.0))
    for _ in range(40):
        ahead.solve_ahead()
        np.testing.assert_allclose(ahead.next_command(None), plain.next_command(None), rtol=0.0, atol=TOL_DEG)

