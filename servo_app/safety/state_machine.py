"""The safety state machine: ``transition(state, event) -> Transition(state, actions, error)``.

Pure: no I/O, threads or clocks (watchdogs turn time into events). It never raises: an internal
error (a bug) comes back as an error and, if the arm may be moving, a fast stop. While a J519
stream is alive the controller has no HOLD (manual 61.7) and an alarm is a power-off stop, so every
stop is ours: a deceleration ramp of the shaper, then either holding still in the stream or sending
last data. Moving never jumps to rest or to the end: streaming -> stopping -> stopped / ending.

Requests (Connect/Disconnect/Start/Stop/Resume/End/Reset) the state cannot honour come back as an
unchanged state, no actions and an error naming the mode, the request and why (the supervisor adds
the operator's next step: :func:`servo_app.supervision.next_step`). A stop is never refused:
where nothing moves it is simply accepted. Other events that do not apply are ignored (unchanged
state, no actions, no error).

Stops: soft stops (StopRequested, JogExpired, InputStale, LeaseLost) ramp gently and resume with one
ResumeRequested. Fast stops (StopRequested(fast=True), SensorFault, LimitApproaching) take the
shortest ramp and, once at rest, need a ResetRequested (acknowledge) before ResumeRequested: the
cause must be looked at before motion restarts. SIGTERM/SIGINT ramps softly, sends last data at rest,
then stops status output; a second signal while still decelerating escalates to the fast ramp.
EndRequested ramps softly and sends last data at rest; its reason, when it has one (the service's
own end: its session log cannot take the stream), names the stop it starts or joins.

Faults (controller alarm; status bit 0 falling or SYSRDY going off while the stream is alive; status
lost or the link dropped while the stream is alive) abandon the stream and record the alarm code
with its cause and remedy; an alarm event brings those (and whether it is a mere warning) from its
backend's catalogue. Only ResetRequested leaves fault: to ready if the last status shows the
controller waiting for a first command, to connected if status flows otherwise, else to
disconnected. ended is left only by StartRequested (a fresh IBGN run) or a controller alarm.

Transition table (tests/test_safety_state_machine.py parses it and checks the code against it).
`=` keeps the mode (fields may change); `(X)` is an action sent only sometimes; `-` no action.
Groups: idle = disconnected, connected, ready; alive = streaming, stopping, stopped, ending;
triggers = StopRequested, JogExpired, InputStale, LeaseLost, SensorFault, LimitApproaching.
"waiting" means status bit 0 = 1, bit 1 = 0 (no command yet in this IBGN run) and SYSRDY = 1.
After SIGTERM/SIGINT ("shut down") Connect, Start and Resume are refused and status is ignored.

  idle:
      StatusReceived [waiting]             -> ready         -
      StatusReceived [otherwise]           -> connected     -
      ControllerAlarm [not a warning]      -> fault         RECORD_FAULT
      StopRequested [nothing moves]        -> =             -
  disconnected:
      StatusReceived [after a signal]      -> =             -
      ConnectRequested                     -> =             START_STATUS_OUTPUT
      DisconnectRequested [cancel connect] -> =             STOP_STATUS_OUTPUT
      Signal [SIGTERM/SIGINT: shut down]   -> =             -
  connected, ready:
      StatusLost, Disconnected             -> disconnected  -
      DisconnectRequested                  -> disconnected  STOP_STATUS_OUTPUT
      Signal [SIGTERM/SIGINT: shut down]   -> disconnected  STOP_STATUS_OUTPUT
  ready:
      StartRequested                       -> streaming     SEND_FIRST_COMMAND, HOLD_POSITION
  streaming:
      triggers [soft or fast, then hold]   -> stopping      BEGIN_DECELERATION
      EndRequested [soft, then end]        -> stopping      BEGIN_DECELERATION
      Signal [soft, then end, shut down]   -> stopping      BEGIN_DECELERATION
  alive:
      StatusReceived [bit0, SYSRDY: track] -> =             -
      StatusReceived [!SYSRDY or !bit0]    -> fault         ABANDON_STREAM, RECORD_FAULT, (STOP_STATUS_OUTPUT)
      StatusLost, Disconnected             -> fault         ABANDON_STREAM, RECORD_FAULT
      ControllerAlarm [not a warning]      -> fault         ABANDON_STREAM, RECORD_FAULT, (STOP_STATUS_OUTPUT)
  stopping:
      ShaperAtRest [then hold]             -> stopped       HOLD_POSITION
      ShaperAtRest [then end]              -> ending        SEND_LAST_DATA
      triggers [fast on soft: escalate]    -> =             BEGIN_DECELERATION
      triggers [otherwise]                 -> =             -
      EndRequested [then end]              -> =             -
      Signal [first: then end, shut down]  -> =             -
      Signal [again, soft stop: escalate]  -> =             BEGIN_DECELERATION
  stopping, stopped:
      ResumeRequested [soft, then hold]    -> streaming     RESUME_MOTION
  stopping, stopped:
      StopRequested [soft on soft: its reason] -> =         -
  stopped:
      triggers [fast on soft: needs reset] -> =             -
      ResetRequested [fast: acknowledge]   -> =             -
      EndRequested, Signal                 -> ending        SEND_LAST_DATA
  ending:
      StatusReceived [!bit0, SYSRDY]       -> ended         (STOP_STATUS_OUTPUT)
      LastDataProcessed                    -> ended         (STOP_STATUS_OUTPUT)
      Signal [status off once ended]       -> =             -
      StopRequested, EndRequested          -> =             -
  ended:
      StartRequested [waiting]             -> streaming     SEND_FIRST_COMMAND, HOLD_POSITION
      ControllerAlarm [not a warning]      -> fault         RECORD_FAULT
      StopRequested, EndRequested          -> =             -
  ended, fault:
      StatusReceived [unless shut down]    -> =             -
      StatusLost, Disconnected             -> =             -
      ConnectRequested [status off]        -> =             START_STATUS_OUTPUT
      DisconnectRequested                  -> =             STOP_STATUS_OUTPUT
      Signal [shut down]                   -> =             (STOP_STATUS_OUTPUT)
  fault:
      ControllerAlarm [not a warning]      -> =             RECORD_FAULT
      ResetRequested [by last status]      -> disconnected|connected|ready  -
      StopRequested [nothing moves]        -> =             -
  *:
      ControllerAlarm [warning]            -> =             REPORT_WARNING
      Signal [not SIGTERM/SIGINT: ignored] -> =             -

Entering fault sends ABANDON_STREAM only from an alive stream, and STOP_STATUS_OUTPUT only after a
shutdown signal while status still flows. Reaching ended after a signal sends STOP_STATUS_OUTPUT.
A fault keeps its first alarm; a later alarm fills in the code only if the fault had none (e.g.
bit 0 fell, then the controller reports why) and is otherwise just recorded.
"""

from __future__ import annotations

import signal as _signal
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from servo_app.safety.actions import (
    ABANDON_STREAM,
    HOLD_POSITION,
    RESUME_MOTION,
    SEND_FIRST_COMMAND,
    SEND_LAST_DATA,
    START_STATUS_OUTPUT,
    STOP_STATUS_OUTPUT,
    Action,
    BeginDeceleration,
    RecordFault,
    ReportWarning,
)
from servo_app.safety.events import (
    ConnectRequested,
    ControllerAlarm,
    Disconnected,
    DisconnectRequested,
    EndRequested,
    Event,
    InputStale,
    JogExpired,
    LastDataProcessed,
    LeaseLost,
    LimitApproaching,
    ResetRequested,
    ResumeRequested,
    SensorFault,
    ShaperAtRest,
    Signal,
    StartRequested,
    StatusLost,
    StatusReceived,
    StopRequested,
)
from servo_app.safety.state import (
    STREAM_ALIVE,
    FaultInfo,
    Mode,
    SafetyState,
    StatusBits,
    Stop,
    StopKind,
    Then,
)

_IDLE = (Mode.DISCONNECTED, Mode.CONNECTED, Mode.READY)
_SHUTDOWN_SIGNALS = frozenset({int(_signal.SIGTERM), int(_signal.SIGINT)})


@dataclass(frozen=True)
class Transition:
    state: SafetyState
    actions: tuple[Action, ...] = ()
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def transition(state: SafetyState, event: Event) -> Transition:
    """The next state and what the caller must do, in order. Never raises."""
    handler = _HANDLERS.get(type(event))
    if handler is None:
        return _refuse(state, event, "unknown event")
    try:
        return handler(state, event)
    except Exception as exc:  # a bug must not kill the servo cycle: that alone would alarm the robot
        return _internal_error(state, event, exc)


def _internal_error(state: SafetyState, event: object, exc: Exception) -> Transition:
    """A bug: report it and, if the arm may be moving, take the fast ramp (fail safe, stream kept)."""
    error = f"internal error handling {event!r} in {getattr(state, 'mode', state)}: {exc!r}"
    mode = getattr(state, "mode", None)
    if mode is Mode.STREAMING or (mode is Mode.STOPPING and not _cur(state).fast):
        stop = replace(_cur(state) if mode is Mode.STOPPING else Stop(""), reason="internal error",
                       kind=StopKind.FAST)
        stopping = replace(state, mode=Mode.STOPPING, stop=stop)
        return Transition(stopping, (BeginDeceleration(fast=True),), error)
    return Transition(state, (), error)


# --- helpers ------------------------------------------------------------------------------------


def _stay(s: SafetyState) -> Transition:
    return Transition(s)


def _go(s: SafetyState, actions: Sequence[Action] = (), **changes: Any) -> Transition:
    return Transition(replace(s, **changes) if changes else s, tuple(actions))


def _refuse(s: SafetyState, event: object, why: str) -> Transition:
    mode = getattr(getattr(s, "mode", None), "value", s)
    return Transition(s, (), f"{type(event).__name__} refused in {mode}: {why}")


def _cur(s: SafetyState) -> Stop:
    """The stop under way; a malformed state without one is treated as an unacknowledged fast stop."""
    return s.stop if s.stop is not None else Stop("unspecified stop", StopKind.FAST)


def _idle_mode(status: StatusBits | None) -> Mode:
    if status is None:
        return Mode.DISCONNECTED
    return Mode.READY if status.waiting else Mode.CONNECTED


def _not_waiting_why(status: StatusBits | None) -> str:
    if status is None:
        return "no status packets: connect first"
    if not status.sysrdy:
        return "SYSRDY is off (servo power not ready)"
    if not status.bit0:
        return ("the controller is not waiting for commands (status bit 0 = 0): run the program with "
                "IBGN start[*] in AUTO mode at 100% override")
    return ("the controller already received commands in this IBGN run (status bit 1 = 1): restart "
            "the program")


def _fault(s: SafetyState, info: FaultInfo, status: StatusBits | None) -> Transition:
    actions: list[Action] = []
    if s.mode in STREAM_ALIVE:
        actions.append(ABANDON_STREAM)
    actions.append(RecordFault(info))
    if s.shutdown and status is not None:
        # Shutting down and the stream is dead: nothing left to watch for.
        actions.append(STOP_STATUS_OUTPUT)
        status = None
    return _go(s, actions, mode=Mode.FAULT, fault=info, status=status, stop=None)


def _own_fault(s: SafetyState, message: str, cause: str, remedy: str) -> FaultInfo:
    return FaultInfo(message=message, cause=cause, remedy=remedy, code=None, during=s.mode)


def _ended(s: SafetyState, status: StatusBits | None) -> Transition:
    if s.shutdown:
        return _go(s, (STOP_STATUS_OUTPUT,), mode=Mode.ENDED, status=None)
    return _go(s, (), mode=Mode.ENDED, status=status)


_RESTART_REMEDY = ("Reset the controller alarm if one is posted, restart the program with IBGN start[*] "
                   "in AUTO mode at 100% override, then reset here and start a new stream.")


# --- link and controller ------------------------------------------------------------------------


def _on_status(s: SafetyState, e: StatusReceived) -> Transition:
    bits = StatusBits(bit0=bool(e.bit0), bit1=bool(e.bit1), sysrdy=bool(e.sysrdy))
    m = s.mode
    if m in STREAM_ALIVE:
        if not bits.sysrdy:
            return _fault(s, _own_fault(
                s, f"SYSRDY went off while {m.value}",
                "Servo power was removed while the command stream was alive (emergency stop, fence, "
                "deadman or an alarm).",
                _RESTART_REMEDY), bits)
        if not bits.bit0:
            if m is Mode.ENDING:
                return _ended(s, bits)
            return _fault(s, _own_fault(
                s, f"status bit 0 fell while {m.value}",
                "The controller stopped waiting for command packets before last data was sent: the "
                "program was stopped or paused, or an alarm was posted.",
                _RESTART_REMEDY), bits)
        return _go(s, status=bits) if bits != s.status else _stay(s)
    if s.shutdown:  # status output was stopped; a straggling packet must not reconnect us
        return _stay(s)
    if m in _IDLE:
        return _go(s, mode=_idle_mode(bits), status=bits)
    return _go(s, status=bits) if bits != s.status else _stay(s)  # ended, fault: track only


def _on_link_lost(s: SafetyState, e: StatusLost | Disconnected) -> Transition:
    m = s.mode
    if m in STREAM_ALIVE:
        what = "status packets lost" if isinstance(e, StatusLost) else "connection lost"
        detail = f" ({e.detail})" if e.detail else ""
        return _fault(s, _own_fault(
            s, f"{what} while {m.value}{detail}",
            "No status packets arrive, so no command packets are sent; the controller posts "
            "MOTN-603 (receiving interval over) and stops.",
            "Check the network link and the controller; " + _RESTART_REMEDY), None)
    if m in (Mode.CONNECTED, Mode.READY):
        return _go(s, mode=Mode.DISCONNECTED, status=None)
    if s.status is None:
        return _stay(s)
    return _go(s, status=None)  # ended, fault


def _on_alarm(s: SafetyState, e: ControllerAlarm) -> Transition:
    message = e.message or e.code
    if e.warning:
        return Transition(s, (ReportWarning(e.code, message, e.cause, e.remedy),))
    cause, remedy = e.cause, e.remedy
    if not cause:  # unknown codes still stop: the controller has stopped, whatever the code says
        cause = f"{e.code} is not in the controller's alarm catalogue."
        remedy = remedy or "See the controller's alarm history and its manual for this code."
    info = FaultInfo(message=message, cause=cause, remedy=remedy, code=e.code, during=s.mode)
    if s.mode is Mode.FAULT:
        if s.fault is None or s.fault.code is None:  # the alarm explains our own detection
            before = f" ({s.fault.message})" if s.fault else ""
            filled = replace(info, message=message + before, during=s.fault.during if s.fault else None)
            return _go(s, (RecordFault(filled),), fault=filled)
        return Transition(s, (RecordFault(info),))  # later alarms are consequences: log them only
    return _fault(s, info, s.status)


# --- requests -----------------------------------------------------------------------------------


def _on_connect(s: SafetyState, e: ConnectRequested) -> Transition:
    if s.shutdown:
        return _refuse(s, e, "shutting down")
    if s.mode is Mode.DISCONNECTED or (s.mode in (Mode.ENDED, Mode.FAULT) and s.status is None):
        return Transition(s, (START_STATUS_OUTPUT,))
    return _refuse(s, e, "status packets are already flowing")


def _on_disconnect(s: SafetyState, e: DisconnectRequested) -> Transition:
    if s.mode in STREAM_ALIVE:
        return _refuse(s, e, "end the stream first: stopping status output before the command stream "
                             "ends may post an alarm (manual 61.3, note 2)")
    if s.mode in (Mode.CONNECTED, Mode.READY):
        return _go(s, (STOP_STATUS_OUTPUT,), mode=Mode.DISCONNECTED, status=None)
    # disconnected (cancels a pending connect), ended, fault: always safe without a stream
    return _go(s, (STOP_STATUS_OUTPUT,), status=None)


def _on_start(s: SafetyState, e: StartRequested) -> Transition:
    m = s.mode
    if m in STREAM_ALIVE:
        return _refuse(s, e, "a stream is already running")
    if m is Mode.FAULT:
        return _refuse(s, e, "reset the fault first")
    if s.shutdown:
        return _refuse(s, e, "shutting down")
    if m in (Mode.READY, Mode.ENDED) and s.status is not None and s.status.waiting:
        return _go(s, (SEND_FIRST_COMMAND, HOLD_POSITION), mode=Mode.STREAMING, stop=None)
    return _refuse(s, e, _not_waiting_why(s.status))


def _stop(s: SafetyState, reason: str, fast: bool) -> Transition:
    kind = StopKind.FAST if fast else StopKind.SOFT
    m = s.mode
    if m is Mode.STREAMING:
        return _go(s, (BeginDeceleration(fast=fast),), mode=Mode.STOPPING, stop=Stop(reason, kind))
    if m in (Mode.STOPPING, Mode.STOPPED):
        cur = _cur(s)
        if fast and not cur.fast:  # escalate; the new reason is what must be acknowledged
            stop = replace(cur, reason=reason, kind=StopKind.FAST)
            actions = (BeginDeceleration(fast=True),) if m is Mode.STOPPING else ()
            return _go(s, actions, stop=stop)
    return _stay(s)  # already stopping at least as fast, or nothing moves


def _on_stop(s: SafetyState, e: StopRequested) -> Transition:
    reason = e.reason or "stop requested"
    t = _stop(s, reason, bool(e.fast))
    if t.state is s and s.mode in (Mode.STOPPING, Mode.STOPPED):
        cur = _cur(s)
        if not cur.fast and cur.then is Then.HOLD and cur.reason != reason:
            # An explicit stop over a soft one (a hold-to-run that ran out, a stale input): its reason
            # stands, so what resumes by itself after those (a jog press) no longer does: resume does.
            return _go(s, stop=replace(cur, reason=reason))
    return t


def _on_resume(s: SafetyState, e: ResumeRequested) -> Transition:
    m = s.mode
    if m in (Mode.STOPPING, Mode.STOPPED):
        cur = _cur(s)
        if s.shutdown:
            return _refuse(s, e, "shutting down")
        if cur.then is Then.END:
            return _refuse(s, e, "the stream is ending")
        if cur.fast:
            at_rest = "" if m is Mode.STOPPED else "wait for rest, then "
            return _refuse(s, e, f"fast stop ({cur.reason}): {at_rest}reset to acknowledge, then resume")
        return _go(s, (RESUME_MOTION,), mode=Mode.STREAMING, stop=None)
    why = {
        Mode.STREAMING: "already streaming",
        Mode.ENDING: "the stream is ending",
        Mode.ENDED: "the stream has ended",
        Mode.FAULT: "the stream ended in a fault",
    }.get(m, "no stream to resume")
    return _refuse(s, e, why)


def _on_end(s: SafetyState, e: EndRequested) -> Transition:
    m = s.mode
    if m is Mode.STREAMING:
        return _go(s, (BeginDeceleration(fast=False),), mode=Mode.STOPPING,
                   stop=Stop(e.reason or "end requested", StopKind.SOFT, Then.END))
    if m is Mode.STOPPING:
        cur = _cur(s)
        stop = replace(cur, then=Then.END, reason=e.reason or cur.reason)
        return _stay(s) if stop == cur else _go(s, stop=stop)
    if m is Mode.STOPPED:
        cur = _cur(s)
        return _go(s, (SEND_LAST_DATA,), mode=Mode.ENDING, stop=replace(cur, then=Then.END,
                                                                         reason=e.reason or cur.reason))
    if m in (Mode.ENDING, Mode.ENDED):
        return _stay(s)
    if m is Mode.FAULT:
        return _refuse(s, e, "the stream is already gone")
    return _refuse(s, e, "no stream to end")


def _on_reset(s: SafetyState, e: ResetRequested) -> Transition:
    m = s.mode
    if m is Mode.FAULT:
        return _go(s, mode=_idle_mode(s.status), fault=None, stop=None)
    if m is Mode.STOPPED and _cur(s).fast:
        return _go(s, stop=replace(_cur(s), kind=StopKind.SOFT))
    if m is Mode.STOPPING and _cur(s).fast:
        return _refuse(s, e, "still decelerating")
    if m is Mode.STOPPED:
        return _refuse(s, e, "nothing to acknowledge (soft stop: resume instead)")
    return _refuse(s, e, "no fault to reset")


# --- servo cycle --------------------------------------------------------------------------------


def _on_at_rest(s: SafetyState, e: ShaperAtRest) -> Transition:
    if s.mode is not Mode.STOPPING:
        return _stay(s)  # reported every still cycle; only ends a deceleration
    if _cur(s).then is Then.HOLD:
        return _go(s, (HOLD_POSITION,), mode=Mode.STOPPED)
    return _go(s, (SEND_LAST_DATA,), mode=Mode.ENDING)


def _on_last_data(s: SafetyState, e: LastDataProcessed) -> Transition:
    return _ended(s, s.status) if s.mode is Mode.ENDING else _stay(s)


def _on_signal(s: SafetyState, e: Signal) -> Transition:
    try:
        sig = int(e.sig)
    except (TypeError, ValueError):
        return _stay(s)
    if sig not in _SHUTDOWN_SIGNALS:
        return _stay(s)
    reason = f"signal {_signal.Signals(sig).name}"
    m = s.mode
    if m is Mode.STREAMING:
        return _go(s, (BeginDeceleration(fast=False),), mode=Mode.STOPPING, shutdown=True,
                   stop=Stop(reason, StopKind.SOFT, Then.END))
    if m is Mode.STOPPING:
        cur = _cur(s)
        if not s.shutdown:
            return _go(s, shutdown=True, stop=replace(cur, then=Then.END))
        if not cur.fast:  # asked twice: the operator wants it over with
            return _go(s, (BeginDeceleration(fast=True),),
                       stop=replace(cur, kind=StopKind.FAST, reason=f"{reason} (again)"))
        return _stay(s)
    if m is Mode.STOPPED:
        return _go(s, (SEND_LAST_DATA,), mode=Mode.ENDING, shutdown=True,
                   stop=replace(_cur(s), then=Then.END))
    if m is Mode.ENDING:
        return _go(s, shutdown=True) if not s.shutdown else _stay(s)
    if m in (Mode.CONNECTED, Mode.READY):
        return _go(s, (STOP_STATUS_OUTPUT,), mode=Mode.DISCONNECTED, status=None, shutdown=True)
    if s.status is not None:  # ended, fault
        return _go(s, (STOP_STATUS_OUTPUT,), status=None, shutdown=True)
    return _go(s, shutdown=True) if not s.shutdown else _stay(s)


def _trigger_reason(e: Any) -> tuple[str, bool]:
    """(reason, fast) of a stop trigger from the servo cycle or the inputs."""
    if isinstance(e, InputStale):
        return f"input {e.source} stale", False
    if isinstance(e, LeaseLost):
        return "control lease lost" + (f" ({e.holder})" if e.holder else ""), False
    if isinstance(e, JogExpired):
        return "hold-to-run expired" + (f" ({e.source})" if e.source else ""), False
    if isinstance(e, SensorFault):  # includes NaN from a sensor: its data cannot be trusted
        return f"sensor fault on {e.source}" + (f": {e.detail}" if e.detail else ""), True
    # LimitApproaching: diff-IK cannot steer clear, so take the shortest stopping distance
    return "limit approaching" + (f": {e.detail}" if e.detail else ""), True


def _on_trigger(s: SafetyState, e: Any) -> Transition:
    return _stop(s, *_trigger_reason(e))


_HANDLERS: dict[type, Callable[[SafetyState, Any], Transition]] = {
    StatusReceived: _on_status,
    StatusLost: _on_link_lost,
    Disconnected: _on_link_lost,
    ControllerAlarm: _on_alarm,
    ConnectRequested: _on_connect,
    DisconnectRequested: _on_disconnect,
    StartRequested: _on_start,
    StopRequested: _on_stop,
    ResumeRequested: _on_resume,
    EndRequested: _on_end,
    ResetRequested: _on_reset,
    ShaperAtRest: _on_at_rest,
    LastDataProcessed: _on_last_data,
    InputStale: _on_trigger,
    SensorFault: _on_trigger,
    LeaseLost: _on_trigger,
    LimitApproaching: _on_trigger,
    JogExpired: _on_trigger,
    Signal: _on_signal,
}
