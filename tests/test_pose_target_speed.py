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
# While the jerk-limited shaper ramps up (its first 0.2 s), the joints lag unevenly, and pulling the
# TCP back across its line adds to its speed: up to +9 % measured, at 5 deg/s turning while 40 mm/s
# moving (+0.8 % with the pull-back off; a twist jog's test allows 3 %). The old code's +27 % and
# +60 % were there too.
RAMP_S, RAMP_REL = 0.2, 0.15


def pose_run(offset: list[float], linear: float, angular: float, dt: float = 0.008,
             tool: tuple[float, ...] | None = None) -> tuple[np.ndarray, np.ndarray, int, bool] | None:
    """A pose target ``offset`` (mm, deg) from the TCP at HOME, run until it is reached (None if refused):
    the TCP speed between consecutive commands sent (mm/s, deg/s), the number of commands the IK drove
    (before the last millimetres' joint move, ``ServoSettings.finish_mm``), and whether it arrived."""
    cycle = ServoCycle(PROFILE, dt, ServoSettings(tool_xyzwpr=tool))
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
    return lin, ang, ik_cycles, arrived


def assert_within(lin: np.ndarray, ang: np.ndarray, linear: float, angular: float, ramp: int = 0) -> None:
    """Every speed within the stated tolerance (the first ``ramp`` of them within RAMP_REL)."""
    rel = np.full(len(lin), REL)
    rel[:ramp] = RAMP_REL
    over_lin = lin - (linear * (1 + rel) + ABS_MM_S)
    over_ang = ang - (angular * (1 + rel) + ABS_DEG_S)
    i, j = int(np.argmax(over_lin)), int(np.argmax(over_ang))
    assert over_lin[i] <= 0.0, f"{lin[i]:.2f} mm/s at command {i + 1} for {linear} mm/s"
    assert over_ang[j] <= 0.0, f"{ang[j]:.3f} deg/s at command {j + 1} for {angular} deg/s"


@pytest.mark.parametrize("dt", [0.008, 0.004])
def test_a_40_mm_s_target_that_ran_at_64_mm_s(dt: float) -> None:
    got = pose_run([100.0, 0.0, 0.0, 0.0, 0.0, 0.0], 40.0, 30.0, dt)
    assert got is not None
    lin, ang, ik_cycles, arrived = got
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
    lin, ang, _, arrived = got
    assert arrived
    assert_within(lin, ang, 40.0, 30.0)


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
    # The commands the IK drove (a target it cannot reach is approached as far as it can); the last
    # millimetres' joint move after them is ServoCycle._finish_pose's, not the IK's.
    lin, ang, ik_cycles, _ = got
    assert_within(lin[:ik_cycles], ang[:ik_cycles], linear, angular, ramp=int(RAMP_S / dt))
