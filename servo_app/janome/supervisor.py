"""The Janome servo process's brain: the shared safety state machine driving the link session.

Pure (no sockets, no clock of its own), the counterpart of ``servo_app.fanuc.supervisor``: the runner
hands it connection events, bytes, requests and ``now``; it returns the frames to send. Every decision
about motion goes through :func:`servo_app.safety.transition`:

- requests (start, stop, resume, end, reset, jog, target) become safety events; refused ones raise
  :class:`CommandRejected` with the state machine's message and change nothing;
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

import signal as _signal
from dataclasses import replace
from typing import Any

import numpy as np

from servo_app.errors import CommandRejected
from servo_app.input_slot import TWIST, InputCommand
from servo_app.janome.alarms import (
    LINK_LOST,
    LINK_TIMEOUT,
    PROTOCOL,
    ROBOT_LEFT,
    JanomeAlarm,
    alarm_code,
    alarm_for_code,
)
from servo_app.janome.motion import JanomeMotion
from servo_app.janome.protocol import FrameError, RobotState, Status
from servo_app.janome.session import JanomeSession, Phase, SessionConfig
from servo_app.safety import (
    AbandonStream,
    Action,
    BeginDeceleration,
    ConnectRequested,
    ControllerAlarm,
    Disconnected,
    EndRequested,
    Event,
    FaultInfo,
    HoldToRun,
    JogExpired,
    LeaseLost,
    Mode,
    RecordFault,
    ReportWarning,
    ResetRequested,
    ResumeMotion,
    ResumeRequested,
    SendFirstCommand,
    SendLastData,
    ShaperAtRest,
    Signal,
    StartRequested,
    StartStatusOutput,
    StatusLost,
    StatusReceived,
    StopRequested,
    StopStatusOutput,
    safe_to_exit,
    stream_alive,
    transition,
)
from servo_app.supervision import SupervisorBase

JOG_EXPIRED = "hold-to-run expired"  # the state machine's stop reason for JogExpired


class JanomeSupervisor(SupervisorBase):
    def alarm_event(self, code: str, message: str) -> ControllerAlarm:
        spec = alarm_for_code(code)  # JNM-nnn; any other code stops with the generic texts
        if spec is None:
            return ControllerAlarm(code=code, message=message)
        return ControllerAlarm(code=code, message=message, cause=spec.cause, remedy=spec.remedy)

    def __init__(self, motion: JanomeMotion, session_config: SessionConfig | None = None,
                 hold_s: float = 0.5) -> None:
        super().__init__(min_input_hold_s=0.05)
        self.motion = motion
        self.session = JanomeSession(motion, session_config or SessionConfig(kind=motion.profile.kind))
        self.default_hold_s = hold_s
        self.hold = HoldToRun(timeout_s=hold_s)

    # ------------------------------------------------------------------ events
    def _feed(self, event: Event, now: float, alarm: JanomeAlarm | None = None,
              message: str | None = None) -> str | None:
        before = self.state
        t = transition(before, event)
        state = t.state
        fault = state.fault
        if fault is not None and fault != before.fault:
            state = replace(state, fault=self._janome_fault(fault, alarm, message))
        if state != before:
            self.log.transitions.append((now, before.mode.value, state.mode.value, type(event).__name__))
            self.changed = True
        self.state = state
        for action in t.actions:
            self._do(action, now)
        return t.error

    @staticmethod
    def _janome_fault(fault: FaultInfo, alarm: JanomeAlarm | None, message: str | None) -> FaultInfo:
        """Replace the state machine's FANUC wording where the cause is Janome's."""
        if fault.code is not None:
            spec = alarm_for_code(fault.code)
            return fault if spec is None else replace(fault, cause=spec.cause, remedy=spec.remedy)
        if alarm is None:
            return fault
        return replace(fault, message=message or fault.message, cause=alarm.cause, remedy=alarm.remedy)

    def _do(self, action: Action, now: float) -> None:
        s, m = self.session, self.motion
        if isinstance(action, StartStatusOutput):
            s.accepting = True
        elif isinstance(action, StopStatusOutput):
            s.close("service shutting down")
        elif isinstance(action, SendFirstCommand):
            s.arm()
        elif isinstance(action, BeginDeceleration):
            if m.shaper is not None:
                m.stop(fast=action.fast)
            reason = self.state.stop_reason or "stop"
            self.log.stops[reason] = self.log.stops.get(reason, 0) + 1
            self.hold = self.hold.release()
        elif isinstance(action, ResumeMotion):
            m.resume()
        elif isinstance(action, SendLastData):
            s.request_end()
        elif isinstance(action, AbandonStream):
            s.abandon(self.state.fault.message if self.state.fault else "stream abandoned")
            self.hold = self.hold.release()
        elif isinstance(action, RecordFault):
            self.changed = True
        elif isinstance(action, ReportWarning):
            self._warn(action.code, action.message, now)

    def _warn(self, code: str, message: str, now: float) -> None:
        self.log.warnings.append({"code": code, "message": message, "t": now})
        del self.log.warnings[:-50]

    # ----------------------------------------------------------------- requests
    def request(self, op: str, now: float, **kw: Any) -> Any:
        """Carry out one request from the API; raises CommandRejected with a clear message if refused."""
        if op == "start":
            self._start(now)
        elif op == "stop":
            self._request(StopRequested(reason=str(kw.get("reason", "stop requested")),
                                        fast=bool(kw.get("fast", False))), now)
        elif op == "resume":
            self._request(ResumeRequested(), now)
        elif op == "end":
            self._start_pending = False
            self._request(EndRequested(), now)
        elif op == "reset":
            self._request(ResetRequested(), now)
        elif op == "lease_lost":
            self._feed(LeaseLost(holder=str(kw.get("holder", ""))), now)
        elif op == "controller_alarm":
            self._feed(self.alarm_event(str(kw["code"]), str(kw.get("message", ""))), now)
        elif op == "jog":
            self._jog(np.asarray(kw["joints"], dtype=float), float(kw.get("hold_s", self.default_hold_s)), now)
        elif op == "target":
            self._motion_gate("target")
            self.motion.set_target(np.asarray(kw["joints"], dtype=float), float(kw.get("speed_scale", 1.0)))
        elif op == "inputs":
            self.inputs.configure(kw.get("enable", False), kw.get("sources"))
            self.changed = True
        else:
            raise CommandRejected(f"op={op!r} is unknown (start, stop, resume, end, reset, jog, target)")
        return None

    def _start(self, now: float) -> None:
        mode, status = self.state.mode, self.state.status
        if mode == Mode.READY or (mode == Mode.ENDED and status is not None and status.waiting):
            self._request(StartRequested(), now)
        elif mode in (Mode.DISCONNECTED, Mode.ENDED) and not self.state.shutdown:
            # Accept the robot's connection; streaming starts when its point job says HELLO.
            self._feed(ConnectRequested(), now)
            self._start_pending = True
        else:
            self._request(StartRequested(), now)  # refused, with the state machine's reason

    def _jog(self, v: np.ndarray, hold_s: float, now: float) -> None:
        reason = self.state.stop_reason or ""
        if self.state.mode in (Mode.STOPPED, Mode.STOPPING) and reason.startswith(JOG_EXPIRED):
            self._request(ResumeRequested(), now)
        self._motion_gate("jog")
        if not (np.isfinite(hold_s) and hold_s > 0):
            raise CommandRejected(f"hold_s={hold_s} must be > 0")
        self.motion.jog(v)
        self.hold = HoldToRun(timeout_s=hold_s).renew(now)

    def _input_move(self, cmd: InputCommand, name: str, hold: float, now: float) -> None:
        """A twist jogs X Y Z (mm/s) and R (its rotation about Z, deg/s); a pose input is an absolute
        X Y Z R target (W and P have no axis here)."""
        v = cmd.values
        xyzr = np.array([v[0], v[1], v[2], v[5]])
        if cmd.kind == TWIST:
            self._jog(xyzr, hold, now)
        else:
            self._motion_gate(f"input {name}")
            self.motion.set_target(xyzr, 1.0)
            self.hold = HoldToRun(timeout_s=hold).renew(now)

    def signal(self, sig: int, now: float) -> None:
        self._feed(Signal(sig=sig), now)

    @property
    def finished(self) -> bool:
        """After a signal: no stream left and no robot connected."""
        return self.state.shutdown and safe_to_exit(self.state) and not self.session.connected

    # ------------------------------------------------------------------ link
    def on_connect(self, now: float) -> None:
        self.session.on_connect(now)

    def on_disconnect(self, reason: str, now: float) -> None:
        self.session.on_disconnect(reason, now)
        self._feed(Disconnected(detail=reason), now, LINK_LOST,
                   f"connection lost while {self.state.mode.value}: {reason}")

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
        self.hold, expired = self.hold.poll(now)
        if expired is not None and self.state.mode == Mode.STREAMING:
            self._feed(JogExpired(), now)
        return s.on_status(st, now)

    def _status_event(self, st: Status, now: float) -> None:
        bye = st.state == RobotState.BYE
        message = f"robot left its loop (BYE, error={st.error.name}) while {self.state.mode.value}" if bye else None
        self._feed(StatusReceived(bit0=not bye, bit1=False, sysrdy=True), now, ROBOT_LEFT, message)
        if self._start_pending and not bye and self.state.mode in (Mode.READY, Mode.ENDED) \
                and self.state.status is not None and self.state.status.waiting:
            self._start_pending = False
            self._feed(StartRequested(), now)

    def _after(self, now: float) -> None:
        s = self.session
        for w in s.warnings:
            self._warn("link", w, now)
        s.warnings.clear()
        if s.pending_alarm is not None:
            a, s.pending_alarm = s.pending_alarm, None
            self._feed(self.alarm_event(alarm_code(a.error), a.message), now)
        if s.phase == Phase.FAULT and stream_alive(self.state):
            self._feed(StatusLost(detail=s.fault_reason), now, PROTOCOL if "malformed" in s.fault_reason
                       or "acknowledges" in s.fault_reason or "HELLO" in s.fault_reason else LINK_TIMEOUT,
                       f"link failed while {self.state.mode.value}: {s.fault_reason}")

    def on_idle(self, now: float) -> None:
        self.session.on_idle(now)
        self.hold, expired = self.hold.poll(now)
        if expired is not None and self.state.mode == Mode.STREAMING:
            self._feed(JogExpired(), now)
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


SIGNALS = {int(_signal.SIGTERM), int(_signal.SIGINT)}
