"""The simulated point job and arm, without sockets: decisions, rejections, move timing, SCARA moves."""

from __future__ import annotations

import argparse
import struct

import numpy as np
import pytest

from servo_app.janome.profile import load_janome_profile
from servo_app.janome.protocol import (
    RECEIVE_BUFFER,
    Arm,
    Cmd,
    ErrorCode,
    RobotKind,
    RobotState,
    Status,
    Target,
    checksum,
)
from servo_app.janome.trapezoid import move_time
from servo_app.sim.janome_pointjob import PointJob, PointJobSettings
from servo_app.sim.janome_robot import JanomeRobot, MovePlan
from servo_app.sim.janome_sim import add_janome_sim_parser

JR = load_janome_profile("jr3000")
JS = load_janome_profile("js3")


def job_after_hello(profile=JR, **kw: object) -> tuple[PointJob, Status]:
    job = PointJob(JanomeRobot(profile, **kw))  # type: ignore[arg-type]
    hello = Status.decode(job.hello())
    return job, hello


def test_hello_carries_version_kind_and_position() -> None:
    _, hello = job_after_hello(JS)
    assert hello.state == RobotState.HELLO and hello.seq == 1 and hello.ack == 0
    assert hello.detail == RobotKind.SCARA and hello.version == 1
    assert hello.xyzr == (200.0, 150.0, 50.0, 0.0) and hello.arm == Arm.RIGHTY


def test_waits_for_a_whole_frame_then_holds() -> None:
    job, hello = job_after_hello()
    frame = Target(seq=1, ack=hello.seq, cmd=Cmd.HOLD).encode()
    job.receive(frame[:30])
    assert job.decide() is None  # inCOM still waiting
    job.receive(frame[30:])
    d = job.decide()
    assert d is not None and d.kind == "hold"
    s = Status.decode(job.status())
    assert s.seq == 2 and s.ack == 1 and s.state == RobotState.READY


def test_line_move_follows_the_trapezoid() -> None:
    job, _hello = job_after_hello()
    t = Target(seq=1, ack=1, cmd=Cmd.LINE, x=160.0, y=160.0, z=50.0, r=0.0, speed=100.0)
    job.receive(t.encode())
    d = job.decide()
    assert d is not None and d.kind == "move" and isinstance(d.plan, MovePlan)
    assert d.plan.duration == pytest.approx(move_time(10.0, 100.0, JR.cp_accel))
    mid = job.robot.at(d.plan, d.plan.duration / 2)
    assert mid[0] == pytest.approx(155.0) and mid[1] == 160.0  # symmetric profile: half way at half time
    job.robot.finish(d.plan)
    assert Status.decode(job.status(move_ms=103)).xyzr == (160.0, 160.0, 50.0, 0.0)


def test_r_only_step_uses_rspeed() -> None:
    job, _ = job_after_hello()
    job.receive(Target(seq=1, ack=1, cmd=Cmd.LINE, x=150.0, y=160.0, z=50.0, r=10.0, rspeed=50.0).encode())
    d = job.decide()
    assert d is not None and d.plan is not None and d.plan.kind == "mono"
    assert d.plan.duration == pytest.approx(move_time(10.0, 50.0, JR.accel[3]))


@pytest.mark.parametrize(("target", "code", "detail"), [
    ({"x": 301.0, "y": 160.0, "z": 50.0}, ErrorCode.OUT_OF_RANGE, 1),
    ({"x": 150.0, "y": 160.0, "z": -1.0}, ErrorCode.OUT_OF_RANGE, 3),
    ({"x": 150.0, "y": 170.0, "z": 50.0, "speed": 0.0}, ErrorCode.BAD_SPEED, 0),
    ({"x": 150.0, "y": 170.0, "z": 50.0, "speed": 5000.0}, ErrorCode.BAD_SPEED, 0),
])
def test_unreachable_targets_are_refused_with_the_axis(target: dict, code: ErrorCode, detail: int) -> None:
    job, _ = job_after_hello()
    job.receive(Target(seq=1, ack=1, cmd=Cmd.LINE, **{"speed": 100.0, **target}).encode())
    d = job.decide()
    assert d is not None and d.kind == "reject" and d.error == code and d.detail == detail
    s = Status.decode(job.reject(d))
    assert s.state == RobotState.ERROR and s.error == code and s.ack == 1  # the frame itself was taken
    assert job.robot.position[0] == 150.0  # did not move


def test_bad_frames_are_rejected_and_the_link_kept() -> None:
    job, _ = job_after_hello()
    good = Target(seq=1, ack=1, cmd=Cmd.HOLD).encode()
    bad = bytearray(good)
    bad[10] ^= 0xFF
    job.receive(bytes(bad))
    d = job.decide()
    assert d is not None and d.error == ErrorCode.BAD_CHECKSUM and "checksum=" in d.message
    s = Status.decode(job.reject(d))
    assert s.state == RobotState.ERROR and s.ack == 0 and not job.gave_up
    # garbage: cmpCOM fails, clrCOM drops everything behind it too
    job.receive(b"hello robot" + good)
    d = job.decide()
    assert d is not None and d.error == ErrorCode.BAD_MAGIC and job.rx == bytearray()
    job.reject(d)
    # the resent frame answers the newest status
    job.receive(Target(seq=1, ack=job.seq, cmd=Cmd.HOLD).encode())
    d = job.decide()
    assert d is not None and d.kind == "hold"
    assert Status.decode(job.status()).state == RobotState.READY and job.errors == 0


def test_field_errors_name_the_field() -> None:
    job, _ = job_after_hello()
    values = [1, 1, 5, 0, 0, 0, 0, 0, 0, 0, 0, 1]  # cmd = 5
    job.receive(b"JRT1" + struct.pack(">13i", *values, checksum(values)) + b"\r\n")
    d = job.decide()
    assert d is not None and d.error == ErrorCode.BAD_COMMAND and d.detail == 3 and "cmd=5" in d.message


def test_stale_frame_is_a_sequence_error() -> None:
    job, _ = job_after_hello()
    job.receive(Target(seq=1, ack=7, cmd=Cmd.HOLD).encode())
    d = job.decide()
    assert d is not None and d.error == ErrorCode.BAD_SEQUENCE


def test_too_many_rejections_end_the_job() -> None:
    job = PointJob(JanomeRobot(JR), PointJobSettings(max_errors=2))
    job.hello()
    for _ in range(2):
        job.receive(b"????")
        d = job.decide()
        assert d is not None
        s = Status.decode(job.reject(d))
    assert s.state == RobotState.BYE and s.error == ErrorCode.TOO_MANY_ERRORS and job.gave_up


def test_receive_buffer_is_8_kb() -> None:
    job, _ = job_after_hello()
    job.receive(bytes(RECEIVE_BUFFER + 100))
    d = job.decide()
    assert d is not None and d.error == ErrorCode.BUFFER_OVERFLOW and d.detail == 100 and not job.rx


def test_end_says_bye() -> None:
    job, _ = job_after_hello()
    job.receive(Target(seq=1, ack=1, cmd=Cmd.END).encode())
    d = job.decide()
    assert d is not None and d.kind == "end"
    s = Status.decode(job.bye())
    assert s.state == RobotState.BYE and s.error == ErrorCode.NONE


def test_stop_flag_overrides_a_move() -> None:
    job, _ = job_after_hello()
    job.receive(Target(seq=1, ack=1, cmd=Cmd.LINE, stop=True, x=160.0, y=160.0, z=50.0, speed=50.0).encode())
    d = job.decide()
    assert d is not None and d.kind == "hold"


# --------------------------------------------------------------------------------- SCARA


def test_scara_line_move_keeps_the_configuration() -> None:
    robot = JanomeRobot(JS)
    plan = robot.plan(Target(1, 1, Cmd.LINE, x=260.0, y=150.0, z=50.0, speed=100.0, arm=1))
    assert isinstance(plan, MovePlan)
    for t in np.linspace(0, plan.duration, 7):
        p = robot.at(plan, float(t))
        assert JS.arm is not None and JS.arm.ik(p[0], p[1], Arm.RIGHTY)[1] > 0
    robot.finish(plan)
    assert robot.arm == Arm.RIGHTY and robot.joints()[1] > 0
    # a line cannot change configuration, nor end where the righty arm's J1 cannot go
    bad = robot.plan(Target(2, 2, Cmd.LINE, x=260.0, y=150.0, z=50.0, speed=100.0, arm=-1))
    assert not isinstance(bad, MovePlan) and bad.code == ErrorCode.UNREACHABLE
    far = robot.plan(Target(2, 2, Cmd.LINE, x=0.0, y=-160.0, z=50.0, speed=100.0, arm=1))
    assert not isinstance(far, MovePlan) and far.code == ErrorCode.UNREACHABLE and "J1=-137.667" in far.message


def test_scara_ptp_may_change_configuration_in_joint_space() -> None:
    robot = JanomeRobot(JS)
    plan = robot.plan(Target(1, 1, Cmd.PTP, x=200.0, y=150.0, z=50.0, arm=-1))
    assert isinstance(plan, MovePlan) and plan.start_joints is not None and plan.end_joints is not None
    assert plan.start_joints[1] == pytest.approx(90.0) and plan.end_joints[1] < 0
    assert plan.duration > 0
    robot.finish(plan)
    assert robot.arm == Arm.LEFTY and robot.position == pytest.approx([200.0, 150.0, 50.0, 0.0])
    assert robot.joints()[1] < 0


def test_start_outside_the_strokes_is_refused() -> None:
    with pytest.raises(ValueError, match=r"start position refused: X=500\.000 mm"):
        JanomeRobot(JR, start=(500.0, 0.0, 0.0, 0.0))


def test_cli_parser_and_bad_arguments(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    add_janome_sim_parser(parser.add_subparsers())
    args = parser.parse_args(["janome", "--connect", "localhost", "--model", "js3"])
    assert args.handler(args) == 2
    assert "expected HOST:PORT" in capsys.readouterr().err
    args = parser.parse_args(["janome", "--connect", "127.0.0.1:1", "--model", "nope"])
    assert args.handler(args) == 2
    assert "'nope' is unknown" in capsys.readouterr().err
