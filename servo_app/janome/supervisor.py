"""The Janome servo process's brain: the shared safety state machine driving the link session.

Pure (no sockets, no clock of its own), the counterpart of ``servo_app.fanuc.supervisor``: the runner
hands it connection events, bytes, requests and ``now``; it returns the frames to send. Every decision
about motion goes through :func:`servo_app.safety.transition`:

- requests (start, stop, resume, end, reset, jog, target) become safety events; refused ones raise
  :class:`CommandRejected` with the state machine's message and change nothing. A twist and a pose
  target map onto X Y Z R (R turns about Z; a rotation about X or Y, or the tool frame, is refused as
  not supported by the Janome backend); every motion is checked whole first (:class:`InvalidRequest`:
  counts, the speeds the stream commands, the work envelope);
- each valid status frame feeds ``StatusReceived``: bit 0 = the point job is in its loop (not BYE),
  bit 1 = 0 (the point job takes a new stream at any time), SYSRDY = 1 (it could not talk otherwise);
- a stop sends no further step; the robot's next status proves its last step is done, which feeds
  ``ShaperAtRest`` (stopping -> stopped, or -> ending and END);
- hold-to-run: each jog renews a deadline; when it passes, ``JogExpired`` stops;
- the connection closing feeds ``Disconnected``; silence ``StatusLost``; a robot error a
  ``ControllerAlarm`` with code ``JNM-nnn``.

The state machine words its own faults for FANUC; faults caused here get Janome's cause and remedy.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, ClassVar

import numpy as np

from servo_app import messages as msg
from servo_app.errors import InvalidRequest
from servo_app.input_slot import TWIST, InputCommand
from servo_app.janome.alarms import (
    LINK_LOST,
    LINK_TIMEOUT,
    PROTOCOL,
    ROBOT_LEFT,
    alarm_code,
    alarm_for_code,
)
from servo_app.janome.kinematics import AXES, UNITS
from servo_app.janome.motion import JanomeMotion
from servo_app.janome.protocol import FrameError, RobotState, Status
from servo_app.janome.session import JanomeSession, Phase, SessionConfig
from servo_app.motion.commands import MIN_ANGULAR_DEG_S, MIN_LINEAR_MM_S
from servo_app.safety import (
    ControllerAlarm,
    Disconnected,
    FaultInfo,
    HoldToRun,
    Mode,
    ShaperAtRest,
    Signal,
    StatusLost,
    StatusReceived,
    stream_alive,
)
from servo_app.supervision import SupervisorBase, axis_values, check_count

UNSUPPORTED = "not supported by the Janome backend"
JOINT_FIELDS = ("joints[0]", "joints[1]", "joints[2]", "joints[3]")


def _most(limit: float) -> str:
    """A limit as shown in a refusal, rounded down (a value sent as shown is accepted)."""
    return f"{math.floor(limit * 1000) / 1000:g}"


class JanomeSupervisor(SupervisorBase):
    max_hold_s = float("inf")  # the robot's own move time bounds a step, not the hold
    REQUESTS: ClassVar[dict[type, str]] = {msg.Twist: "_on_twist", msg.PoseTarget: "_on_pose",
                                           msg.SetTool: "_on_set_tool"}

    def __init__(self, motion: JanomeMotion, session_config: SessionConfig | None = None,
                 hold_s: float = 0.5, start_timeout_s: float = float("inf")) -> None:
        # A start waits for the robot's point job to connect, which an operator may do at the robot.
        super().__init__(min_input_hold_s=0.05, hold_s=hold_s, start_timeout_s=start_timeout_s)
        self.motion = motion
        self.session = JanomeSession(motion, session_config or SessionConfig(kind=motion.profile.kind))

    # ------------------------------------------------------------------- the link
    def _link_open(self, now: float) -> None:
        self.session.accepting = True

    def _link_close(self) -> None:
        self.session.close("service shutting down")

    def _link_arm(self) -> None:
        self.session.arm()

    def _link_end(self) -> None:
        self.session.request_end()

    def _link_abandon(self, reason: str, now: float) -> None:
        self.session.abandon(reason)

    def _link_closed(self) -> bool:
        return not self.session.connected

    def alarm_event(self, code: str, message: str) -> ControllerAlarm:
        spec = alarm_for_code(code)  # JNM-nnn; any other code stops with the generic texts
        if spec is None:
            return ControllerAlarm(code=code, message=message)
        return ControllerAlarm(code=code, message=message, cause=spec.cause, remedy=spec.remedy)

    def _word_fault(self, fault: FaultInfo, context: dict[str, Any]) -> FaultInfo:
        """Replace the state machine's FANUC wording where the cause is Janome's."""
        if fault.code is not None:
            spec = alarm_for_code(fault.code)
            return fault if spec is None else replace(fault, cause=spec.cause, remedy=spec.remedy)
        alarm = context.get("alarm")
        if alarm is None:
            return fault
        return replace(fault, message=context.get("message") or fault.message, cause=alarm.cause,
                       remedy=alarm.remedy)

    # ------------------------------------------------------------------ requests
    def _check_jog(self, v: np.ndarray, fields: tuple[str, ...] = JOINT_FIELDS) -> np.ndarray:
        """Within the speeds the stream really commands (StreamSpeeds: the profile's share, or the link's
        step where tighter), per axis and along the X Y Z line: a faster jog is refused, not scaled down
        without a word; the limit is named with where it comes from, and what to send instead."""
        check_count("joints", v, 4, "X Y Z in mm/s, R in deg/s")
        sp = self.motion.speeds
        for i, (x, lim) in enumerate(zip(v, sp.vel, strict=True)):
            if abs(x) > lim * (1 + 1e-9):
                unit = f"{UNITS[i]}/s"
                raise InvalidRequest(f"{fields[i]}={x:g} {unit} is faster than {AXES[i]}'s speed limit "
                                     f"{_most(lim)} {unit} ({sp.vel_source[i]}); send at most {_most(lim)} {unit}, "
                                     "as GET /api/limits says (speed)")
        lin = float(np.linalg.norm(v[:3]))
        if lin > sp.cp_speed * (1 + 1e-9):
            names = ", ".join(fields[:3])
            raise InvalidRequest(f"{names} = {[float(x) for x in v[:3]]} mm/s: {lin:.1f} mm/s along X Y Z is above "
                                 f"the line speed limit {_most(sp.cp_speed)} mm/s ({sp.cp_source}); send at most "
                                 f"{_most(sp.cp_speed)} mm/s along X Y Z, as GET /api/limits says (cp_speed_mm_s)")
        return v

    def _check_joint_target(self, q: np.ndarray, speed_scale: float) -> None:
        self.motion.check_target(q, speed_scale)

    def _on_twist(self, req: msg.Twist, now: float) -> None:
        """X Y Z from ``linear`` (mm/s), R from ``angular`` about Z (deg/s), in the robot's base axes."""
        lin, ang = axis_values("linear", req.linear), axis_values("angular", req.angular)
        check_count("linear", lin, 3, "x y z in mm/s")
        check_count("angular", ang, 3, "about x y z in deg/s")
        name = self.motion.profile.display_name
        if req.frame != "base":
            raise InvalidRequest(f"{UNSUPPORTED}: frame={req.frame!r}; the {name} jogs along its own X Y Z "
                                 f"axes and turns R about Z: send frame 'base'")
        if ang[0] or ang[1]:
            raise InvalidRequest(f"{UNSUPPORTED}: angular={[float(a) for a in ang]} deg/s turns about X or Y; "
                                 f"the {name} turns only about Z (its R axis): send angular [0, 0, r]")
        v = np.array([lin[0], lin[1], lin[2], ang[2]])
        self._check_jog(v, ("linear[0]", "linear[1]", "linear[2]", "angular[2]"))
        self._hold_to_run(float(req.hold_s), now, "twist")
        self.motion.jog(v)

    def _on_pose(self, req: msg.PoseTarget, now: float) -> None:
        """X Y Z R from ``xyzwpr`` (W and P must be 0: nothing tilts); the speeds cap the move."""
        pose = axis_values("xyzwpr", req.xyzwpr)
        check_count("xyzwpr", pose, 6, "X Y Z in mm, W P R in deg")
        name = self.motion.profile.display_name
        if pose[3] or pose[4]:
            raise InvalidRequest(f"{UNSUPPORTED}: W={pose[3]:g} P={pose[4]:g} deg tilt the tool about X or Y; the "
                                 f"{name} turns only about Z: send W=0 and P=0, and R for the turn")
        target = np.array([pose[0], pose[1], pose[2], pose[5]])
        scale = self._pose_speed_scale(target, float(req.linear_speed), float(req.angular_speed))
        self.motion.check_target(target, scale, "xyzwpr (X, Y, Z, R)")
        self._target_gate("pose target", now)
        self.motion.set_target(target, scale)

    def _on_set_tool(self, req: msg.SetTool, now: float) -> None:
        """Only the flange: the point job moves the robot's own tool point, with no tool offset of ours.
        A payload is accepted and unused: the protocol has none (the robot's own setting holds)."""
        if any(float(v) != 0.0 for v in req.xyzwpr):
            raise InvalidRequest(f"{UNSUPPORTED}: tool {req.name!r} xyzwpr={[float(v) for v in req.xyzwpr]}; the "
                                 f"{self.motion.profile.display_name} moves its own tool point: use the flange tool")

    def _pose_speed_scale(self, target: np.ndarray, linear: float, angular: float) -> float:
        """The share of the axis speeds that keeps the move within ``linear`` mm/s (X Y Z) and
        ``angular`` deg/s (R), counting only what moves."""
        for field, value, lowest, unit in (("linear_speed", linear, MIN_LINEAR_MM_S, "mm/s"),
                                           ("angular_speed", angular, MIN_ANGULAR_DEG_S, "deg/s")):
            if not (np.isfinite(value) and value >= lowest):
                raise InvalidRequest(f"{field}={value} must be a number of at least {lowest} {unit}")
        m = self.motion
        here = m.last if m.last is not None else target
        d = np.abs(target - here)
        scales = [1.0]
        if np.linalg.norm(d[:3]) > 0:
            scales.append(linear / m.cp_speed)
        if d[3] > 0:
            scales.append(angular / float(m.vel[3]))
        return float(min(1.0, max(1e-3, min(scales))))

    def _input_move(self, cmd: InputCommand, name: str, hold: float, now: float) -> None:
        """A twist jogs X Y Z (mm/s) and R (its rotation about Z, deg/s); a pose input is an absolute
        X Y Z R target (W and P have no axis here)."""
        v = cmd.values
        xyzr = np.array([v[0], v[1], v[2], v[5]])
        if cmd.kind == TWIST:
            self._motion_gate("jog", resume_after_hold=True, now=now)
            self._hold_checked(hold)
            self.motion.jog(xyzr)
        else:
            self._motion_gate(f"input {name}")
            self.motion.set_target(xyzr, 1.0)
        self.hold = HoldToRun(timeout_s=hold).renew(now)

    def signal(self, sig: int, now: float) -> None:
        self._feed(Signal(sig=sig), now)

    # ------------------------------------------------------------------ link
    def on_connect(self, now: float) -> None:
        self.session.on_connect(now)
        self.changed = True  # robot_connected in the view, whether or not the safety state moves

    def on_disconnect(self, reason: str, now: float) -> None:
        self.session.on_disconnect(reason, now)
        # A fault's close comes after the fault, and changes no safety state: the view must still say so.
        self.changed = True
        self._feed(Disconnected(detail=reason), now, alarm=LINK_LOST,
                   message=f"connection lost while {self.state.mode.value}: {reason}")

    def on_bytes(self, data: bytes, now: float) -> list[bytes]:
        out: list[bytes] = []
        for item in self.session.take(data):
            if isinstance(item, FrameError):
                out += self.session.on_malformed(item, now)
            else:
                out += self._on_status(item, now)
            self._after(now)
        return out

    def _on_status(self, st: Status, now: float) -> list[bytes]:
        s = self.session
        if not s.handshaken:
            out = s.on_status(st, now)
            if s.handshaken:
                self._status_event(st, now)
            return out
        if s.last_status is not None and st.seq <= s.last_status.seq:
            return s.on_status(st, now)  # a duplicate carries no news
        self._status_event(st, now)
        if self.state.mode == Mode.STOPPING and self.motion.at_rest():
            self._feed(ShaperAtRest(), now)  # the robot reports the last step done
        self._poll_hold(now)
        return s.on_status(st, now)

    def _status_event(self, st: Status, now: float) -> None:
        bye = st.state == RobotState.BYE
        message = f"robot left its loop (BYE, error={st.error.name}) while {self.state.mode.value}" if bye else None
        self._feed(StatusReceived(bit0=not bye, bit1=False, sysrdy=True), now, alarm=ROBOT_LEFT, message=message)
        if not bye:
            self._start_when_ready(now)

    def _after(self, now: float) -> None:
        s = self.session
        for w in s.warnings:
            self._warn("link", w, now)
        s.warnings.clear()
        if s.pending_alarm is not None:
            a, s.pending_alarm = s.pending_alarm, None
            self._feed(self.alarm_event(alarm_code(a.error), a.message), now)
        if s.phase == Phase.FAULT and stream_alive(self.state):
            self._feed(StatusLost(detail=s.fault_reason), now,
                       alarm=PROTOCOL if "malformed" in s.fault_reason or "acknowledges" in s.fault_reason
                       or "HELLO" in s.fault_reason else LINK_TIMEOUT,
                       message=f"link failed while {self.state.mode.value}: {s.fault_reason}")

    def on_idle(self, now: float) -> None:
        self.session.on_idle(now)
        self._poll_hold(now)
        self._after(now)

    # ------------------------------------------------------------------ views
    def describe(self) -> dict[str, Any]:
        s = self.session
        return {
            **self._safety_view(),
            "link": s.phase.value,
            "link_error": s.fault_reason or s.stats.last_error,
            "robot_connected": s.connected,
        }
