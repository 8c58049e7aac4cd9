"""The generic supervisor: what every servo-process supervisor does, whatever the robot's protocol.

A backend's supervisor (FANUC's :class:`~servo_app.fanuc.supervisor.StreamSupervisor`, Janome's
:class:`~servo_app.janome.supervisor.JanomeSupervisor`) subclasses :class:`SupervisorBase` and
supplies its link (``_link_*``: open, close, arm, end, abandon), its motion stage (``self.motion``:
``stop``, ``resume``, ``shaper``) and the requests only it understands. Everything else is here:

- typed requests (:mod:`servo_app.messages`) dispatched by type. A request is checked whole before
  anything changes: its own values first (count, ranges, plausibility: :class:`InvalidRequest`), then
  the state (:class:`CommandRejected`, whose text ends with the next step: :func:`next_step`). A
  refused request changes nothing: no resume, no hold-to-run timer;
- every safety event goes through :func:`servo_app.safety.transition`, and its actions are carried out
  in order (decelerate, resume, abandon, record);
- a start waits for the controller: ``start_pending`` until the stream runs, or until it is given up
  (the link failed, a status shows SYSRDY off past ``SYSRDY_GRACE_S``, or ``start_timeout_s``
  passed), with ``start_error`` saying why;
- hold-to-run, the motion gate, input control (a stale source stops a streaming arm), and the safety
  part of ``describe()``.

Pure: no sockets, no clock of its own (``now`` comes in with every call).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Protocol

import numpy as np

from servo_app import messages as msg
from servo_app.errors import CommandRejected, InvalidRequest
from servo_app.input_slot import InputCommand, InputControl
from servo_app.motion.commands import check_speed_scale
from servo_app.safety import (
    STREAM_ALIVE,
    AbandonStream,
    Action,
    BeginDeceleration,
    ConnectRequested,
    ControllerAlarm,
    EndRequested,
    Event,
    FaultInfo,
    HoldToRun,
    InputStale,
    JogExpired,
    LeaseLost,
    Mode,
    RecordFault,
    ReportWarning,
    ResetRequested,
    ResumeMotion,
    ResumeRequested,
    SafetyState,
    SendFirstCommand,
    SendLastData,
    StartRequested,
    StartStatusOutput,
    StopRequested,
    StopStatusOutput,
    Then,
    motion_allowed,
    safe_to_exit,
    transition,
)

JOG_EXPIRED = "hold-to-run expired"  # the state machine's stop reason for JogExpired

# The API's way to each next step, named in every refusal by the state (409).
START = "start a session first: POST /api/session/start"
START_NEW = "start a new session: POST /api/session/start"
RESUME = "resume: POST /api/session/resume"
RESET = "reset the fault: POST /api/reset"
ACKNOWLEDGE = "acknowledge the fast stop: POST /api/reset, then resume: POST /api/session/resume"
END_FIRST = "end it first: POST /api/session/end"
MOVE = "nothing to do: it streams; jog (POST /api/jog) or send a target (POST /api/target)"
# The state machine's event names, as the operator calls the request.
_ACTIONS = {"StartRequested": "start", "ResumeRequested": "resume", "EndRequested": "end",
            "ResetRequested": "reset", "ConnectRequested": "connect", "DisconnectRequested": "disconnect"}


def stop_kind(reason: str) -> str:
    """A stop reason without its particulars, for the stops counted by reason (a Prometheus label):
    "control lease lost (alice)" -> "control lease lost", "limit approaching: J3 ..." -> "limit approaching".
    Holder names come from clients and details carry numbers: counted whole, every new one was a new
    label, growing without bound. The state's ``stop_reason`` keeps them."""
    return reason.split(" (", 1)[0].split(": ", 1)[0].strip() or "stop"


def next_step(state: SafetyState, request: str = "motion") -> str:
    """What the operator does next when ``request`` (motion, start, resume, end, reset) is refused in
    ``state``: the end of every 409 text."""
    m, stop = state.mode, state.stop
    if state.shutdown:
        return "the servo process is shutting down: restart the service"
    if m is Mode.FAULT:
        return RESET
    if m in (Mode.DISCONNECTED, Mode.CONNECTED, Mode.READY):
        return START
    if m in (Mode.ENDING, Mode.ENDED) or (stop is not None and stop.then is Then.END):
        return START_NEW if m is Mode.ENDED else "wait until it has ended, then " + START_NEW
    if m in (Mode.STOPPING, Mode.STOPPED):
        if stop is not None and stop.fast:
            return ACKNOWLEDGE if m is Mode.STOPPED else "wait for rest, then " + ACKNOWLEDGE
        return RESUME
    # streaming
    if request == "start":
        return "a stream is already running; " + END_FIRST
    return MOVE


class MotionStage(Protocol):
    """What the supervisor asks of a backend's motion stage (FANUC's servo cycle, Janome's stepper)."""

    shaper: Any  # not None while a stream runs (its motion state)

    def stop(self, fast: bool = False) -> None: ...

    def resume(self) -> None: ...

    def at_rest(self) -> bool: ...


@dataclass
class SupervisorLog:
    """What happened, for the parent process and the API (fault texts, warnings, stops)."""

    transitions: list[tuple[float, str, str, str]] = field(default_factory=list)  # (t, from, to, event)
    warnings: list[dict[str, Any]] = field(default_factory=list)  # the last 50, across resets
    # Those active now: since the last reset or new stream, as the service's active alarms are.
    active_warnings: list[dict[str, Any]] = field(default_factory=list)
    stops: dict[str, int] = field(default_factory=dict)


def not_waiting_why(state: SafetyState) -> str:
    """Why a start cannot begin streaming yet, for the operator."""
    status = state.status
    if status is None:
        return "no status from the controller: check that it is running and reachable"
    if not status.sysrdy:
        return "SYSRDY is off (servo power not ready)"
    if not status.bit0:
        return "the controller is not waiting for commands: start its streaming program"
    return "the controller already received commands in this program run: restart the program"


# A start is given up on a status with SYSRDY off only this long after it was asked: a reset just
# before it (POST /api/reset, or RESET at the pendant) brings servo power back, but a status sent
# before that reset, or its first interval after, may still show SYSRDY off. Past this, SYSRDY off
# needs the operator: waiting the whole start_timeout_s for it only delayed the answer (5 s).
SYSRDY_GRACE_S = 0.5
SYSRDY_OFF = ("SYSRDY is off (servo power not ready) in the controller's status: an emergency stop, an "
              "open fence, a released deadman switch or an alarm holds servo power off; clear its cause "
              "at the controller (release the stop, reset the alarm at the teach pendant, or POST "
              "/api/reset for the embedded controller) until not_ready in GET /api/state is empty")


def not_ready(state: SafetyState) -> str | None:
    """Why a start would wait now, while status flows but does not show the controller waiting (an alarm
    held with SYSRDY off, no streaming program running, ...); None when it is ready or has no status."""
    status = state.status
    if status is None or status.waiting or state.mode not in (Mode.CONNECTED, Mode.ENDED):
        return None
    return not_waiting_why(state)


def axis_values(name: str, values: Any) -> np.ndarray:
    """``values`` as a vector of finite numbers; InvalidRequest naming the first bad one."""
    try:
        v = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidRequest(f"{name}={values!r} must be a list of numbers") from None
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        raise InvalidRequest(f"{name}[{int(bad[0])}]={v[bad[0]]} is not a finite number")
    return v


def check_count(name: str, v: np.ndarray, n: int, axes: str) -> None:
    if v.size != n:
        raise InvalidRequest(f"{name} has {v.size} values, expected {n} ({axes})")


def check_speeds(name: str, v: np.ndarray, limits: Any, axis_names: list[str], units: list[str],
                 source: str) -> None:
    """Each |v[i]| within its axis's speed limit; InvalidRequest naming the axis and the limit."""
    for i, (x, lim) in enumerate(zip(v, limits, strict=False)):
        if abs(x) > lim:
            raise InvalidRequest(f"{name}[{i}]={x:g} {units[i]} is faster than {axis_names[i]}'s speed limit "
                                 f"{float(lim):.4g} {units[i]} ({source}); send at most {float(lim):.4g} {units[i]}")


class SupervisorBase:
    motion: MotionStage
    # The backend's link session: ``link_phase`` reads its ``phase`` (a StrEnum of servo_app.state.PHASES
    # values, which the servo process host also reads directly every cycle) and ``fault_reason``.
    session: Any
    default_hold_s: float = 0.2
    max_hold_s: float = 2.0

    def __init__(self, min_input_hold_s: float, hold_s: float | None = None, start_timeout_s: float = 5.0) -> None:
        self.state = SafetyState()
        self.log = SupervisorLog()
        self.inputs = InputControl(min_hold_s=min_input_hold_s)
        if hold_s is not None:
            self.default_hold_s = hold_s
        self.hold = HoldToRun(timeout_s=self.default_hold_s)
        self.changed = False  # set when the safety state changed; the runner clears it after publishing
        # Set by a new warning, which changes no state (ReportWarning): the runner publishes the view for
        # it too, coalesced (process_handle.WARNINGS_PUBLISH_S), and clears it with ``changed``.
        self.warned = False
        self.start_timeout_s = start_timeout_s
        self.start_pending = False  # a start waits for the controller (read by the host every cycle)
        self._start_deadline = 0.0
        self._start_asked = 0.0  # when the pending start was asked (for SYSRDY_GRACE_S)
        self.start_error = ""  # why the last start was given up
        self._fed_actions: tuple[Action, ...] = ()

    # ------------------------------------------------------------ what each backend implements
    def _link_open(self, now: float) -> None:
        """Status output on (FANUC) / accept the robot's connection (Janome)."""
        raise NotImplementedError

    def _link_close(self) -> None:
        raise NotImplementedError

    def _link_arm(self) -> None:
        """Stream from the next status that shows the controller waiting."""
        raise NotImplementedError

    def _link_end(self) -> None:
        """Decelerate to rest, then last data."""
        raise NotImplementedError

    def _link_abandon(self, reason: str, now: float) -> None:
        """Send no further command: the controller stopped or will alarm."""
        raise NotImplementedError

    def _link_recover(self, now: float) -> None:
        """The fault was reset: make a failed link usable for the next start."""

    def _link_failure(self) -> str:
        """Why the link failed, if it has (a pending start gives up at once); empty while it is fine."""
        return ""

    def alarm_event(self, code: str, message: str) -> ControllerAlarm:
        """A controller alarm as a safety event, with the backend's catalogue entry."""
        return ControllerAlarm(code=code, message=message)

    def _word_fault(self, fault: FaultInfo, context: dict[str, Any]) -> FaultInfo:
        """A new fault in the backend's own words (``context`` comes from ``_feed``'s keywords)."""
        return fault

    def _input_move(self, cmd: InputCommand, name: str, hold: float, now: float) -> None:
        """Move as a live input command asks (its hold-to-run renewed for ``hold`` seconds)."""
        raise NotImplementedError

    def _jog_axes(self, v: np.ndarray) -> None:
        """Jog each axis at ``v`` (the backend's units per second); the gate has been passed. By
        default the motion stage's ``jog``."""
        self.motion.jog(v)  # type: ignore[attr-defined]

    def _joint_target(self, q: np.ndarray, speed_scale: float) -> None:
        """Move every axis to ``q``; the gate has been passed. By default the stage's ``set_target``."""
        self.motion.set_target(q, speed_scale)  # type: ignore[attr-defined]

    def _check_jog(self, v: np.ndarray) -> np.ndarray:
        """The axis velocities of a jog, checked (count, speed limits) before anything changes; raises
        InvalidRequest naming the axis and its limit. Nothing is checked by default."""
        return v

    def _check_joint_target(self, q: np.ndarray, speed_scale: float) -> None:
        """Check a joint target (count, ranges, reach from here) before anything changes; raises
        InvalidRequest. Nothing is checked by default."""

    # ------------------------------------------------------------------------------ safety events
    def _feed(self, event: Event, now: float, **context: Any) -> str | None:
        """Apply one safety event and carry out its actions; the refusal text, if refused."""
        before = self.state
        t = transition(before, event)
        state = t.state
        if state.fault is not None and state.fault != before.fault:
            state = replace(state, fault=self._word_fault(state.fault, context))
        if state != before:
            self.log.transitions.append((now, before.mode.value, state.mode.value, type(event).__name__))
            self.changed = True
            if state.mode is Mode.STREAMING and before.mode not in STREAM_ALIVE:  # a new stream, not a resume
                self.log.active_warnings.clear()
        self.state = state
        for action in t.actions:
            self._do(action, now)
        self._fed_actions = t.actions  # what this event set off (none, and the state kept: a fixed point)
        return t.error

    def _do(self, action: Action, now: float) -> None:
        if isinstance(action, StartStatusOutput):
            self._link_open(now)
        elif isinstance(action, StopStatusOutput):
            self._link_close()
        elif isinstance(action, SendFirstCommand):
            self._link_arm()
        elif isinstance(action, BeginDeceleration):
            if self.motion.shaper is not None:
                self.motion.stop(fast=action.fast)
            reason = stop_kind(self.state.stop_reason or "stop")
            self.log.stops[reason] = self.log.stops.get(reason, 0) + 1
            self.hold = self.hold.release()
        elif isinstance(action, ResumeMotion):
            self.motion.resume()
        elif isinstance(action, SendLastData):
            self._link_end()
        elif isinstance(action, AbandonStream):
            self._link_abandon(self.state.fault.message if self.state.fault else "stream abandoned", now)
            self.hold = self.hold.release()
        elif isinstance(action, RecordFault):
            self.changed = True
        elif isinstance(action, ReportWarning):
            self._warn(action.code, action.message, now)
        # HoldPosition: the motion stage holds by itself once at rest.

    def _warn(self, code: str, message: str, now: float) -> None:
        item = {"code": code, "message": message, "t": now}
        for kept in (self.log.warnings, self.log.active_warnings):
            kept.append(item)
            del kept[:-50]
        self.warned = True

    def _request(self, event: Event, now: float) -> None:
        name = type(event).__name__
        err = self._feed(event, now)
        if err:
            action = _ACTIONS.get(name, name)
            raise CommandRejected(f"{err.replace(name, action, 1)}; {next_step(self.state, action)}")

    # ---------------------------------------------------------------------------------- requests
    _HANDLERS: ClassVar[dict[type, Callable[[Any, Any, float], Any]]] = {}

    def request(self, req: msg.Request, now: float) -> Any:
        """Carry out one request from the service; raises CommandRejected with a clear message if refused."""
        handler = type(self)._HANDLERS.get(type(req))
        if handler is None:
            raise InvalidRequest(f"{type(req).__name__} is not supported by this robot's backend")
        return handler(self, req, now)

    def _on_start(self, req: msg.Start, now: float) -> None:
        mode = self.state.mode
        if mode in STREAM_ALIVE:
            raise CommandRejected(f"start refused in {mode.value}: a stream is already running; {END_FIRST}")
        if mode == Mode.FAULT:
            raise CommandRejected(f"start refused in fault; {RESET}, then start")
        if self.state.shutdown:
            raise CommandRejected("start refused: the service is shutting down; restart the service")
        if self._link_failure():
            # Not in fault, so the link failed in an earlier start: it starts afresh (a new status output
            # start), and this start neither gives up at once on that start's reason nor streams from it.
            self._link_recover(now)
            mode = self.state.mode
        if mode == Mode.READY or (mode == Mode.ENDED and self.state.status and self.state.status.waiting):
            self._request(StartRequested(), now)
            return
        # Link first (status output on / accept the robot); StartRequested follows when the controller
        # shows it is waiting. Refused only where status already flows, which is as good.
        self._feed(ConnectRequested(), now)
        self.start_pending = True
        self._start_deadline = now + self.start_timeout_s
        self._start_asked = now
        self.start_error = ""

    def _on_stop(self, req: msg.Stop, now: float) -> str | None:
        """None: a stop of a streaming arm, requested. Where no stream moves the arm the stop is harmless
        and not refused (a STOP must never fail for being unneeded), but it says so: "fast stop requested"
        after the session had ended told the operator something had been moving."""
        mode = self.state.mode
        self._request(StopRequested(reason=req.reason, fast=bool(req.fast)), now)
        if mode in (Mode.STREAMING, Mode.STOPPING, Mode.STOPPED):
            return None
        if mode is Mode.ENDING:  # entered at rest: the last data is sent, the controller drains
            return "nothing was moving: the stream is ending at rest"
        return f"nothing was moving: no stream runs ({mode.value})"

    def _on_resume(self, req: msg.Resume, now: float) -> None:
        self._request(ResumeRequested(), now)

    def _on_end(self, req: msg.End, now: float) -> None:
        self._cancel_start("an end was requested")
        self._request(EndRequested(), now)

    def _on_reset(self, req: msg.Reset, now: float) -> None:
        was_fault = self.state.mode == Mode.FAULT
        self._request(ResetRequested(), now)
        # Taken (a refused reset changes nothing): it acknowledges the warnings too, as the service's
        # active alarms; a view that changes no mode (a fast stop's) is published for it all the same.
        if self.log.active_warnings:
            self.log.active_warnings.clear()
            self.changed = True
        self._link_acknowledge()
        if was_fault:
            self._link_recover(now)

    def _link_acknowledge(self) -> None:
        """A reset taken acknowledges the link's last error too (``link_error`` beside a link that is not
        faulted: a target the robot rejected and was sent again, a datagram refused): the console lists
        it as active beside the warnings, and it stood there until the next connection."""
        stats = getattr(self.session, "stats", None)
        if getattr(stats, "last_error", ""):
            stats.last_error = ""
            self.changed = True

    def _on_lease_lost(self, req: msg.LeaseLost, now: float) -> None:
        self._feed(LeaseLost(holder=req.holder), now)

    def _on_alarm(self, req: msg.ControllerAlarm, now: float) -> None:
        self._feed(self.alarm_event(req.code, req.message), now)

    def _on_jog(self, req: msg.Jog, now: float) -> None:
        # The whole request first: a refused one must not resume the stream or start a hold timer.
        v = self._check_jog(axis_values("joints", req.joints))
        hold_s = self.default_hold_s if req.hold_s is None else float(req.hold_s)
        self._hold_checked(hold_s)
        self._motion_gate("jog", resume_after_hold=True, now=now)
        self._jog_axes(v)
        self.hold = HoldToRun.renewed(hold_s, now)

    def _on_joint_target(self, req: msg.JointTarget, now: float) -> None:
        q = axis_values("joints", req.joints)
        speed_scale = check_speed_scale(req.speed_scale)
        self._check_joint_target(q, speed_scale)
        self._target_gate("target", now)
        self._joint_target(q, speed_scale)

    def _on_inputs(self, req: msg.ConfigureInputs, now: float) -> None:
        self.inputs.configure(bool(req.enable), list(req.sources) if req.sources is not None else None)
        self.changed = True

    _BASE_HANDLERS: ClassVar[dict[type, str]] = {
        msg.Start: "_on_start", msg.Stop: "_on_stop", msg.Resume: "_on_resume", msg.End: "_on_end",
        msg.Reset: "_on_reset", msg.LeaseLost: "_on_lease_lost", msg.ControllerAlarm: "_on_alarm",
        msg.Jog: "_on_jog", msg.JointTarget: "_on_joint_target", msg.ConfigureInputs: "_on_inputs",
    }

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        handlers = {t: getattr(cls, name) for t, name in SupervisorBase._BASE_HANDLERS.items()}
        handlers.update({t: getattr(cls, name) for t, name in getattr(cls, "REQUESTS", {}).items()})
        cls._HANDLERS = handlers

    # -------------------------------------------------------------------------------- the gates
    def _hold_checked(self, hold_s: float) -> None:
        if not (math.isfinite(hold_s) and 0.0 < hold_s <= self.max_hold_s):
            raise InvalidRequest(f"hold_s={hold_s} must be in (0, {self.max_hold_s:g}]")

    def _motion_gate(self, what: str, resume_after_hold: bool = False, now: float = 0.0) -> None:
        """Refuse motion unless the stream runs. A new press after the hold-to-run ran out resumes by
        itself; any other stop needs a resume. Call it once the request's own values are checked: the
        resume is the first change."""
        if resume_after_hold and self._resumable_by_press():
            self._request(ResumeRequested(), now)
        if not motion_allowed(self.state):
            raise CommandRejected(f"{what} refused in {self.state.mode.value}"
                                  + (f" (stopped: {self.state.stop_reason})" if self.state.stop_reason else "")
                                  + f"; {next_step(self.state)}")

    def _target_gate(self, what: str, now: float) -> None:
        """The gate for a target (joint or pose): after a hold-to-run stop it resumes the way a jog
        does, and it ends any hold-to-run still running (a target is not held: the jog it replaces
        must not stop it when that jog's hold runs out)."""
        self._motion_gate(what, resume_after_hold=True, now=now)
        self.hold = self.hold.release()

    def _resumable_by_press(self) -> bool:
        reason = self.state.stop_reason or ""
        return self.state.mode in (Mode.STOPPED, Mode.STOPPING) and reason.startswith(JOG_EXPIRED)

    def _hold_to_run(self, hold_s: float, now: float, what: str) -> None:
        """Gate a hold-to-run motion and renew its deadline."""
        self._hold_checked(hold_s)
        self._motion_gate(what, resume_after_hold=True, now=now)
        self.hold = HoldToRun.renewed(hold_s, now)

    def _poll_hold(self, now: float) -> None:
        # HoldToRun.poll's test without its (watch, event) pair: this runs on every status packet.
        hold = self.hold
        if hold.last_renewed is not None and hold.expired(now):
            self.hold = hold.release()
            if self.state.mode == Mode.STREAMING:
                self._feed(JogExpired(), now)

    # ------------------------------------------------------------------------------------ start
    def _start_when_ready(self, now: float) -> None:
        """Called on each new status: a pending start begins once the controller is waiting."""
        if not self.start_pending:  # the streaming case: nothing to look at
            return
        st = self.state.status
        if self.state.mode == Mode.READY or (self.state.mode == Mode.ENDED and st is not None and st.waiting):
            self.start_pending = False
            self._feed(StartRequested(), now)
        elif st is not None and not st.sysrdy and now - self._start_asked >= SYSRDY_GRACE_S:
            self._cancel_start(SYSRDY_OFF)  # (a status just received says so: not a stale one)

    def watch_start(self, now: float) -> None:
        """A pending start that cannot succeed is given up, with the reason, instead of waiting forever.
        One that found status still flowing (its link request refused) opens the link once status stops."""
        if not self.start_pending:
            return
        failure = self._link_failure()
        if failure:
            self._cancel_start(f"the link failed: {failure}")
        elif now > self._start_deadline:
            self._cancel_start(f"no stream within {self.start_timeout_s:g} s: {not_waiting_why(self.state)}")
        elif self.state.status is None and self._link_closed() and not self.state.shutdown:
            self._feed(ConnectRequested(), now)

    def log_failing(self, trouble: str, now: float) -> None:
        """The session log cannot take the stream much longer (its disk is full, or a write failed):
        a soft stop that ends the stream, named by ``trouble``, and a warning. Ended rather than held:
        a held stream logs every status too. A start under way is given up (the next one opens a new
        log, or is refused while the disk stays full)."""
        self._warn("SESSION-LOG", f"session log: {trouble}", now)
        self._cancel_start(f"the session log cannot be written: {trouble}")
        if self.state.mode in STREAM_ALIVE:
            self._feed(EndRequested(reason=f"session log: {trouble}"), now)
        self.changed = True

    def _cancel_start(self, why: str) -> None:
        if self.start_pending:
            self.start_pending = False
            self.start_error = why
            self.changed = True

    # ----------------------------------------------------------------------------------- inputs
    def on_input(self, cmd: InputCommand, now: float) -> None:
        """The inputs bridge's live command (read from shared memory when a status arrives)."""
        self.inputs.apply(cmd, lambda name: self._input_stale(name, now),
                          lambda c, name, hold: self._input_move(c, name, hold, now))

    def _input_stale(self, name: str, now: float) -> None:
        if self.state.mode == Mode.STREAMING:
            self._feed(InputStale(source=name), now)

    # ------------------------------------------------------------------------------------ views
    def _link_closed(self) -> bool:
        """Nothing is open on the link (or it is dead): a shut-down process may exit."""
        raise NotImplementedError

    def link_phase(self) -> tuple[str, str]:
        """The link's phase (one of :data:`servo_app.state.PHASES`) and, in fault, why."""
        # A session's phase is a StrEnum: str() is its value, without the enum's Python-level value
        # property (twice per loop iteration).
        return str(self.session.phase), self.session.fault_reason

    @property
    def finished(self) -> bool:
        """After a signal: no stream left and the link closed (or dead): the process may exit."""
        return self.state.shutdown and safe_to_exit(self.state) and self._link_closed()

    def _safety_view(self) -> dict[str, Any]:
        st = self.state
        fault = st.fault
        return {
            "state": st.mode.value,
            "stop_reason": st.stop_reason,
            "stop_fast": st.stop_fast,
            "resumable": st.resumable,
            "shutdown": st.shutdown,
            "fault": None if fault is None else {"message": fault.message, "code": fault.code,
                                                 "cause": fault.cause, "remedy": fault.remedy,
                                                 "during": fault.during.value if fault.during else None},
            "stops": dict(self.log.stops),
            "warnings": self.log.active_warnings[-10:],
            "warning_history": self.log.warnings[-20:],
            "start_pending": self.start_pending,
            "start_error": self.start_error or None,
            "not_ready": not_ready(st),
            "inputs_enabled": self.inputs.enabled,
            "input_error": self.inputs.error,
        }
