"""Requests at the supervisor (pure: the controller model on a simulated clock): a request is checked
whole before anything changes, and every refusal by the state ends with the operator's next step."""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pytest
from test_safety_state_machine import STATES
from test_servo_cycle_property import Cell

from servo_app.errors import CommandRejected, InvalidRequest
from servo_app.fanuc.supervisor import MAX_IO_WRITES_PENDING
from servo_app.input_slot import POSE, TWIST, InputCommand
from servo_app.messages import (
    ConfigureInputs,
    End,
    IoWrite,
    Jog,
    JointTarget,
    PoseTarget,
    Request,
    Reset,
    Resume,
    SetTool,
    Stop,
    Twist,
)
from servo_app.safety import Mode
from servo_app.supervision import next_step

# How a 409 text may end: an endpoint, or a plain word where no endpoint helps.
NEXT = re.compile(r"(POST /api/[a-z/]+(, then resume: POST /api/session/resume)?\)?|restart the service)$")


def stopped_by_hold_to_run(cell: Cell) -> None:
    cell.sup.request(Jog(joints=(0, 0, 0, 0, 0, 10.0), hold_s=0.05), cell.t)
    for _ in range(200):
        cell.cycle()
        if cell.sup.state.mode is Mode.STOPPED:
            return
    raise AssertionError(cell.sup.describe())


@pytest.mark.parametrize("bad", [
    Jog(joints=(10.0,)),
    Jog(joints=(5000.0, 0, 0, 0, 0, 0)),
    Jog(joints=(1e308, 0, 0, 0, 0, 0)),
    Jog(joints=(10.0, 0, 0, 0, 0, 0), hold_s=-1.0),
    JointTarget(joints=(400.0, 0, 0, 0, -90.0, 0)),
    JointTarget(joints=(0.0, 0, 0, 0, -90.0, 0), speed_scale=2.0),
    Twist(linear=(10000.0, 0.0, 0.0)),
    PoseTarget(xyzwpr=(2000.0, 0.0, 300.0, 180.0, 0.0, 0.0)),
    PoseTarget(xyzwpr=(0.4, 0.0, 0.3, 180.0, 0.0, 0.0)),
])
def test_a_bad_request_after_a_hold_to_run_stop_changes_nothing(bad: Request) -> None:
    cell = Cell()
    cell.start()
    stopped_by_hold_to_run(cell)
    before, hold = cell.sup.state, cell.sup.hold
    with pytest.raises(InvalidRequest):
        cell.sup.request(bad, cell.t)
    assert cell.sup.state == before and cell.sup.hold == hold  # not resumed, no hold-to-run timer


@pytest.mark.parametrize("kind", ["twist", "pose target"])
def test_a_motion_whose_flange_swing_is_over_the_cap_after_a_hold_to_run_stop_changes_nothing(kind: str) -> None:
    """Within the cap at the TCP, over it at the flange (a turn about a long tool): refused by the cycle,
    and refused before the gate, which would otherwise have resumed the stream (and held a jog)."""
    cell = Cell()
    cell.start()
    cell.sup.request(SetTool(name="long", xyzwpr=(0.0, 0.0, 1500.0, 0.0, 0.0, 0.0)), cell.t)
    stopped_by_hold_to_run(cell)
    before, hold = cell.sup.state, cell.sup.hold
    limit = cell.sup._flange_cap()
    swing = math.degrees(0.5 * limit / 1500.0)
    if kind == "twist":
        req: Request = Twist(linear=(0.8 * limit, 0.0, 0.0), angular=(0.0, 0.0, swing), frame="tool")
    else:
        req = PoseTarget(xyzwpr=(400.0, 0.0, 300.0, 180.0, 0.0, 0.0), linear_speed=0.8 * limit, angular_speed=swing)
    with pytest.raises(InvalidRequest, match="flange-speed cap"):  # the request's own values: 422
        cell.sup.request(req, cell.t)
    assert cell.sup.state == before and cell.sup.hold == hold  # not resumed, no hold-to-run timer
    assert not cell.sup.cycle.ik_active


def test_a_target_after_a_hold_to_run_stop_resumes_and_is_not_held() -> None:
    cell = Cell()
    cell.start()
    stopped_by_hold_to_run(cell)
    goal = np.array(cell.sent[-1]) + np.array([5.0, 0, 0, 0, 0, 0])
    cell.sup.request(JointTarget(joints=tuple(goal), speed_scale=0.3), cell.t)
    assert cell.sup.state.mode is Mode.STREAMING
    for _ in range(600):
        cell.cycle()
    assert cell.sup.state.mode is Mode.STREAMING and np.allclose(cell.sent[-1], goal, atol=1e-3)


@pytest.mark.parametrize("state_name", list(STATES))
@pytest.mark.parametrize("request_name", ["motion", "start", "resume", "end", "reset"])
def test_every_state_names_a_next_step(state_name: str, request_name: str) -> None:
    assert NEXT.search(next_step(STATES[state_name], request_name)) or "nothing to do" in next_step(
        STATES[state_name], request_name)


@pytest.mark.parametrize("state_name", [n for n, s in STATES.items() if s.mode is not Mode.STREAMING])
@pytest.mark.parametrize("req", [Resume(), Reset(), End(), Jog(joints=(1.0, 0, 0, 0, 0, 0)),
                                 JointTarget(joints=(0.0, 0, 0, 0, -90.0, 0)), Twist(linear=(1.0, 0, 0)),
                                 PoseTarget(xyzwpr=(400.0, 0.0, 300.0, 180.0, 0.0, 0.0))])
def test_every_refusal_by_the_state_ends_with_the_next_step(state_name: str, req: Request) -> None:
    cell = Cell()
    cell.start()  # the cycle is set up: a motion the gate lets through has somewhere to go
    cell.sup.state = replace(STATES[state_name])
    try:
        cell.sup.request(req, cell.t)
    except InvalidRequest as exc:
        raise AssertionError(f"a valid request refused as invalid: {exc}") from None
    except CommandRejected as exc:
        assert NEXT.search(str(exc)), str(exc)
        assert "Requested" not in str(exc), str(exc)  # the operator's words, not the state machine's
    cell.sup.request(Stop(), cell.t)


def test_a_steady_status_skips_the_state_machine_and_a_changed_one_still_reaches_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Streaming status packets with the same bits leave the safety state as it was (the transition is
    pure): the supervisor runs it once for them, not once per packet; a new bit is fed at once."""
    import servo_app.supervision as supervision

    fed: list[str] = []
    real = supervision.transition

    def counting(state, event):  # type: ignore[no-untyped-def]
        fed.append(type(event).__name__)
        return real(state, event)

    cell = Cell()
    cell.start()
    monkeypatch.setattr(supervision, "transition", counting)
    for _ in range(50):
        cell.cycle()
    assert cell.sup.state.mode is Mode.STREAMING and fed.count("StatusReceived") <= 2  # moving bit: one change
    cell.ctrl.abort_program()  # bit 0 falls: the controller stopped waiting for commands
    for _ in range(3):
        cell.cycle()
    assert cell.sup.state.mode is Mode.FAULT and "StatusReceived" in fed[-3:]


@pytest.mark.parametrize("kind", ["twist", "pose target"])
def test_an_input_whose_flange_swing_is_over_the_cap_after_a_hold_to_run_stop_changes_nothing(kind: str) -> None:
    """As a requested motion (above), for the inputs' live command: refused by the cycle before the gate,
    which resumes a hold-to-run stop for an input's move; the refusal is the inputs' error."""
    cell = Cell()
    cell.start()
    cell.sup.request(SetTool(name="long", xyzwpr=(0.0, 0.0, 1500.0, 0.0, 0.0, 0.0)), cell.t)
    cell.sup.request(ConfigureInputs(enable=True, sources=("tracker",)), cell.t)
    stopped_by_hold_to_run(cell)
    before, hold = cell.sup.state, cell.sup.hold
    limit = cell.sup._flange_cap()
    swing = math.degrees(0.5 * limit / 1500.0)
    if kind == "twist":
        cmd = InputCommand(kind=TWIST, frame="tool", values=(0.8 * limit, 0.0, 0.0, 0.0, 0.0, swing),
                           linear_speed=0.0, angular_speed=0.0, stamp=cell.t, timeout_s=0.2, source=0, stale=False)
    else:
        cmd = InputCommand(kind=POSE, frame="base", values=(400.0, 0.0, 300.0, 180.0, 0.0, 0.0),
                           linear_speed=0.8 * limit, angular_speed=swing, stamp=cell.t, timeout_s=0.2, source=0,
                           stale=False)
    cell.sup.on_input(cmd, cell.t)
    assert "flange-speed cap" in cell.sup.inputs.error
    assert cell.sup.state == before and cell.sup.hold == hold  # not resumed, no hold-to-run timer
    assert not cell.sup.cycle.ik_active


def test_io_writes_are_refused_once_the_queue_is_full_or_the_stream_ends_and_change_nothing() -> None:
    """One write goes out per command: a flood is refused at MAX_IO_WRITES_PENDING (an end waits for the
    queue, so it stays short), and a write after an end is refused (no command of the stream would
    carry it); the refusals queue nothing."""
    cell = Cell()
    cell.start()
    for k in range(MAX_IO_WRITES_PENDING):
        cell.sup.request(IoWrite(type="DO", index=1 + k, mask=1, value=1), cell.t)
    with pytest.raises(CommandRejected) as full:
        cell.sup.request(IoWrite(type="DO", index=1, mask=1, value=0), cell.t)
    assert NEXT.search(str(full.value)) and "waiting" in str(full.value)
    assert cell.sup.session.io_writes_pending == MAX_IO_WRITES_PENDING
    cell.request(End())
    while not cell.sup.session.end_requested:  # (the safety state asks the link to end once at rest)
        cell.cycle()
    assert cell.sup.session.io_writes_pending > 0  # the end waits for them
    with pytest.raises(CommandRejected) as ending:
        cell.sup.request(IoWrite(type="DO", index=1, mask=1, value=0), cell.t)
    assert NEXT.search(str(ending.value)) and "ending" in str(ending.value)
    for _ in range(MAX_IO_WRITES_PENDING + 200):
        cell.cycle()
        if cell.sup.state.mode is Mode.ENDED:
            break
    assert cell.sup.state.mode is Mode.ENDED, cell.sup.describe()
    assert cell.ctrl.io.read(2, 1, 0xFFFF) == 0xFFFF and cell.ctrl.alarm_active is False  # all 64 written
