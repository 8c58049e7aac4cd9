"""Cartesian-format commands (data format 0) in the FANUC simulator: conversion to joints in the held
configuration (manual 61.5, 61.7), MOTN-156 / MOTN-018, then the joint-format checks (FAQ).

Paths are built without IK: a straight line with a quintic in distance, or the FK of a joint path.
All values cross float32 on the wire, as on a real controller.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_sim_model import PROFILE, Rig
from test_sim_udp import Client, stream_with_retry

from servo_app.check_cli import Trajectory, cartesian_to_joints
from servo_app.fanuc.alarms import ALARMS
from servo_app.fanuc.packets import Command, StatusStart
from servo_app.robots.conventions import fanuc_deg_to_model_rad, matrix_to_xyzwpr, xyzwpr_to_matrix
from servo_app.robots.kinematics import ArmKinematics
from servo_app.sim.fanuc_model import ControllerConfig
from servo_app.sim.fanuc_server import FanucSimulator

ARM = ArmKinematics(PROFILE)
Q0 = np.array([0.0, 10.0, -10.0, 0.0, -40.0, 0.0])  # N U T, 0, 0, 0
CART = 0


def quintic(t: np.ndarray) -> np.ndarray:
    return t**3 * (10.0 - 15.0 * t + 6.0 * t * t)


def f32(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, dtype=np.float32).astype(float)


def pose(q_deg) -> np.ndarray:
    return matrix_to_xyzwpr(ARM.fk_fanuc_deg(q_deg))


def line(start: np.ndarray, delta, duration_s: float, dt: float = 0.008, hold: int = 10) -> np.ndarray:
    """XYZWPR rows from ``start`` by ``delta`` (mm, deg; small angles, so W P R interpolate linearly)
    with a quintic in distance: zero velocity and acceleration at both ends, bounded jerk; then
    ``hold`` rows at the goal."""
    n = round(duration_s / dt)
    rows = start + quintic(np.arange(n + 1) / n)[:, None] * np.asarray(delta, dtype=float)
    return f32(np.vstack([rows, np.repeat(rows[-1:], hold, axis=0)]))


def joint_path_poses(qa, qb, cycles: int) -> np.ndarray:
    """XYZWPR of a quintic joint move (FK only)."""
    qa, qb = np.asarray(qa, float), np.asarray(qb, float)
    qs = qa + quintic(np.arange(cycles + 1) / cycles)[:, None] * (qb - qa)
    return f32(np.array([pose(q) for q in qs]))


def same_pose(a, b, mm: float = 1e-3, rad: float = 1e-5) -> bool:
    ta, tb = xyzwpr_to_matrix(a), xyzwpr_to_matrix(b)
    return bool(np.allclose(ta[:3, 3] * 1000.0, tb[:3, 3] * 1000.0, atol=mm)
                and np.allclose(ta[:3, :3], tb[:3, :3], atol=rad))


LINE = line(pose(Q0), [150.0, 100.0, -80.0, 0.0, 0.0, 15.0], 1.5)


def test_smooth_cartesian_line_streams_without_alarm_and_the_servo_follows() -> None:
    r = Rig(initial_joints=Q0)
    r.ready()
    r.stream(LINE, data_format=CART)
    assert r.m.events == [], r.lines
    assert r.m.processed_commands == len(LINE)
    goal_q = r.m.command_position[:6]
    assert same_pose(pose(goal_q), LINE[-1])  # the command joints reach the commanded pose
    assert str(ARM.configuration(fanuc_deg_to_model_rad(goal_q, ARM.j23_factor))) == "N U T, 0, 0, 0"
    r.tick(40)  # settle
    st = r.status
    assert np.asarray(st.joints[:6]) == pytest.approx(goal_q, abs=1e-3)
    assert same_pose(st.cartesian[:6], LINE[-1], mm=0.01, rad=1e-4)


def test_status_cartesian_fields_are_the_fk_of_the_servo_joints_not_the_command() -> None:
    r = Rig(initial_joints=Q0)
    r.ready()
    half = len(LINE) // 2
    r.stream(LINE[:half], last=False, data_format=CART)
    st = r.status
    assert r.m.events == []
    # The servo lags the command by ~50 ms: mid-line that is millimetres, yet the status pose is FK(servo).
    assert same_pose(st.cartesian[:6], f32(pose(st.joints[:6])), mm=2e-3, rad=2e-5)
    assert np.linalg.norm(np.asarray(st.cartesian[:3]) - LINE[half - 1][:3]) > 1.0


def test_crossing_j5_zero_flips_the_wrist_motn_156() -> None:
    qa, qb = np.array([0.0, 10.0, -10.0, 0.0, -10.0, 0.0]), np.array([0.0, 10.0, -10.0, 0.0, 12.0, 0.0])
    rows = joint_path_poses(qa, qb, 150)
    r = Rig(initial_joints=qa)
    st = r.ready()
    r.stream(rows, data_format=CART)
    assert r.codes() == ["MOTN-156"], r.lines
    assert r.lines == ["MOTN-156 PM:Configuration changed"]
    ev = r.m.alarms()[0]
    # The command that first needs J5 > 0 (Flip); the arm stopped just before, still No-flip.
    q5 = qa[4] + (qb[4] - qa[4]) * quintic(np.arange(151) / 150)
    assert ev.seq == st.seq + int(np.argmax(q5 > 0.0))
    assert r.m.command_position[4] < 0.0
    assert r.m.cartesian is not None and str(r.m.cartesian.held) == "N U T, 0, 0, 0"


def test_starting_on_the_wrist_singularity_keeps_j4_and_leaves_it_without_alarm() -> None:
    # At J5 = 0 only J4 + J6 is defined: float32 noise alone would pick J4 up to 90 deg away and either
    # sign of J5 (MOTN-617 / MOTN-156 on a still arm). The converter keeps J4 there.
    qa, qb = np.array([10.0, 20.0, -5.0, 30.0, 0.0, -20.0]), np.array([10.0, 20.0, -5.0, 30.0, -20.0, -20.0])
    rows = joint_path_poses(qa, qb, 100)
    r = Rig(initial_joints=qa)
    r.ready()
    r.stream([rows[0]] * 10, last=False, data_format=CART)
    assert r.m.command_position[3] == pytest.approx(30.0, abs=1e-9)
    r.stream(rows, data_format=CART)
    assert r.m.events == [], r.lines
    assert r.m.command_position[:6] == pytest.approx(qb, abs=1e-3)


def test_j6_across_180_changes_its_turn_number_motn_156() -> None:
    qa, qb = np.array([0.0, 10.0, -10.0, 0.0, -40.0, 170.0]), np.array([0.0, 10.0, -10.0, 0.0, -40.0, 190.0])
    r = Rig(initial_joints=qa)
    r.ready()
    r.stream(joint_path_poses(qa, qb, 100), data_format=CART)
    assert r.codes() == ["MOTN-156"]
    assert 175.0 < r.m.command_position[5] <= 180.0


def test_cartesian_pose_beyond_a_joint_range_gets_the_joint_format_range_alarm() -> None:
    qa, qb = np.array([165.0, 10.0, -10.0, 0.0, -40.0, 0.0]), np.array([172.0, 10.0, -10.0, 0.0, -40.0, 0.0])
    r = Rig(initial_joints=qa)
    r.ready()
    r.stream(joint_path_poses(qa, qb, 100), data_format=CART)
    assert r.codes() == ["MOTN-017"]
    assert r.m.alarms()[0].axis == 1


def test_unreachable_pose_motn_018() -> None:
    r = Rig(initial_joints=Q0)
    st = r.ready()
    p0 = f32(pose(Q0))
    r.stream([p0, p0, p0 + np.array([5000.0, 0, 0, 0, 0, 0])], data_format=CART)
    assert r.lines == [f"MOTN-018 Position not reachable (Sq.{st.seq + 2})"]
    assert r.m.processed_commands == 2
    assert ALARMS["MOTN-018"].cause and ALARMS["MOTN-018"].remedy and not ALARMS["MOTN-018"].warning


def test_nan_in_a_cartesian_command_motn_605() -> None:
    r = Rig(initial_joints=Q0)
    st = r.ready()
    bad = pose(Q0)
    bad[4] = math.nan  # P
    r.send(r.cmd(bad, data_format=CART))
    r.tick()
    assert r.lines == [f"MOTN-605 ST:Command is NaN or infinity.(A:5,Sq.{st.seq})"]


def test_first_cartesian_command_far_from_the_current_pose_motn_617() -> None:
    r = Rig(initial_joints=Q0)
    st = r.ready()
    r.send(r.cmd(pose(Q0) + np.array([100.0, 0, 0, 0, 0, 0]), data_format=CART))  # same configuration, 100 mm away
    r.tick()
    assert r.lines == [f"MOTN-617 ST:Discontinous command.(Sq.{st.seq})"]


def test_formats_mix_within_one_stream_each_command_continuing_from_the_last() -> None:
    r = Rig(initial_joints=Q0)
    r.ready()
    r.stream([Q0] * 5, last=False)  # joint format first
    r.stream(LINE, last=False, data_format=CART)
    goal = r.m.command_position[:6]
    r.stream([goal] * 5)  # and joint format again, to the end
    assert r.m.events == [], r.lines
    assert r.m.processed_commands == 10 + len(LINE)


def test_model_without_cartesian_support_still_posts_motn_619() -> None:
    r = Rig(ControllerConfig(cartesian_supported=False), initial_joints=Q0)
    r.ready()
    r.send(r.cmd(pose(Q0), data_format=CART))
    r.tick()
    assert r.lines == ["MOTN-619 ST:Cartesian type is not supported"]


def test_servo_app_check_converts_with_the_same_code_as_the_simulator() -> None:
    r = Rig(initial_joints=Q0)
    r.ready()
    r.stream(LINE, data_format=CART)
    joints, failure = cartesian_to_joints(Trajectory(LINE, "xyzwpr", list(range(1, len(LINE) + 1)), Path("-")),
                                          PROFILE)
    assert failure is None
    assert np.array_equal(joints[-1], r.m.command_position[:6])  # bit for bit: one implementation


@pytest.mark.e2e
def test_cartesian_line_over_udp(lines: list[str]) -> None:
    class CartesianClient(Client):
        def send(self, pkt) -> None:
            super().send(replace(pkt, data_format=CART) if isinstance(pkt, Command) else pkt)

    with FanucSimulator(port=0, initial_joints=Q0, log=lines.append) as sim:
        client = CartesianClient(sim.address)
        try:
            client.send(StatusStart())
            stream_with_retry(sim, client, LINE, ahead=7)
            assert sim.alarms() == [], lines
            st = client.wait_status(lambda s: not s.status & 8 and same_pose(s.cartesian[:6], LINE[-1], mm=0.01,
                                                                              rad=1e-4))
        finally:
            client.close()
        assert same_pose(st.cartesian[:6], f32(pose(st.joints[:6])), mm=2e-3, rad=2e-5)
        assert sim.controller.processed_commands == len(LINE)


@pytest.fixture
def lines() -> list[str]:
    return []
