"""A pose target never commands the TCP faster than its ``linear_speed`` / ``angular_speed``.

Measured from the commands actually sent, as the controller and ``servo-app check`` see them: forward
kinematics of consecutive commanded joints (float32, as they go out) over the fixed interval. The
servo cycle runs in process (diff-IK, jerk-limited shaper, guards), no I/O.

Old code: the IK's reference pose integrated what each cycle asked for while the shaper delivered it
later, and the pull-back toward that reference pushed the TCP along the line: a 100 mm move asked at
40 mm/s ran at 64 mm/s (+60 %) for ~10 cycles after the start.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.errors import CommandRejected
from servo_app.fanuc.packets import Status
from servo_app.motion.commands import PoseTarget
from servo_app.motion.servo import ServoCycle, ServoSettings
from servo_app.robots.conventions import fanuc_deg_to_model_rad, matrix_to_xyzwpr
from servo_app.robots.profile import load_profile

PROFILE = load_profile("lrmate200id")
HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
REL = 0.02  # the stated tolerance: 2 % of the requested speed ...
ABS_MM_S, ABS_DEG_S = 0.05, 0.02  # ... plus the float32 rounding of the joints sent (~0.03 mm/s at 4 ms)
# While the jerk-limited shaper ramps up (its first 0.2 s): up to +1.0 % measured (150 random targets,
# the pull-back across the line at 500 mm/s). Before the joints changed velocity in proportion
# (shaper_kernels.velocity_share_limits) they lagged unevenly there: up to +4.8 %; before that the
# old code's +27 % and +60 %.
RAMP_S, RAMP_REL = 0.2, 0.012
# Random targets (the property tests) are held to a looser bound over their first speeding up and its
# turn to braking: measured on random targets, 1 in 50-100 runs over 1.2 % in the ramp (up to +1.9 %:
# [63.6, -140.7, -16.3, 6.3, 13.8, 17.9] at 362 mm/s, 8 ms; +1.42 %: [-113, 10, -135, 17.6, -13.1, -3.6]
# at 282.5 mm/s, 66.1 deg/s, 8 ms, 200 mm tool), where the acceleration turns off the change but not
# against it and the shaper takes the plain limits (velocity_share_limits). The turn to braking itself
# (the acceleration against the change) keeps the joints in proportion since: +2.1 % before
# (test_the_turn_to_braking_of_a_short_move_keeps_its_angular_speed).
RANDOM_RAMP_REL = 0.03


class Run(NamedTuple):
    lin: np.ndarray  # TCP speed between consecutive commands sent, mm/s ...
    ang: np.ndarray  # ... and deg/s
    ik_cycles: int  # commands the IK drove (before the last millimetres' joint move, ServoSettings.finish_mm)
    arrived: bool
    joints: np.ndarray  # the commands sent (FANUC deg, float32 values)


def pose_run(offset: list[float], linear: float, angular: float, dt: float = 0.008,
             tool: tuple[float, ...] | None = None, cap: float | None = None) -> Run | None:
    """A pose target ``offset`` (mm, deg) from the TCP at HOME, run until it is reached (None if refused);
    ``cap``: the flange speed cap (mm/s; None: the profile's)."""
    cycle = ServoCycle(PROFILE, dt, ServoSettings(flange_speed_cap=cap, tool_xyzwpr=tool))
    cycle.begin(HOME, None)
    sent = [cycle.next_command(Status(seq=1))]
    kin = cycle.ik.kin
    goal = np.asarray(matrix_to_xyzwpr(kin.fk_tcp(fanuc_deg_to_model_rad(HOME, PROFILE.j23_factor)))) + offset
    try:
        cycle.pose_target(PoseTarget(xyzwpr=tuple(goal), linear_speed=linear, angular_speed=angular, source="t",
                                     stamp=0.0))
    except CommandRejected:  # out of reach, or too fast for the flange with this tool
        return None
    ik_cycles = 0
    for _ in range(int(40.0 / dt)):
        sent.append(cycle.next_command(Status(seq=1)))
        if cycle._finishing is None:
            ik_cycles = len(sent) - 1
        elif cycle.at_rest():
            break
    arrived = cycle._finishing is not None and cycle.at_rest()
    tcp = [kin.fk_tcp(fanuc_deg_to_model_rad(np.float32(q).astype(float), PROFILE.j23_factor)) for q in sent]
    lin = np.array([np.linalg.norm(b[:3, 3] - a[:3, 3]) * 1000.0 / dt for a, b in itertools.pairwise(tcp)])
    cos = [(np.trace(b[:3, :3] @ a[:3, :3].T) - 1.0) / 2.0 for a, b in itertools.pairwise(tcp)]
    ang = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) / dt
    return Run(lin, ang, ik_cycles, arrived, np.float32(sent).astype(float))


def assert_within(lin: np.ndarray, ang: np.ndarray, linear: float, angular: float, ramp: int = 0,
                  ramp_rel: float = RAMP_REL) -> None:
    """Every speed within the stated tolerance (the first ``ramp`` of them within ``ramp_rel``)."""
    rel = np.full(len(lin), REL)
    rel[:ramp] = ramp_rel
    over_lin = lin - (linear * (1 + rel) + ABS_MM_S)
    over_ang = ang - (angular * (1 + rel) + ABS_DEG_S)
    i, j = int(np.argmax(over_lin)), int(np.argmax(over_ang))
    assert over_lin[i] <= 0.0, f"{lin[i]:.2f} mm/s at command {i + 1} for {linear} mm/s"
    assert over_ang[j] <= 0.0, f"{ang[j]:.3f} deg/s at command {j + 1} for {angular} deg/s"


def ramp_window(lin: np.ndarray, ang: np.ndarray, dt: float) -> int:
    """The commands of the first speeding up and its turn to braking: RAMP_S, or up to 0.05 s past the
    first fall of the linear or the angular speed from its peak so far, whichever is later."""
    def first_fall(v: np.ndarray) -> int:
        peak = np.maximum.accumulate(v)
        falls = np.flatnonzero(v < peak - 0.005 * np.max(peak, initial=0.0))
        return int(falls[0]) if len(falls) else len(v)
    return max(int(RAMP_S / dt), min(first_fall(lin), first_fall(ang)) + int(0.05 / dt))


def assert_finish_straight(run: Run) -> None:
    """The last millimetres' joint move (``ServoCycle._finish_pose``) runs on the straight joint line from
    where the IK left the arm to the goal, every joint monotone: no joint goes out and back.

    Allowed: float32's rounding of the joints sent (half a spacing each, at the start, the end and the
    point), nothing else."""
    q = run.joints[run.ik_cycles:]
    if len(q) < 3:
        return
    h = np.spacing(np.float32(np.max(np.abs(q)))).astype(float) / 2.0
    d = q - q[0]
    step = np.diff(q, axis=0)
    net = np.sign(q[-1] - q[0])
    back = np.max(-step * np.where(net == 0.0, 1.0, net), axis=0)  # the most a joint stepped back
    back[net == 0.0] = np.max(np.abs(d[:, net == 0.0]), axis=0) if (net == 0.0).any() else 0.0
    j = int(np.argmax(back))
    assert back[j] <= 2.0 * h, f"J{j + 1} went {back[j]:.2e} deg against its way in the finish"
    u = d[-1] / np.linalg.norm(d[-1])
    off = np.linalg.norm(d - np.outer(d @ u, u), axis=1)
    assert off.max() <= 3.0 * np.sqrt(q.shape[1]) * h, f"{off.max():.2e} deg off the joint line in the finish"


@pytest.mark.parametrize(("offset", "linear", "angular", "tool"), [
    # Old code: 2.93 x the angular speed (14.7 deg/s) and J1, J4 out by 0.15 deg and back, the move to the
    # goal curved by ruckig's time synchronisation from the IK's motion, ~1e-5 off the joint line.
    ([50.0, 0.0, 0.0, 0.0, 10.0, 0.0], 100.0, 5.0, 200.0),
    # Old code: 1.24 x (1.85 deg/s for 1.5) with a 1.5 m tool.
    ([0.0, 0.0, 0.0, 10.0, 0.0, 0.0], 40.0, 1.5, 1500.0),
])
def test_the_finish_keeps_the_speeds_on_a_straight_joint_line(offset: list[float], linear: float, angular: float,
                                                               tool: float) -> None:
    got = pose_run(offset, linear, angular, tool=(0.0, 0.0, tool, 0.0, 0.0, 0.0))
    assert got is not None and got.arrived
    assert_within(got.lin, got.ang, linear, angular)
    assert_finish_straight(got)


@pytest.mark.parametrize("dt", [0.008, 0.004])
def test_a_40_mm_s_target_that_ran_at_64_mm_s(dt: float) -> None:
    got = pose_run([100.0, 0.0, 0.0, 0.0, 0.0, 0.0], 40.0, 30.0, dt)
    assert got is not None
    lin, ang, ik_cycles, arrived, _ = got
    assert arrived
    assert_within(lin, ang, 40.0, 30.0)  # all of it, its last millimetres' joint move too
    # Still the same approach: at its speed within 0.2 s, the IK driving it to within the last 2 mm
    # (2.5 s at 40 mm/s, plus its start and braking).
    assert lin[int(0.2 / dt)] >= 40.0 * 0.99
    assert ik_cycles * dt < 2.5 + 0.3


def test_a_turn_and_a_move_together_keep_both_speeds() -> None:
    # Old code: 44.5 mm/s for 40 (the translation's share of the pull-back), the turn at 29 of 30 deg/s.
    got = pose_run([30.0, 0.0, 0.0, 0.0, 0.0, 20.0], 40.0, 30.0)
    assert got is not None
    lin, ang, _, arrived, _ = got
    assert arrived
    assert_within(lin, ang, 40.0, 30.0)


def test_a_long_tool_keeps_both_speeds_near_a_singularity() -> None:
    # A 1.5 m tool: the straight TCP line takes the flange past J1's axis (J1 turns 139 deg), J1 and J6
    # counter-rotating at 240 deg/s for 120 mm/s at the TCP; the line's joint direction turned faster than
    # the acceleration let the IK follow it at full speed. Old code: off the line (blend, QP, every joint
    # braking on its own) the TCP ran at 699 mm/s (3.2 x) and turned at 39 deg/s (2.2 x).
    got = pose_run([-97.8, 80.3, 131.3, 1.5, -19.6, -17.4], 219.5, 17.7, 0.004, (0.0, 0.0, 1500.0, 0.0, 0.0, 0.0))
    assert got is not None and got.arrived
    assert_within(got.lin, got.ang, 219.5, 17.7, ramp=int(RAMP_S / 0.004))
    assert_finish_straight(got)


@pytest.mark.parametrize(("offset", "linear", "angular", "dt", "tool"), [
    # Old code: 7.23 deg/s for 6.9 (+4.8 %) at 8 ms ...
    ([55.8, -150.0, -150.0, 7.4, -20.0, 1.4], 500.0, 6.9, 0.008, None),
    # ... 57.84 mm/s for 56 (+3.3 %) with a 200 mm tool (57.64 at 4 ms) ...
    ([0.0, 131.0, 0.0, -11.6, -0.8, -1.8], 56.0, 5.7, 0.008, 200.0),
    ([0.0, 131.0, 0.0, -11.6, -0.8, -1.8], 56.0, 5.7, 0.004, 200.0),
    # ... 40.81 mm/s for 40 (+2.0 %) at 4 ms, 40.64 at 8 ms.
    ([100.0, 0.0, 0.0, 0.0, 12.5, 0.0], 40.0, 5.0, 0.004, 200.0),
    ([100.0, 0.0, 0.0, 0.0, 12.5, 0.0], 40.0, 5.0, 0.008, 200.0),
])
def test_the_shaper_s_ramp_keeps_the_speeds(offset: list[float], linear: float, angular: float, dt: float,
                                              tool: float | None) -> None:
    # The IK's target moves a little every cycle of the shaper's jerk-limited ramp; ruckig's time
    # synchronisation then stretched an axis with little to change over the slowest one's time (J3 stalled
    # at 0.3 of its target while J2 reached it), and the TCP, joint motions that partly cancel, ran over.
    got = pose_run(offset, linear, angular, dt, None if tool is None else (0.0, 0.0, tool, 0.0, 0.0, 0.0))
    assert got is not None and got.arrived
    assert_within(got.lin, got.ang, linear, angular, ramp=int(RAMP_S / dt))


def test_the_turn_to_braking_of_a_short_move_keeps_its_angular_speed() -> None:
    # Found by the property test. Old code: 43.906 deg/s for 43 at command 69 (4 ms; 8 ms: 43.002): where
    # the shaper's acceleration turned against the change it left its velocity-share limits, J5 ended its
    # acceleration ~7 ms after J3 (their jerk limits), and J2, J3, J5 partly cancelling turned the TCP
    # over. Now every joint ends its acceleration in the same time (43.295 deg/s).
    got = pose_run([59.0, 0.0, -90.0, 0.0, -14.25, 0.0], 326.0, 43.0, 0.004, (0.0, 0.0, 200.0, 0.0, 0.0, 0.0))
    assert got is not None and got.arrived
    assert_within(got.lin, got.ang, 326.0, 43.0, ramp=int(RAMP_S / 0.004))


offsets = st.tuples(*[st.floats(-150.0, 150.0)] * 3, *[st.floats(-20.0, 20.0)] * 3)


@settings(max_examples=30, deadline=None)
@given(offsets, st.floats(20.0, 500.0), st.floats(5.0, 90.0), st.sampled_from([0.008, 0.004]),
       st.sampled_from([None, (0.0, 0.0, 200.0, 0.0, 0.0, 0.0)]))
def test_a_pose_target_never_commands_the_tcp_faster_than_asked(offset: tuple[float, ...], linear: float,
                                                                angular: float, dt: float,
                                                                tool: tuple[float, ...] | None) -> None:
    got = pose_run(list(offset), linear, angular, dt, tool)
    if got is None:
        return
    # All the commands: the IK's (a target it cannot reach is approached as far as it can) and the last
    # millimetres' joint move after them (ServoCycle._finish_pose's). Old code: the finish at up to 2.9 x
    # the angular speed, 2.1 x the linear one, joints out and back.
    assert_within(got.lin, got.ang, linear, angular, ramp=ramp_window(got.lin, got.ang, dt),
                  ramp_rel=RANDOM_RAMP_REL)
    if got.arrived:
        assert_finish_straight(got)
