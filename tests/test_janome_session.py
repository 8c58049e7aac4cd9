"""The server-side session and supervisor against the simulated point job, in lock-step, without sockets."""

from __future__ import annotations

import signal

import numpy as np
import pytest

from servo_app.errors import CommandRejected
from servo_app.janome.motion import JanomeMotion
from servo_app.janome.profile import load_janome_profile
from servo_app.janome.protocol import Cmd, ErrorCode, RobotState, Status, Target
from servo_app.janome.session import Phase
from servo_app.janome.supervisor import JanomeSupervisor
from servo_app.messages import End, Jog, JointTarget, Reset, Start, Stop
from servo_app.safety import Mode
from servo_app.sim.janome_pointjob import Decision, PointJob
from servo_app.sim.janome_robot import JanomeRobot


class Rig:
    """servo_app's supervisor and the point job wired back to back; moves complete instantly."""

    def __init__(self, model: str = "jr3000", **robot_kw: object) -> None:
        self.profile = load_janome_profile(model)
        self.motion = JanomeMotion(self.profile)
        self.sup = JanomeSupervisor(self.motion)
        self.robot = JanomeRobot(self.profile, **robot_kw)  # type: ignore[arg-type]
        self.job = PointJob(self.robot)
        self.now = 0.0
        self.sup.on_connect(self.now)
        self.to_service = self.job.hello()
        self.targets: list[Target] = []
        self.decisions: list[Decision] = []

    @property
    def mode(self) -> Mode:
        return self.sup.state.mode

    def exchange(self, dt: float = 0.1, corrupt_target: bool = False) -> Decision | None:
        """One status -> target -> action round."""
        self.now += dt
        out = b"".join(self.sup.on_bytes(self.to_service, self.now))
        self.targets += [Target.decode(f) for f in _frames(out)]
        if corrupt_target and out:
            b = bytearray(out)
            b[12] ^= 0x01
            out = bytes(b)
        self.job.receive(out)
        d = self.job.decide()
        if d is None:
            return None
        self.decisions.append(d)
        if d.kind == "move":
            assert d.plan is not None
            self.robot.finish(d.plan)
            self.to_service = self.job.status(move_ms=int(d.plan.duration * 1000))
        elif d.kind == "hold":
            self.to_service = self.job.status()
        elif d.kind == "reject":
            self.to_service = self.job.reject(d)
        else:
            self.to_service = self.job.bye()
        return d

    def run(self, n: int, **kw: object) -> None:
        for _ in range(n):
            self.exchange(**kw)  # type: ignore[arg-type]


def _frames(data: bytes) -> list[bytes]:
    return [data[i:i + 58] for i in range(0, len(data), 58)]


def started(model: str = "jr3000") -> Rig:
    rig = Rig(model)
    rig.exchange()
    assert rig.mode == Mode.READY and rig.sup.session.phase == Phase.CONNECTED
    rig.sup.request(Start(), rig.now)
    assert rig.mode == Mode.STREAMING
    return rig


def test_start_jog_stop_end() -> None:
    rig = started()
    p0 = rig.robot.position.copy()
    rig.sup.request(Jog(joints=(80.0, 0.0, 0.0, 0.0), hold_s=10.0), rig.now)
    rig.run(20)
    moves = [t for t in rig.targets if t.cmd == Cmd.LINE]
    assert len(moves) >= 15
    steps = np.diff([p0[0]] + [t.x for t in moves])
    assert np.all(steps > 0) and np.max(steps) <= rig.profile.max_step_mm + 1e-9
    assert steps[0] < steps[1] <= steps[2]  # a smooth start: the steps grow
    assert all(t.speed <= rig.profile.cp_speed for t in moves)
    # stop: no further step; the next status (the robot's last step done) ends the stop
    rig.sup.request(Stop(), rig.now)
    assert rig.mode == Mode.STOPPING
    x_at_stop = rig.targets[-1].x
    rig.exchange()
    assert rig.mode == Mode.STOPPED
    assert rig.targets[-1].cmd == Cmd.HOLD and rig.targets[-1].stop
    rig.run(3)
    assert rig.robot.position[0] == pytest.approx(x_at_stop)  # finished its step, went no further
    with pytest.raises(CommandRejected, match="jog refused in stopped"):
        rig.sup.request(Jog(joints=(10.0, 0.0, 0.0, 0.0)), rig.now)
    rig.sup.request(End(), rig.now)
    assert rig.mode == Mode.ENDING
    d = rig.exchange()
    assert d is not None and d.kind == "end" and rig.targets[-1].cmd == Cmd.END
    rig.exchange()  # the BYE
    assert rig.mode == Mode.ENDED and rig.sup.session.phase == Phase.CLOSED and rig.sup.session.want_close


def test_target_is_reached_in_short_steps_and_checked() -> None:
    rig = started()
    rig.sup.request(JointTarget(joints=(200.0, 100.0, 20.0, 45.0), speed_scale=0.5), rig.now)
    rig.run(80)
    assert rig.robot.position == pytest.approx([200.0, 100.0, 20.0, 45.0], abs=1e-3)
    d = np.diff([[150.0, 160.0, 50.0, 0.0]] + [list(t.xyzr) for t in rig.targets if t.moves], axis=0)
    assert np.max(np.linalg.norm(d[:, :3], axis=1)) <= rig.profile.max_step_mm + 1e-6
    with pytest.raises(CommandRejected, match=r"target refused: Y=400.000 mm is outside the stroke \[0.5, 319.5\]"):
        rig.sup.request(JointTarget(joints=(100.0, 400.0, 20.0, 0.0)), rig.now)
    with pytest.raises(CommandRejected, match=r"joints has 3 values, expected 4"):
        rig.sup.request(JointTarget(joints=(100.0, 100.0, 20.0)), rig.now)


def test_hold_to_run_expires_and_a_new_jog_resumes() -> None:
    rig = started()
    rig.sup.request(Jog(joints=(0.0, 50.0, 0.0, 0.0), hold_s=0.35), rig.now)
    rig.run(6)
    assert rig.mode in (Mode.STOPPING, Mode.STOPPED)
    rig.exchange()
    assert rig.mode == Mode.STOPPED and rig.sup.state.stop_reason == "hold-to-run expired"
    rig.sup.request(Jog(joints=(0.0, -50.0, 0.0, 0.0), hold_s=0.35), rig.now)
    assert rig.mode == Mode.STREAMING


def test_wrong_robot_kind_is_refused_at_the_handshake() -> None:
    rig = Rig("jr3000")
    rig.to_service = Status(seq=1, ack=0, state=RobotState.HELLO, detail=2).encode()
    rig.exchange()
    s = rig.sup.session
    assert not s.handshaken and s.want_close and rig.mode == Mode.DISCONNECTED
    assert "detail=2 (robot kind SCARA), but the profile is cartesian" in s.stats.last_error


def test_rejected_target_is_sent_again_then_faults() -> None:
    rig = started()
    rig.sup.request(Jog(joints=(50.0, 0.0, 0.0, 0.0), hold_s=10.0), rig.now)
    rig.run(3)
    n = len(rig.targets)
    d = rig.exchange(corrupt_target=True)
    assert d is not None and d.error == ErrorCode.BAD_CHECKSUM
    rig.exchange()
    assert rig.targets[-1].seq == rig.targets[-2].seq and rig.targets[-1].ack == rig.targets[-2].ack + 1
    assert rig.sup.session.stats.retransmits == 1 and rig.mode == Mode.STREAMING
    assert len(rig.targets) == n + 2
    rig.run(3)
    assert rig.mode == Mode.STREAMING
    # a line so bad that every frame is corrupted: the robot gives up after 3 rejections in a row
    rig.run(4, corrupt_target=True)
    assert rig.mode == Mode.FAULT
    fault = rig.sup.state.fault
    assert fault is not None and fault.code == "JNM-012" and "point job" in fault.cause
    assert "IBGN" not in fault.remedy and "MOTN" not in fault.cause


def test_malformed_status_is_answered_and_counted() -> None:
    rig = started()
    rig.run(2)
    good = bytearray(rig.to_service)
    good[20] ^= 0x10
    rig.to_service = bytes(good)
    d = rig.exchange()
    s = rig.sup.session
    assert s.stats.malformed == 1 and "status frame rejected: status frame: checksum=" in s.stats.last_error
    assert d is not None and d.kind == "hold"  # the robot took the stand-in answer and goes on
    rig.run(2)
    assert rig.mode == Mode.STREAMING and s.stats.status_lost == 1


def test_silence_is_a_fault_with_janome_words() -> None:
    rig = started()
    rig.sup.request(Jog(joints=(50.0, 0.0, 0.0, 0.0), hold_s=10.0), rig.now)
    rig.run(3)
    rig.sup.on_idle(rig.now + 0.5)
    assert rig.mode == Mode.STREAMING
    rig.sup.on_idle(rig.now + 5.0)
    assert rig.mode == Mode.FAULT
    fault = rig.sup.state.fault
    assert fault is not None and "link failed while streaming: no status frame for" in fault.message
    assert "point job stalled" in fault.cause and rig.sup.session.want_close


def test_disconnect_mid_motion_is_a_fault() -> None:
    rig = started()
    rig.sup.request(Jog(joints=(50.0, 0.0, 0.0, 0.0), hold_s=10.0), rig.now)
    rig.run(3)
    rig.sup.on_disconnect("ConnectionResetError: [Errno 104] Connection reset by peer", rig.now)
    fault = rig.sup.state.fault
    assert rig.mode == Mode.FAULT and fault is not None
    assert fault.message.startswith("connection lost while streaming: ConnectionResetError")
    assert "TCP connection closed or reset" in fault.cause and "MOTN-603" not in fault.cause
    rig.sup.request(Reset(), rig.now)
    assert rig.mode == Mode.DISCONNECTED


def test_robot_motion_error_faults_but_keeps_the_link() -> None:
    rig = started()
    rig.robot.ws = load_janome_profile("jc3").workspace()  # pretend the profile is wider than the robot
    rig.robot.ws = type(rig.robot.ws)((0.0, 0.0, 0.0, -360.0), (155.0, 320.0, 100.0, 360.0))  # type: ignore[call-arg]
    rig.sup.request(Jog(joints=(80.0, 0.0, 0.0, 0.0), hold_s=10.0), rig.now)
    rig.run(8)
    fault = rig.sup.state.fault
    assert rig.mode == Mode.FAULT and fault is not None and fault.code == "JNM-006"
    assert "outside the stroke" in fault.message or "OUT_OF_RANGE" in fault.message
    assert "profile's strokes" in fault.remedy
    s = rig.sup.session
    assert not s.want_close and s.phase == Phase.CONNECTED
    rig.run(2)
    assert rig.targets[-1].cmd == Cmd.HOLD and rig.targets[-1].stop
    rig.sup.request(Reset(), rig.now)
    assert rig.mode == Mode.READY
    rig.sup.request(Start(), rig.now)
    assert rig.mode == Mode.STREAMING


def test_sigterm_ends_the_stream_and_finishes() -> None:
    rig = started()
    rig.sup.request(Jog(joints=(50.0, 0.0, 0.0, 0.0), hold_s=10.0), rig.now)
    rig.run(3)
    rig.sup.signal(int(signal.SIGTERM), rig.now)
    assert rig.mode == Mode.STOPPING
    rig.run(3)
    assert rig.mode == Mode.ENDED and rig.targets[-1].cmd == Cmd.END
    rig.sup.on_disconnect("the robot closed the connection", rig.now)
    assert rig.sup.finished


def test_start_before_the_robot_connects_is_kept_pending() -> None:
    rig = Rig()
    rig.sup.request(Start(), rig.now)
    assert rig.mode == Mode.DISCONNECTED
    rig.exchange()  # HELLO
    assert rig.mode == Mode.STREAMING


def test_scara_jog_stops_at_the_edge_in_its_configuration() -> None:
    rig = started("js3")
    rig.sup.request(Jog(joints=(100.0, 0.0, 0.0, 0.0), hold_s=100.0), rig.now)  # its X speed limit
    rig.run(60)
    assert rig.mode == Mode.STREAMING
    _j1, j2, _, _ = rig.robot.joints()
    assert rig.robot.arm == 1 and 2.0 < j2 < 5.0  # at the singular margin, still righty
    assert all(t.arm == 1 for t in rig.targets if t.moves)
    assert all(d.kind != "reject" for d in rig.decisions)
