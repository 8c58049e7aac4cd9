"""A stream's first command (the hold position) goes out before its ready status is decoded.

The packet is made while waiting for bit 0 (``prepare_first_command``); at the ready status only its
sequence number and joints are copied in (``first_command_early``), the runner sends it, and the
session then goes on as if it had sent it itself: the same bytes, never twice, logged as sent ahead.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_fanuc_session import BITS, Hold, commands, status
from test_servo_cycle_property import Cell

from servo_app.fanuc import packets as P
from servo_app.fanuc.session import IoRequest, Phase, SessionConfig, StreamSession
from servo_app.messages import End, Request, Start
from servo_app.robots.conventions import matrix_to_xyzwpr

JOINTS = (10.5, -20.25, 30.0, -0.0, -90.0, 1e-7)


def armed(lead: int = 2) -> StreamSession:
    s = StreamSession(Hold(), SessionConfig(lead=lead, fetch_tables=False))
    s.open(0.0)
    s.arm()
    return s


@pytest.mark.parametrize("fmt", ["joint", "cartesian, still", "cartesian, moved"])
def test_the_early_first_command_is_byte_for_byte_the_one_the_session_would_send(fmt: str) -> None:
    slow, fast = armed(), armed()
    fast.io_read = slow.io_read = IoRequest(P.IoType.DI, 1, 0xFF)
    data = status(9, joints=JOINTS)
    if fmt != "joint":
        fast.to_cartesian = slow.to_cartesian = lambda q: q * 1.5 + 100.0
        seen = JOINTS if fmt.endswith("still") else (0.0,) * 6  # the last status before the ready one
        fast.on_datagram(status(8, bits=P.StatusBit.SYSRDY, joints=seen), 0.0)
        slow.on_datagram(status(8, bits=P.StatusBit.SYSRDY, joints=seen), 0.0)
    fast.prepare_first_command(True)
    first = fast.first_command_early(data)
    assert first is not None
    out_fast, out_slow = fast.on_datagram(data, 0.004), slow.on_datagram(data, 0.004)
    assert [first, *out_fast] == out_slow  # the same packets, the first not sent twice
    assert [c.seq for c in commands(out_fast)] == [10, 11]  # the lead follows through the session
    assert fast.sent[0].early and fast.sent[0].data == first and not fast.sent[1].early
    assert fast.sent[0].command == slow.sent[0].command and fast.stats.commands_sent == 3
    fast.begin_motion()
    (c,) = commands(fast.on_datagram(status(10, joints=JOINTS), 0.008))
    assert c.seq == 12 and fast.phase == Phase.STREAMING


@pytest.mark.parametrize("bits", [P.StatusBit.SYSRDY, BITS | P.StatusBit.COMMAND_RECEIVED,
                                  BITS | P.StatusBit.MOVING, P.StatusBit.WAITING_FOR_COMMAND])
def test_a_status_that_is_not_ready_gets_nothing_ahead(bits: int) -> None:
    s = armed()
    s.prepare_first_command(True)
    assert s.first_command_early(status(9, bits=bits)) is None
    assert s.first_command_early(b"\0" * 7) is None
    assert s.first_command_early(P.Status(seq=9, status=BITS, version=2).encode()) is None
    assert s.first_command_early(status(9)) is not None  # still prepared


def test_a_duplicate_status_gets_nothing_ahead() -> None:
    s = StreamSession(Hold(), SessionConfig(fetch_tables=False))
    s.open(0.0)
    s.on_datagram(status(7, bits=P.StatusBit.SYSRDY), 0.004)
    s.arm()
    s.prepare_first_command(True)
    assert s.first_command_early(status(7)) is None and s.first_command_early(status(6)) is None
    assert s.first_command_early(status(8)) is not None


@pytest.mark.parametrize("why", ["not starting", "end requested", "io write queued", "streaming"])
def test_nothing_is_prepared_unless_the_next_ready_status_starts_the_stream(why: str) -> None:
    s = armed(lead=0)
    starts = why != "not starting"
    if why == "end requested":
        s.request_end()
    elif why == "io write queued":
        s.write_io(IoRequest(P.IoType.DO, 1, 1, 1))
    elif why == "streaming":
        s.on_datagram(status(9), 0.004)
    s.prepare_first_command(starts)
    assert s.first_command_early(status(10)) is None


class RunnerCell(Cell):
    """The supervisor driven as the runner drives it: the packet prepared after each datagram and
    request, the first command sent ahead of the status's handling."""

    def __init__(self, interval_ms: int = 8) -> None:
        super().__init__(interval_ms)
        self.early: list[bytes] = []

    def cycle(self) -> None:
        self.t += self.dt
        raw = self.ctrl.tick(self.t)
        if raw is None:
            self.deliver(self.sup.on_idle(self.t))
        else:
            first = self.sup.session.first_command_early(raw)  # as the runner does
            if first is not None:
                self.early.append(first)
                self.deliver([first])
            self.deliver(self.sup.on_datagram(raw, self.t))
            self.sent += [np.array(c.command.values[:6]) for c in self.sup.session.sent]
        self.sup.prepare_first_command()

    def request(self, req: Request) -> bool:
        ok = super().request(req)
        self.sup.prepare_first_command()
        return ok

    def wait(self, mode: str, cycles: int = 400) -> None:
        for _ in range(cycles):
            self.cycle()
            if self.sup.state.mode.value == mode:
                return
        raise AssertionError(f"never {mode}: {self.sup.describe()}")


@pytest.mark.parametrize("interval_ms", [8, 4])
@pytest.mark.parametrize("data_format", ["joint", "cartesian"])
def test_a_started_stream_begins_with_the_early_command_and_the_controller_takes_it(
        interval_ms: int, data_format: str) -> None:
    cell = RunnerCell(interval_ms)
    if data_format == "cartesian":
        kin = cell.sup.cycle.kin
        cell.sup.session.to_cartesian = lambda q: matrix_to_xyzwpr(kin.fk_fanuc_deg(q))
    for round_ in range(2):  # a first start (limit tables fetched first), then one after an ended stream
        if round_ == 0:
            cell.start()
        else:
            cell.request(Start())
            cell.wait("streaming")
        assert len(cell.early) == round_ + 1
        first = P.decode_from_pc(cell.early[-1])
        assert isinstance(first, P.Command)
        assert first.seq == cell.ctrl.last_status_seq and cell.sup.session.sent[0].early
        assert first.data_format == (P.DataFormat.JOINT if data_format == "joint" else P.DataFormat.CARTESIAN)
        for _ in range(30):
            cell.cycle()
        assert cell.sup.state.mode.value == "streaming" and cell.lines == []  # no alarm: 600, 617, 156...
        assert cell.ctrl.processed_commands > 0
        cell.request(End())
        cell.wait("ended")
        for _ in range(60):  # the controller's program comes back to IBGN start
            cell.cycle()
    assert cell.lines == []
