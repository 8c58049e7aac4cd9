"""A frozen controller at the supervisor (pure: the controller model on a simulated clock).

The controller stops mid-stream (SIGSTOP of its process: no status, and what is sent to it waits in
its socket), the operator resets and starts while it is frozen (the start fails: no status after the
status output start), then it thaws and takes that status output start late. The link and the safety
state must agree again, reset and start must give their true reasons, and once the controller's
alarm is reset at its pendant a start streams. (Before the fix the link stayed failed beside a
connected safety state: reset was refused, and every start gave up at once on the old reason.)
The same with real processes and signals: tests/test_fault_matrix_e2e.py::test_controller_frozen_then_back.
"""

from __future__ import annotations

import pytest
from test_servo_cycle_property import CLIENT, Cell

from servo_app.errors import CommandRejected
from servo_app.fanuc.packets import StatusStart
from servo_app.fanuc.session import Phase
from servo_app.messages import End, Jog, Request, Reset, Start
from servo_app.safety import Mode


class FrozenCell(Cell):
    """A Cell whose controller can be frozen: it neither ticks nor reads, and the datagrams sent to it
    meanwhile wait in its socket's buffer, delivered in order when it thaws."""

    def __init__(self) -> None:
        super().__init__()
        self.frozen = False
        self.buffered: list[bytes] = []

    def deliver(self, out: list[bytes]) -> None:
        if self.frozen:
            self.buffered += out
        else:
            super().deliver(out)

    def thaw(self) -> None:
        self.frozen = False
        out, self.buffered = self.buffered, []
        self.deliver(out)

    def cycle(self) -> None:
        if self.frozen:
            self.t += self.dt
            self.deliver(self.sup.on_idle(self.t))
        else:
            super().cycle()
        self.sup.watch_start(self.t)  # as the servo process does every loop

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / self.dt)):
            self.cycle()

    def refused(self, req: Request) -> str:
        before = (self.sup.state, self.sup.session.phase, self.sup.start_pending)
        with pytest.raises(CommandRejected) as exc:
            self.sup.request(req, self.t)
        self.deliver(self.sup._take())
        assert (self.sup.state, self.sup.session.phase, self.sup.start_pending) == before  # nothing changed
        return str(exc.value)

    def start_outcome(self, limit_s: float = 10.0) -> str:
        """Start, and run until the start streams ("") or is given up (its reason)."""
        assert self.request(Start())
        for _ in range(round(limit_s / self.dt)):  # (the service answers a start once the link streams)
            if not self.sup.start_pending and self.sup.session.phase != Phase.WAITING_READY:
                break
            self.cycle()
        assert not self.sup.start_pending
        return "" if self.sup.state.mode is Mode.STREAMING else self.sup.start_error


def frozen_after_a_failed_start() -> FrozenCell:
    cell = FrozenCell()
    cell.start()
    assert cell.request(Jog(joints=(20.0, 0, 0, 0, 0, 0), hold_s=0.5))
    cell.run(0.2)
    cell.frozen = True
    cell.run(0.2)
    assert cell.sup.state.mode is Mode.FAULT and "status packets lost" in cell.sup.state.fault.message  # type: ignore[union-attr]
    assert cell.request(Reset())
    assert cell.sup.state.mode is Mode.DISCONNECTED
    why = cell.start_outcome()
    assert "no status packet" in why and "after status output start" in why, why
    assert cell.buffered == [StatusStart().encode()]  # the start's status output start waits in the socket
    return cell


def test_a_frozen_controller_that_thaws_is_connected_and_gives_true_reasons() -> None:
    cell = frozen_after_a_failed_start()
    cell.thaw()
    cell.run(0.3)
    sup = cell.sup
    # It was starved of commands: MOTN-603 holds, SYSRDY off; status flows again from the late start.
    assert any(line.startswith("MOTN-603") for line in cell.lines), cell.lines
    assert sup.state.mode is Mode.CONNECTED and sup.state.status is not None and not sup.state.status.sysrdy
    assert sup.session.phase == Phase.CONNECTED  # the link agrees with the safety state
    assert sup.describe()["link_error"] == "" and sup.describe()["fault"] is None
    assert "SYSRDY is off" in (sup.describe()["not_ready"] or ""), sup.describe()  # the state says why
    # Reset has no fault to reset, as the state says; a start waits for the controller and then names
    # why it never became ready, not the failure of the start made while it was frozen.
    assert "reset refused in connected: no fault to reset" in cell.refused(Reset())
    why = cell.start_outcome()
    assert "SYSRDY is off" in why and "no status packet" not in why, why
    assert sup.session.phase == Phase.CONNECTED and sup.state.mode is Mode.CONNECTED
    # The alarm reset at the controller's pendant: the next start streams from the flowing status.
    cell.ctrl.reset()
    cell.run(0.5)
    assert sup.state.mode is Mode.READY and sup.describe()["not_ready"] is None
    assert cell.start_outcome() == ""
    n = len(cell.sent)
    assert cell.request(Jog(joints=(20.0, 0, 0, 0, 0, 0), hold_s=0.5))
    cell.run(0.3)
    assert sup.state.mode is Mode.STREAMING and cell.sent[-1][0] - cell.sent[n][0] > 1.0  # J1 moved
    assert [line for line in cell.lines if not line.startswith("MOTN-603")] == [], cell.lines


def test_a_controller_frozen_after_a_stream_ended_is_relinked_when_it_thaws() -> None:
    """The same from ended (no alarm: no stream was alive): the link follows the status back, and a
    start streams from the flowing status."""
    cell = FrozenCell()
    cell.start()
    assert cell.request(End())
    cell.run(1.5)
    assert cell.sup.state.mode is Mode.ENDED and cell.sup.state.status is None
    cell.frozen = True
    why = cell.start_outcome()
    assert "no status packet" in why and "after status output start" in why, why
    cell.thaw()
    cell.run(0.5)
    assert cell.sup.state.mode is Mode.ENDED and cell.sup.state.status is not None
    assert cell.sup.session.phase == Phase.CONNECTED and cell.sup.describe()["link_error"] == ""
    assert cell.start_outcome() == ""
    assert cell.lines == []


def test_a_start_never_gives_up_on_an_earlier_starts_link_failure() -> None:
    """Whatever left the link failed outside a fault (here: forced, beside a connected safety state), a
    start sends a fresh status output start and waits on it, never giving up on that failure's reason."""
    cell = FrozenCell()
    cell.ctrl.on_datagram(StatusStart().encode(), cell.t, CLIENT)  # status flows (another start's)
    cell.ctrl.abort_program()  # not waiting for commands: the safety state stays connected
    cell.run(0.1)
    sup = cell.sup
    assert sup.state.mode is Mode.CONNECTED and sup.session.phase == Phase.CONNECTED
    sup.session.abandon("an earlier start's link failure", cell.t)
    sent: list[bytes] = []
    cell.deliver = sent.extend  # type: ignore[method-assign]
    assert cell.request(Start())
    assert sent == [StatusStart().encode()]
    sup.watch_start(cell.t)
    assert sup.start_pending and sup.start_error == "" and sup.session.phase == Phase.FETCHING_TABLES
