"""The safety state machine against its documented table, named scenarios and random event sequences."""

from __future__ import annotations

import re
import signal
from dataclasses import dataclass, replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import servo_app.safety.state_machine as sm
from servo_app.fanuc.alarms import ALARMS
from servo_app.fanuc.packets import StatusBit
from servo_app.safety import (
    ABANDON_STREAM,
    HOLD_POSITION,
    REQUESTS,
    RESUME_MOTION,
    SEND_FIRST_COMMAND,
    SEND_LAST_DATA,
    START_STATUS_OUTPUT,
    STOP_STATUS_OUTPUT,
    STREAM_ALIVE,
    BeginDeceleration,
    ConnectRequested,
    ControllerAlarm,
    Disconnected,
    DisconnectRequested,
    EndRequested,
    InputStale,
    JogExpired,
    LastDataProcessed,
    LeaseLost,
    LimitApproaching,
    Mode,
    RecordFault,
    ReportWarning,
    ResetRequested,
    ResumeRequested,
    SafetyState,
    SensorFault,
    ShaperAtRest,
    Signal,
    StartRequested,
    StatusBits,
    StatusLost,
    StatusReceived,
    StopKind,
    StopRequested,
    Then,
    Transition,
    motion_allowed,
    safe_to_exit,
    stream_alive,
    transition,
)

# --- fixtures: every mode, reached through real transitions ---------------------------------------

WAITING = StatusReceived(bit0=True, bit1=False, sysrdy=True)  # IBGN start executing, no command yet
RUNNING = StatusReceived(bit0=True, bit1=True, sysrdy=True, moving=True)  # commands being received
IDLE = StatusReceived(bit0=False, bit1=False, sysrdy=True)  # program not waiting
SERVO_OFF = StatusReceived(bit0=True, bit1=True, sysrdy=False)
SIGTERM = Signal(int(signal.SIGTERM))
SIGINT = Signal(int(signal.SIGINT))
WARNING_CODE = next(code for code, spec in ALARMS.items() if spec.warning)


def alarm(code: str, message: str = "") -> ControllerAlarm:
    """The event as the FANUC supervisor builds it: classified from the FANUC alarm catalogue."""
    spec = ALARMS.get(code)
    if spec is None:
        return ControllerAlarm(code, message)
    return ControllerAlarm(code, message, warning=spec.warning, cause=spec.cause, remedy=spec.remedy)


def drive(*events: object, state: SafetyState | None = None) -> SafetyState:
    s = state or SafetyState()
    for e in events:
        t = transition(s, e)  # type: ignore[arg-type]
        assert t.error is None, t.error
        s = t.state
    return s


STREAMING = drive(WAITING, StartRequested(), RUNNING)
STATES: dict[str, SafetyState] = {
    "disconnected": SafetyState(),
    "disconnected_shutdown": drive(SIGTERM),
    "connected": drive(IDLE),
    "connected_stale_stream": drive(RUNNING),
    "ready": drive(WAITING),
    "streaming": drive(WAITING, StartRequested()),
    "streaming_running": STREAMING,
    "stopping_soft": drive(StopRequested("console"), state=STREAMING),
    "stopping_fast": drive(SensorFault("ft", "NaN"), state=STREAMING),
    "stopping_end": drive(EndRequested(), state=STREAMING),
    "stopping_shutdown": drive(SIGTERM, state=STREAMING),
    "stopping_shutdown_fast": drive(SIGTERM, SIGINT, state=STREAMING),
    "stopped_soft": drive(JogExpired(), ShaperAtRest(), state=STREAMING),
    "stopped_fast": drive(LimitApproaching("J3"), ShaperAtRest(), state=STREAMING),
    "ending": drive(EndRequested(), ShaperAtRest(), state=STREAMING),
    "ending_shutdown": drive(SIGTERM, ShaperAtRest(), state=STREAMING),
    "ended": drive(EndRequested(), ShaperAtRest(), IDLE, state=STREAMING),
    "ended_waiting": drive(EndRequested(), ShaperAtRest(), IDLE, WAITING, state=STREAMING),
    "ended_no_status": drive(EndRequested(), ShaperAtRest(), IDLE, StatusLost(), state=STREAMING),
    "ended_shutdown": drive(SIGTERM, ShaperAtRest(), LastDataProcessed(), state=STREAMING),
    "fault_alarm": drive(alarm("MOTN-611", "MOTN-611 ST:Exceeded Jnt Jerk Limit."),
                         state=STREAMING),
    "fault_status_lost": drive(StatusLost(), state=STREAMING),
    "fault_bit0": drive(IDLE, state=STREAMING),
    "fault_idle_waiting": drive(alarm("MOTN-606"), WAITING, state=drive(IDLE)),
    "fault_shutdown": drive(SIGTERM, alarm("MOTN-603"), state=STREAMING),
}

EVENTS: dict[str, object] = {
    "status_waiting": WAITING,
    "status_running": RUNNING,
    "status_idle": IDLE,
    "status_servo_off": SERVO_OFF,
    "status_lost": StatusLost("3 intervals"),
    "disconnected": Disconnected("ECONNREFUSED"),
    "alarm_known": alarm("MOTN-603", "MOTN-603 ST:Receiving interval over"),
    "alarm_unknown": alarm("SRVO-001", "SRVO-001 Operator panel E-stop"),
    "alarm_warning": alarm(WARNING_CODE),
    "connect": ConnectRequested(),
    "disconnect": DisconnectRequested(),
    "start": StartRequested(),
    "stop_soft": StopRequested("console stop"),
    "stop_fast": StopRequested("console e-stop", fast=True),
    "resume": ResumeRequested(),
    "end": EndRequested(),
    "reset": ResetRequested(),
    "at_rest": ShaperAtRest(),
    "last_data": LastDataProcessed(),
    "input_stale": InputStale("spacemouse"),
    "sensor_fault": SensorFault("force", "NaN on Fz"),
    "lease_lost": LeaseLost("web-1"),
    "sigterm": SIGTERM,
    "sigint": SIGINT,
    "sighup": Signal(int(signal.SIGHUP)),
    "limit": LimitApproaching("J5 upper"),
    "jog_expired": JogExpired("web"),
}


def test_fixtures_cover_every_mode_and_event_type():
    assert {s.mode for s in STATES.values()} == set(Mode)
    assert {type(e) for e in EVENTS.values()} == set(sm._HANDLERS)


# --- the documented table, parsed from the module docstring ----------------------------------------

MODE_GROUPS = {
    "idle": {Mode.DISCONNECTED, Mode.CONNECTED, Mode.READY},
    "alive": set(STREAM_ALIVE),
    "*": set(Mode),
}
EVENT_GROUPS = {
    "triggers": {"StopRequested", "JogExpired", "InputStale", "LeaseLost", "SensorFault", "LimitApproaching"},
}


@dataclass(frozen=True)
class Row:
    modes: frozenset[Mode]
    events: frozenset[str]
    to: frozenset[Mode] | None  # None: "=" (mode kept)
    required: tuple[str, ...]
    optional: frozenset[str]
    text: str


def _parse_table(doc: str) -> list[Row]:
    rows: list[Row] = []
    modes: set[Mode] | None = None
    table = doc[doc.index("Transition table"):doc.index("Entering fault")]
    for line in table.splitlines():
        if h := re.fullmatch(r"  (\S[^:]*):", line):
            modes = set()
            for name in (n.strip() for n in h.group(1).split(",")):
                modes |= MODE_GROUPS.get(name, {Mode(name)} if name in Mode._value2member_map_ else set())
            assert modes, line
            continue
        r = re.fullmatch(r"      (?P<ev>[A-Za-z, ]+?)\s*(\[[^\]]*\])?\s*-> (?P<to>\S+)\s+(?P<act>.*)", line)
        if not r:
            continue
        assert modes is not None, line
        events: set[str] = set()
        for name in (n.strip() for n in r.group("ev").split(",")):
            events |= EVENT_GROUPS.get(name, {name})
        to = None if r.group("to") == "=" else frozenset(Mode(m) for m in r.group("to").split("|"))
        acts = [a.strip() for a in r.group("act").split(",") if a.strip() != "-"]
        rows.append(Row(
            frozenset(modes), frozenset(events), to,
            tuple(a for a in acts if not a.startswith("(")),
            frozenset(a.strip("()") for a in acts if a.startswith("(")),
            line.strip(),
        ))
    return rows


ROWS = _parse_table(sm.__doc__ or "")


def action_name(action: object) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", type(action).__name__).upper()


def test_table_parses_and_names_real_events_and_actions():
    assert len(ROWS) > 40
    event_names = {t.__name__ for t in sm._HANDLERS}
    action_names = {"BEGIN_DECELERATION", "SEND_FIRST_COMMAND", "HOLD_POSITION", "RESUME_MOTION",
                    "SEND_LAST_DATA", "START_STATUS_OUTPUT", "STOP_STATUS_OUTPUT", "ABANDON_STREAM",
                    "RECORD_FAULT", "REPORT_WARNING"}
    for row in ROWS:
        assert row.events <= event_names, row.text
        assert set(row.required) | row.optional <= action_names, row.text


def _matching_row(before: SafetyState, event: object, t: Transition) -> Row | None:
    name = type(event).__name__
    got = [action_name(a) for a in t.actions]
    for row in ROWS:
        if before.mode not in row.modes or name not in row.events:
            continue
        to_ok = t.state.mode is before.mode if row.to is None else t.state.mode in row.to
        required = [a for a in got if a in row.required]
        acts_ok = (list(row.required) == required and set(got) <= set(row.required) | row.optional
                   and len(got) == len(set(got)))
        if to_ok and acts_ok:
            return row
    return None


def check_documented(before: SafetyState, event: object, t: Transition) -> Row | None:
    """A documented transition, a refused request, or an ignored event; nothing else."""
    name = type(event).__name__
    assert isinstance(t, Transition)
    if t.error is not None:
        assert isinstance(event, REQUESTS), f"{name} is not a request but got error {t.error!r}"
        assert t.state == before and t.actions == ()
        assert before.mode.value in t.error and name in t.error
        return None
    row = _matching_row(before, event, t)
    if row is not None:
        return row
    has_rows = any(before.mode in r.modes and name in r.events for r in ROWS)
    assert not has_rows, f"{before.mode} + {event} -> {t.state.mode} {t.actions} matches no documented row"
    assert not isinstance(event, REQUESTS), f"request {name} accepted in {before.mode} without a row"
    assert t.state == before and t.actions == (), f"undocumented change: {before} + {event} -> {t}"
    return None


@pytest.mark.parametrize("event_name", list(EVENTS))
@pytest.mark.parametrize("state_name", list(STATES))
def test_every_state_event_pair_is_documented(state_name, event_name):
    before, event = STATES[state_name], EVENTS[event_name]
    t = transition(before, event)  # type: ignore[arg-type]
    check_documented(before, event, t)
    assert transition(before, event) == t  # deterministic  # type: ignore[arg-type]
    _check_step(before, event, t)


def test_every_documented_row_is_exercised():
    used = set()
    for before in STATES.values():
        for event in EVENTS.values():
            row = check_documented(before, event, transition(before, event))  # type: ignore[arg-type]
            if row is not None:
                used.add(row.text)
    missing = [r.text for r in ROWS if r.text not in used]
    assert not missing, missing


# --- invariants of one step (used by the table test and the random sequences) ---------------------


def _check_step(before: SafetyState, event: object, t: Transition) -> None:
    after, acts = t.state, t.actions
    if t.error is not None:
        assert after == before and acts == ()
    # fault is left only by reset; fault info exactly in fault
    if before.mode is Mode.FAULT and after.mode is not Mode.FAULT:
        assert isinstance(event, ResetRequested)
    assert (after.mode is Mode.FAULT) == (after.fault is not None)
    # stop info exactly while stopping, stopped, ending, ended
    assert (after.stop is not None) == (after.mode in (Mode.STOPPING, Mode.STOPPED, Mode.ENDING, Mode.ENDED))
    # a live stream always sees the controller waiting with servo ready
    if after.mode in STREAM_ALIVE:
        assert after.status is not None and after.status.bit0 and after.status.sysrdy
    # moving never jumps to rest or to the end
    if before.mode is Mode.STREAMING:
        assert after.mode in (Mode.STREAMING, Mode.STOPPING, Mode.FAULT)
    if after.mode is Mode.STOPPED and before.mode is not Mode.STOPPED:
        assert before.mode is Mode.STOPPING and isinstance(event, ShaperAtRest) and acts == (HOLD_POSITION,)
    if after.mode is Mode.ENDING and before.mode is not Mode.ENDING:
        assert before.mode in (Mode.STOPPING, Mode.STOPPED) and acts == (SEND_LAST_DATA,)
        if before.mode is Mode.STOPPING:
            assert isinstance(event, ShaperAtRest)
    if after.mode is Mode.ENDED and before.mode is not Mode.ENDED:
        assert before.mode is Mode.ENDING
    # ended is left only by a new start or an alarm
    if before.mode is Mode.ENDED and after.mode is not Mode.ENDED:
        assert (isinstance(event, StartRequested) and after.mode is Mode.STREAMING) or (
            isinstance(event, ControllerAlarm) and after.mode is Mode.FAULT)
    # the stream starts with a first command and resumes only from a soft hold
    if after.mode is Mode.STREAMING and before.mode is not Mode.STREAMING:
        if before.mode in (Mode.READY, Mode.ENDED):
            assert acts == (SEND_FIRST_COMMAND, HOLD_POSITION)
        else:
            assert before.mode in (Mode.STOPPING, Mode.STOPPED) and acts == (RESUME_MOTION,)
            assert before.stop is not None and before.stop.kind is StopKind.SOFT
    if isinstance(event, ResumeRequested) and before.stop is not None and before.stop.fast:
        assert t.error is not None
    # a live stream ends only through last data (ending -> ended) or a fault that abandons it
    if before.mode in STREAM_ALIVE and after.mode not in STREAM_ALIVE:
        assert (before.mode is Mode.ENDING and after.mode is Mode.ENDED) or (
            after.mode is Mode.FAULT and ABANDON_STREAM in acts)
    if ABANDON_STREAM in acts:
        assert before.mode in STREAM_ALIVE and after.mode is Mode.FAULT
    if any(isinstance(a, BeginDeceleration) for a in acts):
        assert after.mode is Mode.STOPPING
    # status output stops only without a command stream (manual 61.3 note 2)
    if STOP_STATUS_OUTPUT in acts:
        assert after.mode not in STREAM_ALIVE and after.status is None
    # a fast stop stays fast until acknowledged at rest
    if before.stop_fast and after.mode in (Mode.STOPPING, Mode.STOPPED, Mode.ENDING) and not after.stop_fast:
        assert before.mode is Mode.STOPPED and isinstance(event, ResetRequested)
    # shutdown is one-way and never starts anything
    if before.shutdown:
        assert after.shutdown
        assert not {START_STATUS_OUTPUT, SEND_FIRST_COMMAND, RESUME_MOTION} & set(acts)
    assert motion_allowed(after) == (after.mode is Mode.STREAMING)
    assert stream_alive(after) == (after.mode in STREAM_ALIVE)


# --- random event sequences -------------------------------------------------------------------------

event_st = st.sampled_from(list(EVENTS.values()))
# status packets dominate real traffic and keep the stream alive long enough to reach deep modes
weighted_st = st.one_of(event_st, st.sampled_from([WAITING, RUNNING, ShaperAtRest(), StartRequested()]))


@settings(max_examples=400, deadline=None)
@given(st.lists(weighted_st, max_size=60))
def test_random_sequences_keep_invariants(events):
    s = SafetyState()
    fast_unacknowledged = False
    for e in events:
        t = transition(s, e)
        _check_step(s, e, t)
        check_documented(s, e, t)
        # a fast stop is never followed by motion without a reset at rest in between
        if s.stop_fast and s.mode in (Mode.STOPPING, Mode.STOPPED):
            fast_unacknowledged = True
        if isinstance(e, ResetRequested) and t.ok:
            fast_unacknowledged = False
        if t.state.mode is Mode.STREAMING and s.mode is not Mode.STREAMING and s.mode in STREAM_ALIVE:
            assert not fast_unacknowledged
        if t.state.mode not in STREAM_ALIVE:
            fast_unacknowledged = False
        s = t.state


@settings(max_examples=400, deadline=None)
@given(st.lists(weighted_st, max_size=60), st.sampled_from([SIGTERM, SIGINT]),
       st.lists(weighted_st, max_size=20))
def test_a_signal_always_reaches_a_safe_exit(before, sig, after):
    """Signal anywhere, anything after it, then the cycle reporting rest and last data -> safe to exit."""
    s = SafetyState()
    for e in before:
        s = transition(s, e).state
    actions = []
    for e in (sig, *after, ShaperAtRest(), LastDataProcessed()):
        t = transition(s, e)
        _check_step(s, e, t)
        actions += t.actions
        s = t.state
    assert safe_to_exit(s), s
    assert s.shutdown
    # the order the brief demands whenever a stream was alive: decelerate, last data, status off
    if SEND_LAST_DATA in actions and STOP_STATUS_OUTPUT in actions:  # (a lost link needs no stop packet)
        assert actions.index(SEND_LAST_DATA) < actions.index(STOP_STATUS_OUTPUT)


def test_a_fault_during_shutdown_stops_status_output_too():
    s, ts = steps(STREAMING, SIGTERM, alarm("MOTN-603"))
    assert s.fault is not None
    assert ts[1].actions == (ABANDON_STREAM, RecordFault(s.fault), STOP_STATUS_OUTPUT)
    assert s.mode is Mode.FAULT and safe_to_exit(s)


@settings(max_examples=200, deadline=None)
@given(st.lists(weighted_st, max_size=40), st.sampled_from([EVENTS[k] for k in (
    "stop_soft", "stop_fast", "input_stale", "sensor_fault", "lease_lost", "limit", "jog_expired")]))
def test_every_stop_trigger_brings_a_live_stream_to_rest(events, trigger):
    s = SafetyState()
    for e in events:
        s = transition(s, e).state
    was_alive = s.mode in STREAM_ALIVE
    s = transition(transition(s, trigger).state, ShaperAtRest()).state  # type: ignore[arg-type]
    if was_alive:
        assert s.mode in (Mode.STOPPED, Mode.ENDING)


# --- named scenarios ----------------------------------------------------------------------------------


def steps(state: SafetyState, *events: object) -> tuple[SafetyState, list[Transition]]:
    out = []
    for e in events:
        t = transition(state, e)  # type: ignore[arg-type]
        _check_step(state, e, t)
        out.append(t)
        state = t.state
    return state, out


def test_happy_path_connect_start_stop_resume_end_disconnect():
    s, ts = steps(SafetyState(), ConnectRequested(), IDLE, WAITING, StartRequested())
    assert [t.actions for t in ts] == [(START_STATUS_OUTPUT,), (), (), (SEND_FIRST_COMMAND, HOLD_POSITION)]
    assert [t.state.mode for t in ts] == [Mode.DISCONNECTED, Mode.CONNECTED, Mode.READY, Mode.STREAMING]
    assert motion_allowed(s)

    s, ts = steps(s, RUNNING, StopRequested("console"), ShaperAtRest(), ResumeRequested())
    assert [t.actions for t in ts] == [(), (BeginDeceleration(fast=False),), (HOLD_POSITION,),
                                       (RESUME_MOTION,)]
    assert [t.state.mode for t in ts] == [Mode.STREAMING, Mode.STOPPING, Mode.STOPPED, Mode.STREAMING]
    assert ts[1].state.stop_reason == "console" and not ts[1].state.stop_fast
    assert ts[2].state.resumable and not motion_allowed(ts[2].state)

    s, ts = steps(s, EndRequested(), ShaperAtRest(), IDLE, DisconnectRequested())
    assert [t.state.mode for t in ts] == [Mode.STOPPING, Mode.ENDING, Mode.ENDED, Mode.ENDED]
    assert [t.actions for t in ts] == [(BeginDeceleration(fast=False),), (SEND_LAST_DATA,), (),
                                       (STOP_STATUS_OUTPUT,)]
    assert ts[2].state.status is not None  # a normal end keeps status flowing
    assert safe_to_exit(s)


def test_resume_while_decelerating_goes_straight_back_to_streaming():
    s, ts = steps(STREAMING, InputStale("spacemouse"), ResumeRequested())
    assert ts[0].state.stop_reason == "input spacemouse stale"
    assert ts[1].state.mode is Mode.STREAMING and ts[1].actions == (RESUME_MOTION,)
    assert s.stop is None


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGINT"])
def test_signal_decelerates_then_last_data_then_status_off(signame):
    s, ts = steps(STREAMING, Signal(int(getattr(signal, signame))), RUNNING, ShaperAtRest(), RUNNING,
                  LastDataProcessed())
    assert [a for t in ts for a in t.actions] == [BeginDeceleration(fast=False), SEND_LAST_DATA,
                                                  STOP_STATUS_OUTPUT]
    assert s.mode is Mode.ENDED and s.shutdown and safe_to_exit(s)
    assert ts[0].state.stop_reason == f"signal {signame}"
    # a straggling status packet after status output stopped changes nothing
    assert transition(s, WAITING).state == s


def test_second_signal_escalates_to_the_fast_ramp_once():
    s, ts = steps(STREAMING, SIGTERM, SIGINT, SIGTERM)
    assert ts[1].actions == (BeginDeceleration(fast=True),) and s.stop_fast
    assert ts[2].actions == () and ts[2].state == ts[1].state


def test_signal_while_stopped_sends_last_data_at_once():
    s, ts = steps(STATES["stopped_soft"], SIGTERM)
    assert ts[0].actions == (SEND_LAST_DATA,) and s.mode is Mode.ENDING and s.shutdown


def test_signal_while_ending_stops_status_once_ended():
    s, ts = steps(STATES["ending"], SIGTERM, IDLE)
    assert ts[0].actions == () and ts[1].actions == (STOP_STATUS_OUTPUT,) and safe_to_exit(s)


@pytest.mark.parametrize(("event", "fast", "reason"), [
    (StopRequested("console"), False, "console"),
    (StopRequested("e-stop button", fast=True), True, "e-stop button"),
    (JogExpired("web"), False, "hold-to-run expired (web)"),
    (InputStale("can0"), False, "input can0 stale"),
    (LeaseLost("web-1"), False, "control lease lost (web-1)"),
    (SensorFault("force", "NaN on Fz"), True, "sensor fault on force: NaN on Fz"),
    (LimitApproaching("J5 upper"), True, "limit approaching: J5 upper"),
])
def test_each_stop_source_decelerates_with_its_ramp_and_reason(event, fast, reason):
    t = transition(STREAMING, event)
    assert t.state.mode is Mode.STOPPING and t.actions == (BeginDeceleration(fast=fast),)
    assert t.state.stop_reason == reason and t.state.stop_fast == fast
    assert t.actions[0].mode == t.state.stop.kind.value == ("fast" if fast else "soft")
    assert t.state.stop is not None and t.state.stop.then is Then.HOLD
    assert not motion_allowed(t.state)


def test_fast_stop_needs_acknowledgement_at_rest_before_resume():
    s = STATES["stopping_fast"]
    t = transition(s, ResumeRequested())
    assert t.error == ("ResumeRequested refused in stopping: fast stop (sensor fault on ft: NaN): "
                       "wait for rest, then reset to acknowledge, then resume")
    assert "still decelerating" in (transition(s, ResetRequested()).error or "")
    s, ts = steps(s, ShaperAtRest())
    assert "reset to acknowledge" in (transition(s, ResumeRequested()).error or "")
    s, ts = steps(s, ResetRequested())
    assert s.mode is Mode.STOPPED and not s.stop_fast and ts[0].actions == ()  # reset never moves
    s, ts = steps(s, ResumeRequested())
    assert s.mode is Mode.STREAMING and ts[0].actions == (RESUME_MOTION,)


def test_fast_trigger_escalates_a_soft_stop():
    s, ts = steps(STATES["stopping_soft"], LimitApproaching("J2"), StopRequested("again"), InputStale("x"))
    assert ts[0].actions == (BeginDeceleration(fast=True),)
    assert s.stop_reason == "limit approaching: J2" and s.stop_fast
    assert ts[1].actions == ts[2].actions == ()
    s, ts = steps(STATES["stopped_soft"], SensorFault("imu"))
    assert ts[0].actions == () and s.stop_fast and not s.resumable


def test_an_explicit_stop_over_a_soft_stop_takes_its_place():
    """A stop requested while a hold-to-run that ran out (or a stale input) holds the arm: its reason
    stands, so only a resume moves on (a jog press resumed after it, as if it had not been sent)."""
    s, _ = steps(STATES["streaming_running"], JogExpired(), ShaperAtRest())
    assert s.mode is Mode.STOPPED and s.stop_reason == "hold-to-run expired"
    for start in (s, STATES["stopping_soft"]):
        t = transition(start, StopRequested("operator stop"))
        assert t.state.mode is start.mode and t.state.stop_reason == "operator stop" and t.actions == ()
        assert not t.state.stop_fast and t.state.resumable
    # A later trigger does not take it back; a fast stop is not made soft; an ending stays an ending.
    s2, _ = steps(s, StopRequested("operator stop"), JogExpired(), InputStale("x"))
    assert s2.stop_reason == "operator stop"
    fast = transition(STATES["stopped_fast"], StopRequested("soft again")).state
    assert fast.stop_fast and fast.stop_reason == STATES["stopped_fast"].stop_reason
    ending, _ = steps(STATES["streaming_running"], EndRequested("done"))
    assert transition(ending, StopRequested("x")).state.stop_reason == ending.stop_reason
    s3, ts = steps(s, StopRequested("operator stop"), ResumeRequested())
    assert s3.mode is Mode.STREAMING and ts[-1].actions == (RESUME_MOTION,)


def test_end_after_a_fast_stop_needs_no_acknowledgement():
    _, ts = steps(STATES["stopping_fast"], EndRequested(), ShaperAtRest(), LastDataProcessed())
    assert [t.state.mode for t in ts] == [Mode.STOPPING, Mode.ENDING, Mode.ENDED]
    assert ts[0].actions == () and ts[1].actions == (SEND_LAST_DATA,)


@pytest.mark.parametrize("start", ["streaming_running", "stopping_soft", "stopping_fast", "stopped_soft"])
def test_an_end_with_a_reason_names_the_stop_through_to_ended(start: str):
    """The service's own end (its session log cannot take the stream): whatever stop was under way, the
    stream ends, softly unless already fast, and its reason is what the operator reads once ended."""
    before = STATES[start]
    s, ts = steps(before, EndRequested(reason="session log: the disk is full"), ShaperAtRest(), IDLE)
    assert [t.error for t in ts] == [None, None, None]
    assert s.mode is Mode.ENDED and s.stop_reason == "session log: the disk is full"
    assert s.stop_fast == before.stop_fast  # an end never slows a fast stop down
    if before.mode is Mode.STREAMING:
        assert ts[0].actions == (BeginDeceleration(fast=False),)
    elif before.mode is Mode.STOPPED:
        assert ts[0].state.mode is Mode.ENDING and ts[0].actions == (SEND_LAST_DATA,)
    else:
        assert ts[0].actions == () and ts[1].actions == (SEND_LAST_DATA,)


def test_an_end_without_a_reason_keeps_the_stop_under_way():
    s = transition(STATES["stopped_soft"], EndRequested()).state
    assert s.mode is Mode.ENDING and s.stop_reason == STATES["stopped_soft"].stop_reason
    assert transition(STATES["stopping_end"], EndRequested()).state == STATES["stopping_end"]


def test_controller_alarm_faults_with_the_manuals_cause_and_remedy():
    t = transition(STREAMING, alarm("MOTN-611", "MOTN-611 ST:Exceeded Jnt Jerk Limit.(A:3,Sq.12)"))
    assert t.state.mode is Mode.FAULT
    f = t.state.fault
    assert f is not None and f.code == "MOTN-611" and f.during is Mode.STREAMING
    assert f.cause == ALARMS["MOTN-611"].cause and f.remedy == ALARMS["MOTN-611"].remedy
    assert f.message.startswith("MOTN-611 ST:Exceeded")
    assert t.actions == (ABANDON_STREAM, RecordFault(f))
    assert not motion_allowed(t.state)


def test_alarm_when_not_streaming_records_without_abandoning():
    t = transition(STATES["ready"], alarm("MOTN-606"))
    assert t.state.mode is Mode.FAULT and t.actions == (RecordFault(t.state.fault),)  # type: ignore[arg-type]


def test_unknown_alarm_code_still_faults():
    t = transition(STREAMING, alarm("SRVO-001", "SRVO-001 Operator panel E-stop"))
    assert t.state.fault is not None and t.state.fault.code == "SRVO-001"
    assert "not in the controller's alarm catalogue" in t.state.fault.cause


def test_warning_is_reported_and_changes_nothing():
    spec = ALARMS[WARNING_CODE]
    for s in STATES.values():
        t = transition(s, alarm(WARNING_CODE, "w"))
        assert t.state == s and t.error is None
        assert t.actions == (ReportWarning(WARNING_CODE, "w", spec.cause, spec.remedy),)


@pytest.mark.parametrize("state_name", ["streaming_running", "stopping_soft", "stopped_soft"])
def test_bit0_falling_while_streaming_faults_and_a_later_alarm_explains_it(state_name):
    s, ts = steps(STATES[state_name], IDLE)
    assert s.mode is Mode.FAULT and s.fault is not None and s.fault.code is None
    assert "bit 0 fell" in s.fault.message and s.fault.during is STATES[state_name].mode
    assert ts[0].actions[0] == ABANDON_STREAM
    s, ts = steps(s, alarm("MOTN-603", "MOTN-603 ST:Receiving interval over"))
    assert s.fault is not None and s.fault.code == "MOTN-603" and s.fault.cause == ALARMS["MOTN-603"].cause
    assert "bit 0 fell" in s.fault.message and s.fault.during is STATES[state_name].mode
    # a further alarm is a consequence: logged, the root cause stays
    s2, ts = steps(s, alarm("MOTN-618"))
    assert s2 == s and isinstance(ts[0].actions[0], RecordFault) and ts[0].actions[0].fault.code == "MOTN-618"


@pytest.mark.parametrize("event", [StatusLost(), Disconnected(), SERVO_OFF])
def test_link_loss_or_servo_off_while_alive_faults(event):
    for name in ("streaming_running", "stopping_soft", "stopped_fast", "ending"):
        t = transition(STATES[name], event)
        assert t.state.mode is Mode.FAULT and t.actions[0] == ABANDON_STREAM, name
        assert t.state.fault is not None and t.state.fault.remedy


def test_fault_is_left_only_by_reset_to_the_mode_the_status_shows():
    for s in (STATES[n] for n in STATES if n.startswith("fault")):
        for name, e in EVENTS.items():
            if name != "reset":
                assert transition(s, e).state.mode is Mode.FAULT, (s, e)  # type: ignore[arg-type]
    assert transition(STATES["fault_status_lost"], ResetRequested()).state.mode is Mode.DISCONNECTED
    assert transition(STATES["fault_bit0"], ResetRequested()).state.mode is Mode.CONNECTED
    assert transition(STATES["fault_idle_waiting"], ResetRequested()).state.mode is Mode.READY
    # a controller still mid-stream (bit 1 = 1) is not ready for a fresh first command
    stale = replace(STATES["fault_alarm"], status=StatusBits(bit0=True, bit1=True, sysrdy=True))
    assert transition(stale, ResetRequested()).state.mode is Mode.CONNECTED
    t = transition(STATES["fault_alarm"], ResetRequested())
    assert t.state.fault is None and t.actions == ()


def test_reconnect_after_a_lost_link_fault():
    s, ts = steps(STATES["fault_status_lost"], ConnectRequested(), WAITING, ResetRequested(),
                  StartRequested())
    assert ts[0].actions == (START_STATUS_OUTPUT,) and ts[1].state.mode is Mode.FAULT
    assert s.mode is Mode.STREAMING


def test_new_stream_after_ended_only_when_the_controller_waits_again():
    t = transition(STATES["ended"], StartRequested())
    assert t.error is not None and "status bit 0 = 0" in t.error and "IBGN" in t.error
    t = transition(STATES["ended_waiting"], StartRequested())
    assert t.state.mode is Mode.STREAMING and t.actions == (SEND_FIRST_COMMAND, HOLD_POSITION)
    assert t.state.stop is None


@pytest.mark.parametrize(("state_name", "event", "expected"), [
    ("ended", ResumeRequested(), "ResumeRequested refused in ended: the stream has ended"),
    ("fault_alarm", StartRequested(), "StartRequested refused in fault: reset the fault first"),
    ("disconnected", StartRequested(),
     "StartRequested refused in disconnected: no status packets: connect first"),
    ("connected_stale_stream", StartRequested(), "StartRequested refused in connected: the controller "
     "already received commands in this IBGN run (status bit 1 = 1): restart the program"),
    ("streaming", StartRequested(), "StartRequested refused in streaming: a stream is already running"),
    ("streaming", ResumeRequested(), "ResumeRequested refused in streaming: already streaming"),
    ("stopping_end", ResumeRequested(), "ResumeRequested refused in stopping: the stream is ending"),
    ("stopped_soft", ResetRequested(),
     "ResetRequested refused in stopped: nothing to acknowledge (soft stop: resume instead)"),
    ("ready", EndRequested(), "EndRequested refused in ready: no stream to end"),
    ("ready", ConnectRequested(), "ConnectRequested refused in ready: status packets are already flowing"),
    ("disconnected_shutdown", ConnectRequested(), "ConnectRequested refused in disconnected: shutting down"),
    ("ended_shutdown", StartRequested(), "StartRequested refused in ended: shutting down"),
])
def test_illegal_requests_are_refused_with_a_clear_error(state_name, event, expected):
    s = STATES[state_name]
    assert transition(s, event) == Transition(s, (), expected)


def test_disconnect_is_refused_while_the_stream_is_alive():
    for s in STATES.values():
        t = transition(s, DisconnectRequested())
        if s.mode in STREAM_ALIVE:
            assert t.error is not None and "61.3" in t.error
        else:
            assert t.actions == (STOP_STATUS_OUTPUT,) and t.state.status is None


def test_stop_is_never_refused():
    for s in STATES.values():
        assert transition(s, StopRequested()).error is None
        assert transition(s, StopRequested(fast=True)).error is None


def test_status_from_byte_and_ready_needs_a_fresh_ibgn_run_with_servo_on():
    assert StatusReceived.from_byte(0b1101) == StatusReceived(True, False, True, True)
    fields = ("bit0", "bit1", "sysrdy", "moving")  # the safety machine's own layout is J519's
    for bit, field in zip((StatusBit.WAITING_FOR_COMMAND, StatusBit.COMMAND_RECEIVED, StatusBit.SYSRDY,
                           StatusBit.MOVING), fields, strict=True):
        assert StatusReceived.from_byte(int(bit)) == StatusReceived(**{f: f == field for f in fields})
    assert transition(SafetyState(), StatusReceived.from_byte(0b0101)).state.mode is Mode.READY
    assert transition(SafetyState(), StatusReceived.from_byte(0b0111)).state.mode is Mode.CONNECTED
    assert transition(SafetyState(), StatusReceived.from_byte(0b0001)).state.mode is Mode.CONNECTED
    assert transition(STATES["ready"], IDLE).state.mode is Mode.CONNECTED


def test_never_raises_on_unknown_events_or_malformed_states():
    t = transition(STREAMING, object())  # type: ignore[arg-type]
    assert t.state == STREAMING and t.actions == () and "unknown event" in (t.error or "")
    broken = SafetyState(mode=Mode.STOPPING, status=STREAMING.status, stop=None)
    for e in EVENTS.values():
        transition(broken, e)  # type: ignore[arg-type]
    # a stop of unknown kind is treated as an unacknowledged fast stop
    assert transition(broken, ResumeRequested()).error is not None
    assert transition(STREAMING, Signal("TERM")).state == STREAMING  # type: ignore[arg-type]
    assert transition(SafetyState(mode=Mode.FAULT), alarm("MOTN-603")).state.fault is not None


def test_an_internal_error_while_moving_takes_the_fast_ramp(monkeypatch):
    def boom(s, e):
        raise RuntimeError("bug")

    monkeypatch.setitem(sm._HANDLERS, InputStale, boom)
    t = transition(STREAMING, InputStale("x"))
    assert t.error is not None and "internal error" in t.error and "bug" in t.error
    assert t.state.mode is Mode.STOPPING and t.state.stop_fast
    assert t.actions == (BeginDeceleration(fast=True),)
    t = transition(STATES["stopping_soft"], InputStale("x"))
    assert t.state.stop_fast and t.actions == (BeginDeceleration(fast=True),)
    for name in ("ready", "stopped_soft", "fault_alarm"):
        t = transition(STATES[name], InputStale("x"))
        assert t.state == STATES[name] and t.actions == () and t.error is not None
