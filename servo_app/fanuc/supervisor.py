"""The servo process's brain: the safety state machine driving the stream session and the servo cycle.

Pure (no sockets, no clock of its own): the runner hands it datagrams, requests and ``now``; it
returns the datagrams to send. Every decision about motion goes through
:func:`servo_app.safety.transition`, and every stop is the shaper's jerk-limited deceleration:

- requests (start, stop, resume, end, reset, jog, target) become safety events; refused ones raise
  :class:`CommandRejected` with the state machine's message and change nothing;
- hold-to-run: each jog renews a deadline; when it passes, ``JogExpired`` stops the arm;
- status packets feed ``StatusReceived``; silence feeds ``StatusLost``;
- the shaper reaching rest during a stop feeds ``ShaperAtRest``;
- a controller alarm (reported by whoever can see it, e.g. the embedded simulator) feeds
  ``ControllerAlarm`` and so a fault carrying the manual's cause and remedy.
"""

from __future__ import annotations

import signal as _signal
from typing import Any

import numpy as np

from servo_app.errors import CommandRejected
from servo_app.fanuc.alarms import ALARMS
from servo_app.fanuc.packets import LimitTableResponse, Status
from servo_app.fanuc.session import IoRequest, Phase, SessionConfig, StreamSession
from servo_app.input_slot import POSE, TWIST, InputCommand
from servo_app.motion.commands import PoseTarget, Twist
from servo_app.motion.servo import ServoCycle
from servo_app.safety import (
    AbandonStream,
    Action,
    BeginDeceleration,
    ConnectRequested,
    ControllerAlarm,
    EndRequested,
    Event,
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
    transition,
)
from servo_app.supervision import SupervisorBase

JOG_EXPIRED = "hold-to-run expired"  # the state machine's stop reason for JogExpired


class StreamSupervisor(SupervisorBase):
    def alarm_event(self, code: str, message: str) -> ControllerAlarm:
        spec = ALARMS.get(code)  # an unknown code still stops: the state machine words it generically
        if spec is None:
            return ControllerAlarm(code=code, message=message)
        return ControllerAlarm(code=code, message=message, warning=spec.warning, cause=spec.cause,
                               remedy=spec.remedy)

    def __init__(self, cycle: ServoCycle, session_config: SessionConfig | None = None) -> None:
        super().__init__(min_input_hold_s=0.02)
        self.cycle = cycle
        self.session = StreamSession(cycle, session_config or SessionConfig())
        self.hold = HoldToRun(timeout_s=0.2)
        self._now = 0.0
        self._out: list[bytes] = []

    # ------------------------------------------------------------------ events
    def _feed(self, event: Event, now: float) -> str | None:
        t = transition(self.state, event)
        if t.state != self.state:
            self.log.transitions.append((now, self.state.mode.value, t.state.mode.value, type(event).__name__))
            self.changed = True
        self.state = t.state
        for action in t.actions:
            self._do(action, now)
        return t.error

    def _do(self, action: Action, now: float) -> None:
        s, c = self.session, self.cycle
        if isinstance(action, StartStatusOutput):
            if not s.output_on:
                self._out += s.open(now)
        elif isinstance(action, StopStatusOutput):
            if s.output_on:
                self._out += s.close_now()
        elif isinstance(action, SendFirstCommand):
            s.arm()
        elif isinstance(action, BeginDeceleration):
            if c.shaper is not None:
                c.stop(fast=action.fast)
            reason = self.state.stop_reason or "stop"
            self.log.stops[reason] = self.log.stops.get(reason, 0) + 1
            self.hold = self.hold.release()
        elif isinstance(action, ResumeMotion):
            c.resume()
        elif isinstance(action, SendLastData):
            s.request_end()
        elif isinstance(action, AbandonStream):
            s.abandon(self.state.fault.message if self.state.fault else "stream abandoned", now)
            self.hold = self.hold.release()
        elif isinstance(action, RecordFault):
            self.changed = True
        elif isinstance(action, ReportWarning):
            self.log.warnings.append({"code": action.code, "message": action.message})
        # HoldPosition: the shaper holds by itself once at rest.

    # ----------------------------------------------------------------- requests
    def request(self, op: str, now: float, **kw: Any) -> Any:
        """Carry out one request from the API; raises CommandRejected with a clear message if refused."""
        self._now = now
        if op == "start":
            return self._start(now)
        if op == "stop":
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
            self._jog(np.asarray(kw["joints"], dtype=float), float(kw.get("hold_s", 0.2)), now)
        elif op == "twist":
            try:
                cmd = Twist(source=str(kw.get("source", "api")), stamp=now, frame=kw.get("frame", "base"),
                            linear=tuple(kw.get("linear", (0.0, 0.0, 0.0))),
                            angular=tuple(kw.get("angular", (0.0, 0.0, 0.0))))
            except ValueError as exc:
                raise CommandRejected(str(exc)) from None
            self._hold_to_run(float(kw.get("hold_s", 0.2)), now, "twist")
            self.cycle.twist(cmd)
        elif op == "pose":
            try:
                pose = PoseTarget(source=str(kw.get("source", "api")), stamp=now, xyzwpr=tuple(kw["xyzwpr"]),
                                  linear_speed=float(kw.get("linear_speed", 100.0)),
                                  angular_speed=float(kw.get("angular_speed", 30.0)))
            except ValueError as exc:
                raise CommandRejected(str(exc)) from None
            self._motion_gate("pose target")
            self.cycle.pose_target(pose)
        elif op == "target":
            self._motion_gate("target")
            self.cycle.set_joint_target(np.asarray(kw["joints"], dtype=float), float(kw.get("speed_scale", 1.0)))
        elif op == "inputs":
            self.inputs.configure(kw.get("enable", False), kw.get("sources"))
            self.changed = True
        elif op == "io_read":
            self.session.io_read = IoRequest(int(kw["type"]), int(kw["index"]), int(kw.get("mask", 0xFFFF)))
        elif op == "io_write":
            if not self.session.phase == Phase.STREAMING:
                raise CommandRejected("I/O is written through command packets: only while streaming")
            self.session.write_io(IoRequest(int(kw["type"]), int(kw["index"]), int(kw.get("mask", 0xFFFF)),
                                            int(kw["value"])))
        else:
            raise CommandRejected(f"op={op!r} is unknown")
        return None

    def _start(self, now: float) -> None:
        mode = self.state.mode
        if mode in (Mode.STREAMING, Mode.STOPPING, Mode.STOPPED, Mode.ENDING):
            raise CommandRejected(f"StartRequested refused in {mode.value}: a stream is already running")
        if mode == Mode.FAULT:
            raise CommandRejected("StartRequested refused in fault: reset first")
        if self.state.shutdown:
            raise CommandRejected("StartRequested refused: the service is shutting down")
        if mode == Mode.READY or (mode == Mode.ENDED and self.state.status and self.state.status.waiting):
            self._request(StartRequested(), now)
            return
        # Status output first; StartRequested follows when the controller shows it is waiting.
        self._feed(ConnectRequested(), now)
        self._start_pending = True

    def _jog(self, v: np.ndarray, hold_s: float, now: float) -> None:
        self._hold_to_run(hold_s, now, "jog")
        self.cycle.jog_joints(v)

    def _hold_to_run(self, hold_s: float, now: float, what: str) -> None:
        """Gate a hold-to-run motion and renew its deadline."""
        if not 0.0 < hold_s <= 2.0:
            raise CommandRejected(f"hold_s={hold_s} must be in (0, 2]")
        # A new press after the hold-to-run ran out resumes by itself; any other stop needs a resume.
        reason = self.state.stop_reason or ""
        if self.state.mode in (Mode.STOPPED, Mode.STOPPING) and reason.startswith(JOG_EXPIRED):
            self._request(ResumeRequested(), now)
        self._motion_gate(what)
        self.hold = HoldToRun(timeout_s=hold_s).renew(now)

    def on_late_input(self, cmd: InputCommand, now: float) -> bool:
        """A command that reached the slot while this cycle's IK was solving (``ServoCycle.late_command``).

        Only a new twist or pose target for an arm streaming under input control is taken now (True);
        anything that changes the safety state (stale, nothing live) or needs a gate (enable, resume)
        waits for the next status packet's regular read, where it is handled in order."""
        if not (self.inputs.enabled and self.state.mode == Mode.STREAMING and not cmd.stale
                and cmd.kind in (TWIST, POSE)):
            return False
        self.on_input(cmd, now)
        return True

    def _input_move(self, cmd: InputCommand, name: str, hold: float, now: float) -> None:
        if cmd.kind == TWIST:
            twist = Twist(source=name, stamp=cmd.stamp, frame=cmd.frame, linear=cmd.values[:3],  # type: ignore[arg-type]
                          angular=cmd.values[3:6])
            self._hold_to_run(hold, now, f"input {name}")
            self.cycle.twist(twist)
        else:
            pose = PoseTarget(source=name, stamp=cmd.stamp, xyzwpr=cmd.values[:6],  # type: ignore[arg-type]
                              linear_speed=cmd.linear_speed, angular_speed=cmd.angular_speed)
            self._hold_to_run(hold, now, f"input {name}")
            self.cycle.pose_target(pose)

    def signal(self, sig: int, now: float) -> list[bytes]:
        self._out = []
        self._feed(Signal(sig=sig), now)
        return self._take()

    @property
    def finished(self) -> bool:
        """After a signal: the stream ended (or never ran) and the status output is off."""
        return self.state.shutdown and safe_to_exit(self.state) and not self.session.output_on

    # ------------------------------------------------------------------ cycle
    def on_datagram(self, data: bytes, now: float) -> list[bytes]:
        self._out = []
        packet = self.session.decode(data)
        if packet is None:
            return []
        if isinstance(packet, Status):
            self._on_status_before(packet, now)
        self._out += self.session.on_packet(packet, now)
        if isinstance(packet, Status):
            self._after_status(packet, now)
        elif isinstance(packet, LimitTableResponse):
            pass
        return self._take()

    def _on_status_before(self, st: Status, now: float) -> None:
        prev = self.session.last_status
        if prev is not None and prev.seq == st.seq:
            return  # a duplicate carries no news
        self._feed(StatusReceived(bit0=st.waiting_for_command, bit1=st.command_received, sysrdy=st.sysrdy,
                                  moving=st.moving), now)
        # A start after an ended stream stays in ended (not ready) while the controller comes back to
        # IBGN start: the waiting status there is as good as ready.
        st_bits = self.state.status
        ready = self.state.mode == Mode.READY or (self.state.mode == Mode.ENDED and st_bits is not None
                                                  and st_bits.waiting)
        if self._start_pending and ready and self.session.phase != Phase.FETCHING_TABLES:
            self._start_pending = False
            self._feed(StartRequested(), now)
        # Hold-to-run and rest are judged before the command for this status is computed.
        self.hold, expired = self.hold.poll(now)
        if expired is not None and self.state.mode == Mode.STREAMING:
            self._feed(JogExpired(), now)

    def _after_status(self, st: Status, now: float) -> None:
        if self.state.mode == Mode.STOPPING and self.cycle.at_rest():
            self._feed(ShaperAtRest(), now)
        if self.session.phase == Phase.CLOSED and self.state.mode == Mode.ENDING:
            self._feed(StatusReceived(bit0=st.waiting_for_command, bit1=st.command_received, sysrdy=st.sysrdy),
                       now)
        if self.session.phase == Phase.FAULT and self.state.mode in (Mode.STREAMING, Mode.STOPPING,
                                                                    Mode.STOPPED, Mode.ENDING):
            self._feed(StatusLost(detail=self.session.fault_reason), now)

    def on_idle(self, now: float) -> list[bytes]:
        self._out = []
        self.session.on_idle(now)
        if self.session.phase == Phase.FAULT and self.state.mode not in (Mode.FAULT, Mode.DISCONNECTED,
                                                                        Mode.ENDED):
            self._feed(StatusLost(detail=self.session.fault_reason), now)
        elif (self.session.phase == Phase.CLOSED and self.state.mode == Mode.ENDED
              and self.state.status is not None):
            self._feed(StatusLost(detail="status output stopped"), now)
        return self._take()

    def _take(self) -> list[bytes]:
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ views
    def describe(self) -> dict[str, Any]:
        return {
            **self._safety_view(),
            "link": self.session.phase.value,
            "link_error": self.session.fault_reason or self.session.stats.last_error,
            "inputs_enabled": self.inputs.enabled,
            "input_error": self.inputs.error,
        }


SIGNALS = {int(_signal.SIGTERM), int(_signal.SIGINT)}
