"""Trajectory timing and replay (servo_app.motion.trajectory, ServoCycle's replay mode): pure, no I/O.

The planned samples must pass the controller's own check (ControllerLimitChecker) and end at rest at
the last waypoint; the servo cycle must send exactly them, pause along the path and resume to the end.
"""

from __future__ import annotations

import itertools
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from servo_app.errors import CommandRejected
from servo_app.fanuc.packets import Status
from servo_app.motion.checker import ControllerLimitChecker, check_trajectory
from servo_app.motion.limit_tables import default_tables
from servo_app.motion.servo import ServoCycle
from servo_app.motion.trajectory import (
    DONE,
    MAX_SAMPLES,
    PAUSED,
    TrajectoryPlanner,
    TrajectoryRefused,
    first_violation,
    flange_speeds,
    ramp_positions,
    warp_positions,
)
from servo_app.robots.conventions import fanuc_deg_to_model_rad, matrix_to_xyzwpr
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile

PROFILE = load_profile("lrmate200id")
TABLES = default_tables(PROFILE)
DT = PROFILE.interval_s
HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])  # wrist bent: away from every configuration boundary


def planner(q_now: np.ndarray = HOME, **kw: float) -> TrajectoryPlanner:
    return TrajectoryPlanner.for_stream(PROFILE, DT, TABLES, q_now, **kw)  # type: ignore[arg-type]


def controller_alarms(samples: np.ndarray) -> list[str]:
    kin = ArmKinematics(PROFILE)
    checker = ControllerLimitChecker.for_profile(PROFILE, kin.flange_xyz_mm_fanuc_deg)
    checker.reset(samples[0])
    return [f"{v.code} J{v.axis} at {v.seq}" for v in check_trajectory(checker, samples) if not v.warning]


def distance_to_polyline(point: np.ndarray, line: np.ndarray) -> float:
    """Distance (deg) from a joint vector to the polyline through the samples."""
    a, b = line[:-1], line[1:]
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", point - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * d - point, axis=1)))


def streaming_cycle(q0: np.ndarray = HOME) -> ServoCycle:
    cycle = ServoCycle(PROFILE, DT)
    cycle.begin(q0, None)
    cycle.next_command(Status(seq=1))  # the stream's first command: the rest position
    return cycle


joint_offsets = st.lists(st.floats(-25.0, 25.0, allow_nan=False), min_size=6, max_size=6)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(joint_offsets, min_size=1, max_size=3))
def test_random_joint_paths_pass_the_controller_check_and_end_at_rest_at_the_last_waypoint(
        offsets: list[list[float]]) -> None:
    assume(np.abs(np.array(offsets)).max() > 0.1)  # a path that does not move is refused (nothing to do)
    waypoints = HOME + np.array(offsets)
    p = planner()
    traj = p.plan(p.joint_segments(HOME, waypoints, None))
    q = traj.samples
    assert np.array_equal(q[0], HOME)
    assert np.allclose(q[-1], waypoints[-1], atol=1e-4)
    assert np.array_equal(q[-1], q[-2]) and np.array_equal(q[-2], q[-3]), "ends at rest"
    assert controller_alarms(q) == []
    assert first_violation(q, p.limits.envelope, DT) == -1


def test_a_dense_path_that_turns_back_is_replayed_through_its_rows() -> None:
    t = np.linspace(0.0, 1.0, 400)[:, None]
    rows = HOME + np.hstack([30.0 * np.sin(2 * np.pi * t), 10.0 * t, np.zeros((400, 4))])
    p = planner()
    traj = p.plan(p.dense_segments(HOME, rows, "rows"))
    assert controller_alarms(traj.samples) == []
    # every row lies on the played path (within the spline's fit of the thinned rows)
    assert max(distance_to_polyline(r, traj.samples) for r in rows[::10]) < 0.05


def _recording(amplitude: np.ndarray, moving_s: float, rests: tuple[int, int, int]) -> np.ndarray:
    """Rows one per interval, as a session log records a hand-guided stretch: ``rests`` intervals at
    rest before, halfway and after a smooth motion by ``amplitude`` over ``moving_s``."""
    t = np.arange(0.0, moving_s + 1e-9, DT)
    rows = HOME + np.outer(0.5 - 0.5 * np.cos(np.pi * t / moving_s), amplitude)
    mid = len(rows) // 2
    return np.vstack([np.repeat(rows[:1], rests[0], axis=0), rows[:mid], np.repeat(rows[mid:mid + 1], rests[1], axis=0),
                      rows[mid:], np.repeat(rows[-1:], rests[2], axis=0)])


def joint_speed_peaks(q: np.ndarray) -> np.ndarray:
    return np.abs(np.diff(q, axis=0)).max(axis=0) / DT


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(joint_offsets, st.floats(0.8, 4.0), st.tuples(*[st.integers(0, 300)] * 3))
def test_a_recording_replays_no_faster_than_it_was_recorded(offsets: list[float], moving_s: float,
                                                             rests: tuple[int, int, int]) -> None:
    """A recorded stretch is replayed at its own pace (a hand-guided path at 15 deg/s was replayed at 59
    deg/s when timed by the limits alone); its rests are not replayed as a creep; the limits hold."""
    amplitude = np.array(offsets)
    assume(np.abs(amplitude).max() > 1.0)
    rows = _recording(amplitude, moving_s, rests)
    p = planner()
    traj = p.plan(p.dense_segments(HOME, rows, "rows"))
    # The samples are float32 (as the controller takes them): a speed by finite difference is known to one
    # float32 step per interval (7.6e-6 deg at 90 deg, ~0.001 deg/s at 8 ms), which a joint that barely
    # moves shows (J5 at -90 deg: 0.0067 against 0.0061 deg/s recorded).
    resolution = np.spacing(np.abs(traj.samples).max(axis=0).astype(np.float32)).astype(float) / DT
    assert np.all(joint_speed_peaks(traj.samples) <= joint_speed_peaks(rows) * 1.03 + resolution)
    assert traj.duration_s < moving_s * 1.5 + 0.5, "rests are skipped, the motion is not crept"
    assert controller_alarms(traj.samples) == []
    assert np.allclose(traj.samples[-1], rows[-1], atol=1e-4)
    fastest = p.plan(p.dense_segments(HOME, rows, "rows", recorded_pace=False))
    assert fastest.duration_s <= traj.duration_s + DT


def test_dense_flange_poses_are_one_path_not_a_stop_at_every_row() -> None:
    """A CSV of X Y Z W P R rows (the flange, as ``servo-app check`` reads them) is timed as one dense
    path: it lasts about as long as it was recorded, without stopping at each of its 200 rows."""
    kin = ArmKinematics(PROFILE)
    rows = _recording(np.array([20.0, 5.0, -5.0, 10.0, 10.0, 15.0]), 1.6, (0, 0, 0))
    poses = np.array([matrix_to_xyzwpr(kin.fk_fanuc_deg(q)) for q in rows])
    p = planner()
    traj = p.plan(p.dense_pose_segments(HOME, poses, "csv"))
    assert traj.duration_s < 1.6 * 1.5 + 0.5
    speeds = np.abs(np.diff(traj.samples, axis=0)).max(axis=1)
    assert np.count_nonzero(speeds[5:-5] == 0.0) < 5, "no rest between the rows"
    assert controller_alarms(traj.samples) == []
    assert np.allclose(traj.samples[-1], rows[-1], atol=1e-3)


def test_cartesian_waypoints_keep_the_tcp_on_the_straight_segment() -> None:
    kin = ArmKinematics(PROFILE)
    x0 = matrix_to_xyzwpr(kin.fk_fanuc_deg(HOME))
    poses = np.array([x0, x0 + np.array([80.0, -40.0, 60.0, 0.0, 0.0, 15.0])])
    p = planner()
    segs, _ = p.cartesian_segments(HOME, poses, None)
    traj = p.plan(segs)
    assert controller_alarms(traj.samples) == []
    xyz = np.array([kin.fk_fanuc_deg(q)[:3, 3] * 1000.0 for q in traj.samples])
    a, b = poses[0][:3], poses[1][:3]
    u = (b - a) / np.linalg.norm(b - a)
    off = (xyz - a) - np.outer((xyz - a) @ u, u)
    assert np.linalg.norm(off, axis=1).max() < 1.0
    assert np.allclose(xyz[-1], b, atol=1e-2)


@pytest.mark.parametrize("apart", [0.0, 3.6e-211, 1e-9, 9e-7])
def test_a_repeated_waypoint_is_one_point_the_path_stays_at(apart: float) -> None:
    # Measured on the old code: waypoints 3.6e-211 deg apart on a joint at 0 (hypothesis' find) made the
    # spline's knots equal (scipy: "`x` must be strictly increasing"), 1e-9 deg apart left TOPP-RA no
    # timing (refused); and so a Cartesian pose repeated 1e-9 mm apart.
    step = np.array([0.0, 0.0, 0.0, 0.0, 0.0, apart])
    waypoints = HOME + np.array([[0.0, 5.0, 0.0, 0.0, 0.0, 0.0], [0.0, 5.0, 0.0, 0.0, 0.0, 0.0],
                                 [0.0, 0.0, 0.0, 0.0, 0.0, 10.0], [0.0, 0.0, 0.0, 0.0, 0.0, 10.0]])
    waypoints[1] += step
    waypoints[3] += step
    for times in (None, [0.5, 1.5, 2.5, 3.0]):
        p = planner()
        traj = p.plan(p.joint_segments(HOME, waypoints, times))
        q = traj.samples
        assert np.allclose(q[-1], waypoints[-1], atol=1e-4)
        assert np.array_equal(q[-1], q[-2]) and np.array_equal(q[-2], q[-3]), "ends at rest"
        assert controller_alarms(q) == []
        assert first_violation(q, p.limits.envelope, DT) == -1
        if times is not None:  # the repeated waypoint is held for its time
            assert traj.duration_s >= 2.5
    x0 = matrix_to_xyzwpr(ArmKinematics(PROFILE).fk_fanuc_deg(HOME))
    poses = x0 + np.array([[20.0, 0.0, 0.0, 0.0, 0.0, 0.0], [20.0 + apart, 0.0, 0.0, 0.0, 0.0, 0.0],
                           [40.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    p = planner()
    segs, _ = p.cartesian_segments(HOME, poses, None)
    assert controller_alarms(p.plan(segs).samples) == []


def test_times_are_honoured_when_feasible_and_refused_when_not() -> None:
    p = planner()
    w = np.array([HOME, HOME + np.array([20.0, 0, 0, 0, 0, 0])])
    slow = p.plan(p.joint_segments(HOME, w, [0.0, 3.0]))
    assert abs(slow.duration_s - 3.0) < 0.05
    with pytest.raises(TrajectoryRefused, match="times"):
        p.plan(p.joint_segments(HOME, w, [0.0, 0.05]))


def test_a_plan_the_servo_process_could_not_take_between_two_statuses_is_refused() -> None:
    """790 s at 4 ms (197 504 samples) was planned, and the servo process taking it whole between two
    statuses held the cycle up long enough for MOTN-603; over MAX_SAMPLES is refused, saying to split."""
    p = TrajectoryPlanner.for_stream(PROFILE, 0.004, TABLES, HOME)  # type: ignore[arg-type]
    w = np.array([HOME, HOME + np.array([90.0, 0, 0, 0, 0, 0])])
    with pytest.raises(TrajectoryRefused, match="would last over 400 s: split it"):
        p.plan(p.joint_segments(HOME, w, [0.0, 790.0]))
    assert len(p.plan(p.joint_segments(HOME, w, [0.0, 390.0])).samples) <= MAX_SAMPLES


def test_a_waypoint_out_of_range_is_refused_by_index() -> None:
    p = planner()
    with pytest.raises(TrajectoryRefused, match=r"joints\[1\]"):
        p.joint_segments(HOME, np.array([HOME, HOME + np.array([0, 0, 0, 0, 0, 500.0])]), None)


def test_warp_is_the_sample_on_whole_indices_and_ramps_land_on_samples() -> None:
    q = np.cumsum(np.random.default_rng(1).normal(size=(50, 6)), axis=0)
    assert np.array_equal(warp_positions(q, np.arange(50.0)), q)
    down = ramp_positions(q, 10, 9, up=False)
    assert np.array_equal(down[-1], q[14].astype(np.float32).astype(float))  # (9 - 1) / 2 samples
    up = ramp_positions(q, 14, 9, up=True)
    assert np.array_equal(up[-1], q[19].astype(np.float32).astype(float))  # (9 + 1) / 2 samples


def test_servo_cycle_replays_the_samples_exactly_and_holds_the_end() -> None:
    p = planner()
    traj = p.plan(p.joint_segments(HOME, np.array([HOME + np.array([15.0, -5.0, 5.0, 10.0, 5.0, -20.0])]), None))
    cycle = streaming_cycle()
    cycle.replay(cycle.check_replay(traj.samples), traj.ramp_steps)
    sent = [cycle.next_command(Status(seq=1)) for _ in range(len(traj.samples) + 10)]
    assert np.array_equal(np.array(sent[: len(traj.samples) - 1]), traj.samples[1:])
    assert cycle.replay_player is not None and cycle.replay_player.state == DONE
    assert cycle.at_rest() and np.array_equal(sent[-1], traj.samples[-1])
    assert controller_alarms(np.vstack([traj.samples[:1], sent])) == []


def test_a_soft_stop_pauses_on_the_path_and_resume_finishes_it() -> None:
    p = planner()
    goal = HOME + np.array([30.0, 10.0, -10.0, 0.0, 0.0, 0.0])
    traj = p.plan(p.joint_segments(HOME, np.array([goal]), None))
    cycle = streaming_cycle()
    cycle.replay(cycle.check_replay(traj.samples), traj.ramp_steps)
    sent = [cycle.next_command(Status(seq=1)) for _ in range(len(traj.samples) // 2)]
    cycle.stop(fast=False)
    while not cycle.at_rest():
        sent.append(cycle.next_command(Status(seq=1)))
        assert len(sent) < 2 * len(traj.samples)
    player = cycle.replay_player
    assert player is not None and player.state == PAUSED
    rest = sent[-1]
    # at rest on the planned path: one of the samples (the ramps end on whole samples)
    assert np.min(np.abs(traj.samples - rest).max(axis=1)) == 0.0
    cycle.resume()
    for _ in range(len(traj.samples) + traj.ramp_steps + 10):
        sent.append(cycle.next_command(Status(seq=1)))
    assert player.state == DONE and cycle.at_rest()
    assert np.array_equal(sent[-1], traj.samples[-1])
    assert controller_alarms(np.vstack([traj.samples[:1], sent])) == []


def test_a_fast_stop_or_another_command_leaves_the_replay_with_coherent_motion() -> None:
    p = planner()
    traj = p.plan(p.joint_segments(HOME, np.array([HOME + np.array([30.0, 0, 0, 0, 0, 0])]), None))
    cycle = streaming_cycle()
    cycle.replay(cycle.check_replay(traj.samples), traj.ramp_steps)
    sent = [cycle.next_command(Status(seq=1)) for _ in range(len(traj.samples) // 2)]
    cycle.stop(fast=True)
    assert cycle.replay_player is not None and not cycle.replay_player.active
    while not cycle.at_rest():
        sent.append(cycle.next_command(Status(seq=1)))
    assert controller_alarms(np.vstack([traj.samples[:1], sent])) == []


def test_replay_refuses_samples_that_do_not_start_at_rest_here() -> None:
    p = planner()
    traj = p.plan(p.joint_segments(HOME, np.array([HOME + np.array([10.0, 0, 0, 0, 0, 0])]), None))
    cycle = streaming_cycle(HOME + np.array([1.0, 0, 0, 0, 0, 0]))
    assert "moved since the plan" in cycle.replay_start_mismatch(traj.samples)
    nan = traj.samples.copy()
    nan[7, 2] = np.nan
    with pytest.raises(CommandRejected, match=r"joints\[7\]\[2\]=nan"):
        streaming_cycle().check_replay(nan)


def test_replay_refuses_a_value_float32_cannot_hold_and_takes_the_plan_as_float32_values() -> None:
    """A value past float32's range would go on the wire as inf: refused at once, naming the value as
    sent (it used to pass, and only the cycle's guard stopped the replay at that sample). A float64
    plan is taken as its float32 values, the same as the float32 plan the service sends."""
    p = planner()
    traj = p.plan(p.joint_segments(HOME, np.array([HOME + np.array([10.0, 0, 0, 0, 0, 0])]), None))
    big = traj.samples.astype(np.float64)
    big[9, 4] = 1e39
    with pytest.raises(CommandRejected, match=r"joints\[9\]\[4\]=1e\+39 is not a finite number"):
        streaming_cycle().check_replay(big)
    cycle = streaming_cycle()
    as32 = cycle.check_replay(traj.samples.astype(np.float32))
    assert as32.dtype == np.float64
    assert np.array_equal(as32, cycle.check_replay(traj.samples.astype(np.float64)))
    assert np.array_equal(as32, traj.samples.astype(np.float32).astype(np.float64))
    with pytest.raises(CommandRejected, match="expected numbers"):
        cycle.check_replay(np.full((3, 6), "x"))


@pytest.mark.parametrize("defect", ["jump", "out of range"])
def test_a_bad_sample_is_not_sent_the_replay_ends_and_the_arm_stops_within_the_limits(defect: str) -> None:
    p = planner()
    traj = p.plan(p.joint_segments(HOME, np.array([HOME + np.array([30.0, 0, 0, 0, 0, 0])]), None))
    bad = traj.samples.copy()
    k = len(bad) // 2
    if defect == "jump":
        bad[k] += 1.0  # a step the controller would alarm on
    else:
        bad[k:, 5] = 400.0  # J6 beyond its range
    cycle = streaming_cycle()
    cycle.replay(cycle.check_replay(bad), traj.ramp_steps)
    sent = [cycle.next_command(Status(seq=1)) for _ in range(k + 1)]
    assert cycle.replay_player is not None and not cycle.replay_player.active
    assert cycle.replay_error
    while not cycle.at_rest():
        sent.append(cycle.next_command(Status(seq=1)))
        assert len(sent) < 4 * len(bad)
    assert controller_alarms(np.vstack([traj.samples[:1], sent])) == []


def test_the_vectorised_flange_speed_is_the_checker_s() -> None:
    from servo_app.motion.trajectory import flange_speeds

    kin = ArmKinematics(PROFILE)
    q = HOME + np.cumsum(np.random.default_rng(2).normal(scale=0.5, size=(40, 6)), axis=0)
    one_by_one = [np.linalg.norm(kin.flange_xyz_mm_fanuc_deg(b) - kin.flange_xyz_mm_fanuc_deg(a)) / DT
                  for a, b in itertools.pairwise(q)]
    assert np.allclose(flange_speeds(kin, q, DT), one_by_one, rtol=1e-12, atol=1e-9)


def test_a_wild_joint_target_is_refused_in_a_short_message() -> None:
    """1e300 deg (a value sent in the wrong units) is named in a few characters, not 300 digits twice."""
    with pytest.raises(CommandRejected, match=r"joints\[5\]=1e\+300 deg \(J6 = 1e\+300 deg") as refused:
        streaming_cycle().check_joint_target(HOME + np.array([0, 0, 0, 0, 0, 1e300]))
    assert len(str(refused.value)) < 200, str(refused.value)


def test_a_tool_change_while_a_trajectory_is_paused_ends_it_saying_why() -> None:
    """Paused by a soft stop, at rest: a tool change is taken (the arm is still), and the plan, made for
    the old TCP and payload, is ended with the reason, so a resume does not trace the old TCP's path
    (before, resume went on with it)."""
    p = planner()
    traj = p.plan(p.joint_segments(HOME, np.array([HOME + np.array([30.0, 0, 0, 0, 0, 0])]), None))
    cycle = streaming_cycle()
    cycle.replay(cycle.check_replay(traj.samples), traj.ramp_steps)
    for _ in range(len(traj.samples) // 3):
        cycle.next_command(Status(seq=1))
    cycle.stop()
    while not cycle.at_rest():
        cycle.next_command(Status(seq=1))
    player = cycle.replay_player
    assert player is not None and player.active  # paused
    cycle.set_tool((0.0, 0.0, 150.0, 0.0, 0.0, 0.0), 1.0)
    assert not player.active and "tool change" in cycle.replay_error
    cycle.resume()
    rest = cycle.next_command(Status(seq=1)).copy()
    for _ in range(50):
        np.testing.assert_array_equal(cycle.next_command(Status(seq=1)), rest)


# A pick-and-place through via points (measured: 2.192 s at rest at each, 1.288 s blended).
VIA = HOME + np.array([[20.0, 10.0, -10.0, 0.0, 10.0, 30.0], [40.0, 20.0, 0.0, 10.0, 0.0, 0.0],
                       [20.0, 30.0, 10.0, 0.0, -10.0, -30.0], [0.0, 10.0, 0.0, 0.0, 0.0, 0.0]])


def assert_within_every_limit(p: TrajectoryPlanner, q: np.ndarray) -> None:
    """Every check the plan must pass: the servo's float32 guard, the controller's, the flange-speed
    cap, the joint ranges and the held configuration; ends at rest."""
    assert first_violation(q, p.limits.envelope, DT) == -1
    assert controller_alarms(q) == []
    assert flange_speeds(p.flange_kin, q, DT).max() <= p.limits.flange_speed_max
    assert p.region.contains(fanuc_deg_to_model_rad(q, PROFILE.j23_factor)).all()
    assert np.array_equal(q[-1], q[-2]) and np.array_equal(q[-2], q[-3]), "ends at rest"


def test_blended_waypoints_are_passed_through_without_stopping() -> None:
    p = planner()
    stops = p.plan(p.joint_segments(HOME, VIA, None))
    traj = p.plan(p.joint_segments(HOME, VIA, None, blend=True))
    q = traj.samples
    assert_within_every_limit(p, q)
    assert np.array_equal(q[0], HOME) and np.allclose(q[-1], VIA[-1], atol=1e-4)
    speed = np.abs(np.diff(q, axis=0)).max(axis=1) / DT  # the fastest joint's, deg/s
    for w in VIA[:-1]:  # every waypoint on the path, passed at speed (the rest-to-rest plan stops there)
        assert distance_to_polyline(w, q) < 0.05
        k = int(np.argmin(np.linalg.norm(q - w, axis=1)))
        assert speed[k - 1: k + 1].min() > 50.0, (w, speed[k - 1: k + 1])
        k = int(np.argmin(np.linalg.norm(stops.samples - w, axis=1)))
        assert np.abs(stops.samples[k + 1] - stops.samples[k]).max() / DT < 0.5
    assert traj.duration_s < 0.7 * stops.duration_s, (traj.duration_s, stops.duration_s)


def test_blend_from_elsewhere_passes_through_the_first_waypoint_too_and_a_repeat_is_one_point() -> None:
    p = planner()
    start = HOME + np.array([-10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    w = np.array([HOME, HOME, VIA[0], VIA[1]])  # (the repeat of HOME: one knot)
    q = p.plan(p.joint_segments(start, w, None, blend=True)).samples
    assert_within_every_limit(p, q)
    assert np.array_equal(q[0], start)
    k = int(np.argmin(np.linalg.norm(q - HOME, axis=1)))
    assert distance_to_polyline(HOME, q) < 0.05 and np.abs(q[k + 1] - q[k]).max() / DT > 20.0


def test_a_blended_spline_that_overshoots_the_joint_range_is_refused_naming_the_waypoints() -> None:
    """J5 to within 1 deg of its range (FANUC -125 deg: -124.5 with the margin) and back: the spline
    turns past the waypoint, outside the range; straight segments stay inside."""
    p = planner()
    lo = PROFILE.joint_min_deg[4] + 1.0
    w = np.array([[20.0, 0.0, 0.0, 0.0, -90.0, 0.0], [20.0, 0.0, 0.0, 0.0, lo, 0.0], [40.0, 0.0, 0.0, 0.0, -90.0, 0.0]])
    with pytest.raises(TrajectoryRefused, match=r"blend: the spline from joints\[1\] to joints\[2\] overshoots.*J5=.*"
                                                r"add a waypoint between them, or send blend=false"):
        p.joint_segments(HOME, w, None, blend=True)
    assert_within_every_limit(p, p.plan(p.joint_segments(HOME, w, None)).samples)


def test_blend_with_times_is_refused_saying_what_to_do() -> None:
    p = planner()
    with pytest.raises(TrajectoryRefused, match=r"times: not with blend.*drop times, or send blend=false"):
        p.joint_segments(HOME, VIA, [0.0, 1.0, 2.0, 3.0], blend=True)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.lists(st.floats(-70.0, 70.0), min_size=6, max_size=6), min_size=2, max_size=5))
def test_random_blended_waypoints_are_planned_within_every_limit_or_refused_with_a_reason(
        offsets: list[list[float]]) -> None:
    """Waypoints up to 70 deg from HOME on every joint, within the joint ranges (inside their 0.5 deg
    margin): the plan passes every check, or it is refused naming why (a waypoint in another
    configuration, the spline leaving the range)."""
    lo, hi = np.array(PROFILE.joint_min_deg) + 0.5, np.array(PROFILE.joint_max_deg) - 0.5
    w = np.clip(HOME + np.array(offsets), lo, hi)
    p = planner()
    try:
        traj = p.plan(p.joint_segments(HOME, w, None, blend=True))
    except TrajectoryRefused as exc:
        assert re.search(r"joints\[\d+\]|blend|no timing|nothing to do", str(exc)), str(exc)
        return
    assert_within_every_limit(p, traj.samples)
    assert np.allclose(traj.samples[-1], w[-1], atol=1e-4)
    for x in w:
        assert distance_to_polyline(x, traj.samples) < 0.05


@pytest.mark.parametrize("gap", [2e-6, 1e-3, 0.2])
def test_a_blend_through_two_near_coincident_waypoints_is_refused_naming_both(gap: float) -> None:
    """Two consecutive waypoints closer than BLEND_MIN_CHORD_DEG (above COINCIDENT_DEG's "same point"):
    the spline would turn on the spot between them (planned, it took up to 5.3 s, or no timing was
    found): refused naming both and what to do; the same path stopping at each is planned."""
    p = planner()
    w = np.insert(VIA, 2, VIA[1] + np.array([gap, 0.0, 0.0, 0.0, 0.0, 0.0]), axis=0)
    with pytest.raises(TrajectoryRefused, match=rf"blend: joints\[1\] and joints\[2\] are {gap:.3g} deg apart, "
                                                r"closer than 0.25 deg .*; send them as one waypoint, or send "
                                                r"blend=false"):
        p.joint_segments(HOME, w, None, blend=True)
    assert_within_every_limit(p, p.plan(p.joint_segments(HOME, w, None)).samples)
    # From where the arm rests to a first waypoint as close: drop it (one knot pair: a straight line is kept).
    w = np.vstack([HOME + np.array([0.0, gap, 0.0, 0.0, 0.0, 0.0]), VIA])
    with pytest.raises(TrajectoryRefused, match=r"blend: the start \(where the arm rests\) and joints\[0\] are .*"
                                                r"drop joints\[0\], or send blend=false"):
        p.joint_segments(HOME, w, None, blend=True)
    q = p.plan(p.joint_segments(HOME, w[:1], None, blend=True)).samples
    assert np.allclose(q[-1], w[0], atol=1e-4)


def test_a_blend_with_waypoints_just_over_the_near_distance_is_planned() -> None:
    p = planner()
    w = np.insert(VIA, 2, VIA[1] + np.array([0.26, 0.0, 0.0, 0.0, 0.0, 0.0]), axis=0)
    assert_within_every_limit(p, p.plan(p.joint_segments(HOME, w, None, blend=True)).samples)
