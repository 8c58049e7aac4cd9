"""Input commands reach the servo cycle only when enabled; a stale source stops the arm."""

from __future__ import annotations

import time

import numpy as np
from test_servo_cycle_property import KIN, Cell

from servo_app.input_slot import NONE, POSE, TWIST, InputCommand, InputSlotReader, InputSlotWriter
from servo_app.messages import ConfigureInputs, Stop
from servo_app.robots.conventions import matrix_to_xyzwpr


def twist(vx: float, stamp: float, stale: bool = False, kind: int = TWIST) -> InputCommand:
    return InputCommand(kind=kind, frame="base", values=(vx, 0, 0, 0, 0, 0), linear_speed=0, angular_speed=0,
                        stamp=stamp, timeout_s=0.1, source=0, stale=stale)


def flange_x(cell: Cell) -> float:
    return float(matrix_to_xyzwpr(KIN.fk_fanuc_deg(cell.sent[-1]))[0])


def test_inputs_move_the_arm_only_when_enabled_and_stale_stops_it() -> None:
    cell = Cell()
    cell.start()
    x0 = flange_x(cell)
    for _ in range(30):  # not enabled: ignored
        cell.sup.on_input(twist(100.0, cell.t), cell.t)
        cell.cycle()
    assert flange_x(cell) == x0
    cell.request(ConfigureInputs(enable=True, sources=("spacemouse",)))
    for _ in range(80):
        cell.sup.on_input(twist(100.0, cell.t), cell.t)
        cell.cycle()
    assert flange_x(cell) > x0 + 20
    cell.sup.on_input(twist(0.0, cell.t, stale=True, kind=NONE), cell.t)
    assert cell.sup.state.mode.value == "stopping"
    assert cell.sup.state.stop_reason == "input spacemouse stale"
    for _ in range(100):
        cell.cycle()
    assert cell.sup.state.mode.value == "stopped" and cell.sup.cycle.at_rest()
    # A fresh sample after a stale stop does not restart the arm by itself: the operator resumes.
    before = flange_x(cell)
    for _ in range(20):
        cell.sup.on_input(twist(100.0, cell.t), cell.t)
        cell.cycle()
    assert flange_x(cell) == before and "refused in stopped" in cell.sup.inputs.error
    assert not cell.ctrl.alarms()


def test_pose_inputs_track_a_target() -> None:
    cell = Cell()
    cell.start()
    cell.request(ConfigureInputs(enable=True, sources=("tracker",)))
    goal = matrix_to_xyzwpr(KIN.fk_fanuc_deg(cell.sent[-1])) + np.array([30.0, 20.0, -10.0, 0, 0, 0])
    cmd = InputCommand(kind=POSE, frame="base", values=tuple(goal), linear_speed=200.0, angular_speed=30.0,
                       stamp=0.0, timeout_s=0.2, source=0, stale=False)
    for _ in range(150):
        cell.sup.on_input(cmd, cell.t)
        cell.cycle()
    assert np.allclose(matrix_to_xyzwpr(KIN.fk_fanuc_deg(cell.sent[-1]))[:3], goal[:3], atol=0.5)
    assert not cell.ctrl.alarms()


def test_slot_round_trip_between_writer_and_reader() -> None:
    w = InputSlotWriter()
    r = InputSlotReader(w.name)
    try:
        assert r.poll() is None
        cmd = twist(12.5, time.monotonic())
        w.publish(cmd)
        assert r.poll() == cmd
        assert r.poll() is None  # nothing new
    finally:
        r.close()
        w.close()


def test_an_input_taken_during_the_solve_makes_the_same_packet_as_one_read_before_it() -> None:
    """ServoCycle.late_command: a twist that arrives while the IK solves replaces the one the cycle
    began with, and the packet (and every one after) is what the new twist read in time would give."""
    late, timely = Cell(), Cell()
    for c in (late, timely):
        c.start()
        c.request(ConfigureInputs(enable=True, sources=("ft",)))
    x0 = flange_x(late)
    pending: list[InputCommand] = []
    taken: list[bool] = []

    def arrives_during_the_solve() -> None:  # one new command per solve, while there are any
        if pending:
            taken.append(late.sup.on_late_input(pending.pop(0), late.t))

    late.sup.cycle.late_command = arrives_during_the_solve
    for k in range(60):
        first, newer = twist(40.0 + k, late.t), twist(80.0 - k, late.t)
        late.sup.on_input(first, late.t)
        # Every third cycle a second one arrives during the solve again: the newest makes the packet.
        pending += [twist(60.0, late.t), newer] if k % 3 == 0 else [newer]
        timely.sup.on_input(newer, timely.t)
        late.cycle()
        timely.cycle()
        assert np.array_equal(late.sent[-1], timely.sent[-1]), k
    assert all(taken) and len(taken) == 80 and late.sup.cycle.late_inputs == 80
    assert flange_x(late) > x0 + 5  # it moved
    assert not late.ctrl.alarms()


def test_late_inputs_that_change_the_safety_state_wait_for_the_next_packet() -> None:
    cell = Cell()
    cell.start()
    assert not cell.sup.on_late_input(twist(50.0, cell.t), cell.t)  # input control not enabled
    cell.request(ConfigureInputs(enable=True, sources=("ft",)))
    assert not cell.sup.on_late_input(twist(0.0, cell.t, stale=True, kind=NONE), cell.t)
    assert not cell.sup.on_late_input(twist(0.0, cell.t, kind=NONE), cell.t)
    assert cell.sup.state.mode.value == "streaming"
    assert cell.sup.on_late_input(twist(50.0, cell.t), cell.t)
    cell.request(Stop())
    assert not cell.sup.on_late_input(twist(50.0, cell.t), cell.t)  # stopping: only a resume moves it


def test_peek_leaves_the_command_new_until_consumed() -> None:
    w = InputSlotWriter()
    r = InputSlotReader(w.name)
    try:
        first, second = twist(1.0, 1.0), twist(2.0, 2.0)
        w.publish(first)
        assert r.peek() == first and r.peek() == first  # not taken yet
        w.publish(second)
        assert r.peek() == second and r.current is None  # peeked, not taken
        r.consume()
        assert r.current == second
        assert r.peek() is None and r.poll() is None
        w.publish(first)
        assert r.peek() == first
        w.publish(second)  # written after the peek: consuming the peeked one keeps this one new
        r.consume()
        assert r.current == first and r.poll() == second and r.current == second
        assert second.same_motion(twist(2.0, 5.0)) and not second.same_motion(first)
        assert not second.same_motion(twist(2.0, 2.0, stale=True))
        assert not second.same_motion(None)
    finally:
        r.close()
        w.close()
