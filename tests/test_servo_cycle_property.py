"""The whole servo cycle against the controller model, in simulated time (no sockets, no clock).

The supervisor (safety state machine, stream session, diff-IK, shaper) talks datagrams with the pure
FANUC controller model: random streams of commands — twists, pose targets, jogs, joint targets,
jumps, reversals, NaN, out-of-range values, stops, resumes — must never make the controller alarm,
never leave a joint range and never change the arm configuration held since the start.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import pytest

from servo_app.errors import CommandRejected
from servo_app.fanuc.packets import StatusStart
from servo_app.fanuc.session import SessionConfig
from servo_app.fanuc.supervisor import StreamSupervisor
from servo_app.messages import End, Jog, JointTarget, PoseTarget, Request, Reset, Resume, Start, Stop, Twist
from servo_app.motion.diffik import IkSettings
from servo_app.motion.servo import ServoCycle
from servo_app.robots.configuration import configuration_of
from servo_app.robots.conventions import fanuc_deg_to_model_rad, matrix_to_xyzwpr
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile
from servo_app.sim.fanuc_model import ControllerConfig, FanucControllerModel

PROFILE = load_profile("lrmate200id")
KIN = ArmKinematics(PROFILE)
HOME = [0.0, 10.0, -10.0, 0.0, -70.0, 0.0]
CLIENT = ("127.0.0.1", 50000)
CYCLES_PER_EXAMPLE = 1000
EXAMPLES = int(os.environ.get("SERVO_PROPERTY_STREAMS", "10"))  # 10 x 1000 = 10,000 cycles


class Cell:
    """Supervisor and controller model exchanging datagrams on a simulated clock."""

    def __init__(self, interval_ms: int = 8) -> None:
        self.lines: list[str] = []
        self.ctrl = FanucControllerModel(PROFILE, ControllerConfig(interval_ms=interval_ms), initial_joints=HOME,
                                         log=self.lines.append)
        self.dt = interval_ms / 1000
        self.sup = StreamSupervisor(ServoCycle(PROFILE, self.dt), SessionConfig())
        self.t = 0.0
        self.sent: list[np.ndarray] = []

    def deliver(self, out: list[bytes]) -> None:
        for b in out:
            for reply in self.ctrl.on_datagram(b, self.t, CLIENT):
                self.sup.on_datagram(reply, self.t)  # limit-table responses

    def cycle(self) -> None:
        self.t += self.dt
        raw = self.ctrl.tick(self.t)
        if raw is None:
            self.deliver(self.sup.on_idle(self.t))
            return
        self.deliver(self.sup.on_datagram(raw, self.t))
        self.sent += [np.array(c.command.values[:6]) for c in self.sup.session.sent]

    def request(self, req: Request) -> bool:
        try:
            self.sup.request(req, self.t)
        except CommandRejected:
            return False
        finally:
            self.deliver(self.sup._take())
        return True

    def start(self) -> None:
        assert self.ctrl.on_datagram(StatusStart().encode(), self.t, CLIENT) == []
        self.request(Start())
        for _ in range(200):
            self.cycle()
            if self.sup.state.mode.value == "streaming":
                return
        raise AssertionError(f"never streaming: {self.sup.describe()}")


HOLD_RENEW_CYCLES = 10  # a held button: the client re-sends its jog this often
BAD = [math.nan, math.inf, -math.inf, 50.0, -50.0]  # in units of the field's scale: absurd magnitudes


@dataclass(frozen=True)
class PoseOffset:
    """A pose target relative to where the arm is when it is sent (made into a PoseTarget then)."""

    offset: tuple[float, ...]
    linear_speed: float
    angular_speed: float


def random_events(seed: int, n: int = 40) -> list[tuple[int, Request | PoseOffset]]:
    """A realistic operator/sensor stream: mostly valid commands, ~10 % bad values, stops and resumes."""
    rng = np.random.default_rng(seed)

    def vec(k: int, scale: float) -> tuple[float, ...]:
        v = rng.uniform(-1, 1, k)
        if rng.random() < 0.1:
            v[rng.integers(k)] = rng.choice(BAD)
        return tuple(float(x) for x in v * scale)

    out: list[tuple[int, Request | PoseOffset]] = []
    for _ in range(n):
        gap = int(rng.integers(5, 120))
        kind = rng.choice(["twist", "twist", "jog", "jog", "target", "pose", "pose", "stop", "stop_fast",
                           "resume"])
        ev: Request | PoseOffset
        if kind == "twist":
            frame = str(rng.choice(["base", "tool"]))
            linear, angular = vec(3, 400.0), vec(3, 90.0)  # drawn in this order, as before
            ev = Twist(frame=frame, linear=linear, angular=angular, hold_s=float(rng.uniform(0.05, 0.5)))
        elif kind == "jog":
            ev = Jog(joints=vec(6, 200.0), hold_s=float(rng.uniform(0.05, 0.5)))
        elif kind == "target":
            ev = JointTarget(joints=vec(6, 120.0), speed_scale=float(rng.uniform(0.05, 1.0)))
        elif kind == "pose":
            ev = PoseOffset(offset=vec(6, 250.0), linear_speed=float(rng.uniform(10, 1500)),
                            angular_speed=float(rng.uniform(5, 180)))
        elif kind == "stop":
            ev = Stop()
        elif kind == "stop_fast":
            ev = Stop(fast=True)
        else:
            ev = Resume()
        out.append((gap, ev))
    return out


def run_events(cell: Cell, events: list[tuple[int, Request | PoseOffset]]) -> float:
    start_cfg = configuration_of(fanuc_deg_to_model_rad(np.array(HOME), PROFILE.j23_factor), KIN)
    lo, hi = np.array(PROFILE.joint_min_deg), np.array(PROFILE.joint_max_deg)
    queue = list(events)
    next_at = 0
    held: Request | None = None
    for k in range(CYCLES_PER_EXAMPLE):
        if held is not None and k < next_at and k % HOLD_RENEW_CYCLES == 0:
            cell.request(held)
        if queue and k >= next_at:
            gap, ev = queue.pop(0)
            next_at = k + gap
            held = ev if isinstance(ev, (Twist, Jog)) else None
            if cell.sup.state.stop_fast and cell.sup.state.mode.value == "stopped":
                cell.request(Reset())  # the operator acknowledges a fast stop at rest, then goes on
                cell.request(Resume())
            if isinstance(ev, PoseOffset):
                here = matrix_to_xyzwpr(KIN.fk_fanuc_deg(np.array(cell.sent[-1] if cell.sent else HOME)))
                goal = here + np.array(ev.offset) * [1, 1, 1, 0.1, 0.1, 0.1]
                cell.request(PoseTarget(xyzwpr=tuple(float(x) for x in goal), linear_speed=ev.linear_speed,
                                        angular_speed=ev.angular_speed))
            else:
                cell.request(ev)
        cell.cycle()
        alarms = [e for e in cell.ctrl.alarms()]
        assert not alarms, (alarms, cell.sup.describe())
        if cell.sent:
            q = cell.sent[-1]
            qm = fanuc_deg_to_model_rad(q, PROFILE.j23_factor)
            assert np.all(np.degrees(qm) >= lo - 1e-6) and np.all(np.degrees(qm) <= hi + 1e-6), q
            assert configuration_of(qm, KIN) == start_cfg, (q, configuration_of(qm, KIN), start_cfg)
    assert cell.sup.state.mode.value != "fault", cell.sup.describe()
    return moving_share(cell)


def moving_share(cell: Cell) -> float:
    s = np.array(cell.sent)
    return float(np.mean(np.any(np.diff(s, axis=0) != 0, axis=1))) if len(s) > 1 else 0.0


MOVING: list[float] = []  # share of moving cycles per random stream


@pytest.mark.parametrize("seed", range(EXAMPLES))
def test_random_command_streams_never_alarm_leave_range_or_change_configuration(seed: int) -> None:
    cell = Cell(interval_ms=8 if seed % 2 else 4)
    cell.start()
    MOVING.append(run_events(cell, random_events(seed)))


def test_the_random_streams_really_moved_the_arm() -> None:
    # Guards the property test above against degenerating into a stream that barely moves.
    print("moving share per stream:", MOVING)
    assert len(MOVING) == EXAMPLES and np.mean(MOVING) > 0.3, MOVING


@pytest.mark.parametrize("interval_ms", [8, 4])
def test_pose_target_step_reached_and_end_clean(interval_ms: int) -> None:
    """A step pose target arrives near the time-optimal time and stays: no hunting about the goal."""
    cell = Cell(interval_ms)
    cell.start()
    here = matrix_to_xyzwpr(KIN.fk_fanuc_deg(np.array(HOME)))
    goal = here + np.array([80.0, -60.0, 50.0, 0.0, 0.0, 10.0])
    speed = 250.0
    assert cell.request(PoseTarget(xyzwpr=tuple(goal), linear_speed=speed, angular_speed=45.0))
    errors = []
    for _ in range(int(3.0 / cell.dt)):
        cell.cycle()
        errors.append(float(np.linalg.norm(matrix_to_xyzwpr(KIN.fk_fanuc_deg(cell.sent[-1]))[:3] - goal[:3])))
    reached = matrix_to_xyzwpr(KIN.fk_fanuc_deg(cell.sent[-1]))
    assert np.allclose(reached[:3], goal[:3], atol=0.02), reached
    assert abs(((reached[5] - goal[5]) + 180) % 360 - 180) < 0.02
    # Time-optimal at the target's speed and braking acceleration (a trapezoid; the ramps' jerk adds a
    # little): 122 mm at 250 mm/s and 2000 mm/s^2.
    distance, acc = float(np.linalg.norm(goal[:3] - here[:3])), IkSettings().target_linear_acc
    optimal = distance / speed + speed / acc
    arrived = int(np.argmax(np.array(errors) < 0.05))
    print(f"pose step {distance:.0f} mm: within 0.05 mm after {arrived * cell.dt:.3f} s, optimal {optimal:.3f} s")
    assert errors[arrived] < 0.05 and arrived * cell.dt < 1.6 * optimal  # measured 1.50 (0.86 s)
    assert max(errors[arrived:]) < 0.05  # and stays there
    moving = [i for i in range(1, len(cell.sent)) if np.any(cell.sent[i] != cell.sent[i - 1])]
    assert moving[-1] * cell.dt < 1.6 * optimal + 0.3  # then at rest
    # A stream repeating the reached target (a tracker whose part stopped) leaves the arm where it is.
    rest = cell.sent[-1].copy()
    for _ in range(int(0.5 / cell.dt)):
        assert cell.request(PoseTarget(xyzwpr=tuple(goal), linear_speed=speed, angular_speed=45.0))
        cell.cycle()
    assert np.array_equal(cell.sent[-1], rest)
    assert cell.request(End())
    for _ in range(300):
        cell.cycle()
    assert cell.sup.state.mode.value == "ended" and not cell.ctrl.alarms()


@pytest.mark.parametrize("interval_ms", [8, 4])
def test_moving_pose_target_is_followed_with_bounded_lag(interval_ms: int) -> None:
    """A target sliding along a 100 mm/s circle (a tracked part): the TCP follows it within a bounded lag."""
    cell = Cell(interval_ms)
    cell.start()
    centre = matrix_to_xyzwpr(KIN.fk_fanuc_deg(np.array(HOME)))
    radius, speed = 60.0, 100.0  # mm, mm/s
    omega = speed / radius
    errors = []
    for k in range(int(4.0 / cell.dt)):
        t = k * cell.dt
        goal = centre + np.array([radius * (math.cos(omega * t) - 1), radius * math.sin(omega * t), 0, 0, 0, 0])
        assert cell.request(PoseTarget(xyzwpr=tuple(goal), linear_speed=250.0, angular_speed=45.0))
        cell.cycle()
        if t > 1.0:  # after the catch-up from rest
            here = matrix_to_xyzwpr(KIN.fk_fanuc_deg(cell.sent[-1]))
            errors.append(float(np.linalg.norm(here[:3] - goal[:3])))
    # Steady lag of P-control toward a moving target: v / gain = 100 / 10 = 10 mm, plus the shaper's
    # velocity lag (its acceleration ramp, acc/jerk ~ 0.05 s: 5 mm). Measured ~14.5 mm.
    print(f"tracking error max {max(errors):.2f} mm, mean {np.mean(errors):.2f} mm")
    assert max(errors) < 20.0, max(errors)
    assert not cell.ctrl.alarms()


@pytest.mark.parametrize("interval_ms", [8, 4])
@pytest.mark.parametrize(("start", "linear", "angular"), [
    ([0, 0, 0, 0, -90, 0], (100.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
    ([0, 10, -10, 0, -70, 0], (150.0, 0.0, 50.0), (0.0, 0.0, 0.0)),
    ([20, 30, -20, 10, -60, 30], (0.0, 0.0, -120.0), (0.0, 0.0, 0.0)),
    ([-30, 20, -30, 20, -50, -20], (200.0, -100.0, 80.0), (0.0, 0.0, 0.0)),
    ([0, 0, 0, 0, -90, 0], (80.0, 40.0, 0.0), (0.0, 0.0, 20.0)),
])
def test_cartesian_jog_keeps_its_line_and_speed_through_the_shaper(
        start: list[float], linear: tuple[float, ...], angular: tuple[float, ...], interval_ms: int) -> None:
    """IK and jerk-limited shaper together (what the controller receives): a twist held 0.8 s, then a
    soft stop. The TCP stays within 0.5 mm of its line and never runs faster than commanded; a pure
    translation keeps the tool's orientation. (The IK used to pull the lagging TCP back onto its
    reference in one cycle: 2-5 mm off the line and 20-37 % over speed.)"""
    from servo_app.fanuc.packets import Status
    from servo_app.motion.commands import Twist

    dt = interval_ms / 1000
    cycle = ServoCycle(PROFILE, dt)
    cycle.begin(np.array(start, float), None)
    poses = []
    for k in range(round(1.6 / dt)):
        if k < round(0.8 / dt):
            cycle.twist(Twist(linear=linear, angular=angular, frame="base", source="t", stamp=0.0))
        elif k == round(0.8 / dt):
            cycle.stop()
        poses.append(KIN.fk_fanuc_deg(cycle.next_command(Status(seq=k))))
    p = np.array([m[:3, 3] for m in poses]) * 1000.0
    u = np.array(linear) / np.linalg.norm(linear)
    rel = p - p[0]
    along = rel @ u
    off_line = np.linalg.norm(rel - np.outer(along, u), axis=1)
    speed = np.diff(along) / dt
    assert off_line.max() < 0.5, off_line.max()
    # Not over by more than 0.1 %: the joints change velocity in proportion while the shaper ramps
    # (shaper_kernels.velocity_share_limits); before, 120 mm/s along z ran at 120.42 (+0.35 %).
    assert np.linalg.norm(linear) * 0.97 < speed.max() < np.linalg.norm(linear) * 1.001
    # Stopped without backing up: at most a cycle a hair past zero speed (8 um: the IK's braking is not
    # jerk-aware, the shaper's is), where the old pull-back made it back up at 7 mm/s.
    assert speed.min() > -1.5 and cycle.at_rest()
    if not any(angular):
        turned = [np.degrees(np.arccos(np.clip((np.trace(poses[0][:3, :3].T @ m[:3, :3]) - 1) / 2, -1, 1)))
                  for m in poses]
        assert max(turned) < 0.05


@pytest.mark.parametrize("take_over", ["pose", "twist"])
def test_a_jog_after_the_ik_took_over_a_pending_joint_motion_is_followed(take_over: str) -> None:
    """A joint target reversed while moving waits for rest (pending); a pose target or twist that takes
    the moving arm over replaces it. A jog after that is steered. Old code: still pending, the jog
    issued no stop and was never steered: the shaper ran on at the IK's last velocity (seed 2 above:
    across the elbow boundary)."""
    from servo_app.fanuc.packets import Status
    from servo_app.motion.commands import PoseTarget as IkPoseTarget
    from servo_app.motion.commands import Twist as IkTwist

    dt = 0.008
    home = np.array(HOME)
    cycle = ServoCycle(PROFILE, dt)
    cycle.begin(home, None)
    sent = [cycle.next_command(Status(seq=0))]

    def run(seconds: float) -> None:
        for _ in range(round(seconds / dt)):
            sent.append(cycle.next_command(Status(seq=len(sent))))

    cycle.set_joint_target(home + np.array([30.0, 0, 0, 0, 0, 0]))
    run(0.3)
    cycle.set_joint_target(home - np.array([30.0, 0, 0, 0, 0, 0]))  # the other way: waits for rest
    if take_over == "pose":
        here = matrix_to_xyzwpr(KIN.fk_fanuc_deg(sent[-1]))
        goal = tuple(here + np.array([0.0, 80.0, 0.0, 0.0, 0.0, 0.0]))
        cycle.pose_target(IkPoseTarget(xyzwpr=goal, linear_speed=100.0, angular_speed=30.0, source="t", stamp=0.0))
    else:
        cycle.twist(IkTwist(linear=(0.0, 60.0, 0.0), angular=(0.0, 0.0, 0.0), frame="base", source="t", stamp=0.0))
    run(0.2)
    jog = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 20.0])
    cycle.jog_joints(jog)
    run(1.5)
    step = (np.asarray(sent[-1]) - np.asarray(sent[-2])) / dt
    assert np.allclose(step, jog, atol=0.05), step  # the jog's speed on J6 alone, the rest at rest
