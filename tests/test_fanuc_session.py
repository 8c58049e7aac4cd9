"""The client-side stream session as a pure state machine: sequencing, lead, losses, ending."""

from __future__ import annotations

import numpy as np
import pytest

from servo_app.fanuc import packets as P
from servo_app.fanuc.session import IoRequest, Phase, SessionConfig, StreamSession
from servo_app.motion.limit_tables import LimitTables


class Hold:
    """A motion source that holds the start position and counts its calls."""

    def __init__(self) -> None:
        self.q0: np.ndarray | None = None
        self.tables: LimitTables | None = None
        self.calls = 0
        self.rest_requested = False
        self.rest_after = 0  # commands until "at rest" once rest is requested

    def begin(self, q_start: np.ndarray, tables: LimitTables | None) -> None:
        self.q0, self.tables = q_start, tables

    def next_command(self, status: P.Status) -> np.ndarray:
        self.calls += 1
        if self.rest_requested:
            self.rest_after -= 1
        assert self.q0 is not None
        return self.q0 + 0.001 * self.calls

    def request_rest(self) -> None:
        self.rest_requested = True

    def at_rest(self) -> bool:
        return self.rest_requested and self.rest_after <= 0


BITS = P.StatusBit.WAITING_FOR_COMMAND | P.StatusBit.SYSRDY


def status(seq: int, bits: int = BITS, joints: tuple[float, ...] = (1, 2, 3, 4, 5, 6)) -> bytes:
    return P.Status(seq=seq, status=bits, joints=joints).encode()


def commands(out: list[bytes]) -> list[P.Command]:
    return [c for c in map(P.decode_from_pc, out) if isinstance(c, P.Command)]


def open_streaming(lead: int = 0, first_seq: int = 5) -> tuple[StreamSession, Hold, list[bytes]]:
    m = Hold()
    s = StreamSession(m, SessionConfig(lead=lead, fetch_tables=False))
    out = s.open(0.0)
    assert out == [P.StatusStart().encode()]
    assert s.phase == Phase.CONNECTED
    assert s.on_datagram(status(first_seq - 2), 0.004) == []  # ready, but streaming is not armed
    s.arm()
    assert s.on_datagram(status(first_seq - 1, bits=P.StatusBit.SYSRDY), 0.008) == []  # not ready yet
    out = s.on_datagram(status(first_seq), 0.016)
    s.begin_motion()  # as the runner does once the first commands have gone
    return s, m, out


def test_first_command_carries_the_status_seq_then_plus_one() -> None:
    s, m, out = open_streaming(first_seq=41)
    (c,) = commands(out)
    assert c.seq == 41 and c.data_format == P.DataFormat.JOINT and c.last_data == 0
    assert m.q0 is not None and list(m.q0) == [1, 2, 3, 4, 5, 6]
    for k in range(1, 5):
        (c,) = commands(s.on_datagram(status(41 + k), 0.016 + 0.008 * k))
        assert c.seq == 41 + k
    assert s.phase == Phase.STREAMING


def test_exactly_one_command_per_status_and_none_for_duplicates() -> None:
    s, _, _ = open_streaming()
    assert len(commands(s.on_datagram(status(6), 0.1))) == 1
    assert s.on_datagram(status(6), 0.1) == []  # duplicated status packet
    assert s.on_datagram(status(4), 0.1) == []  # reordered, older
    assert s.stats.status_duplicated == 2


def test_lost_status_packets_are_made_up_for() -> None:
    s, _, _ = open_streaming(lead=1)
    (c,) = commands(s.on_datagram(status(6), 0.1))
    out = commands(s.on_datagram(status(9), 0.2))  # 7 and 8 lost on the wire
    assert [c.seq for c in out] == [c.seq + 1, c.seq + 2, c.seq + 3]
    assert s.stats.status_lost == 2


def test_lead_fills_the_buffer_once() -> None:
    _, _, out = open_streaming(lead=3, first_seq=10)
    assert [c.seq for c in commands(out)] == [10, 11, 12, 13]


def test_lead_bounded_by_the_controller_buffer() -> None:
    with pytest.raises(ValueError, match="lead=9"):
        SessionConfig(lead=9)


def test_sequence_wraps_to_zero() -> None:
    s, _, out = open_streaming(first_seq=0xFFFFFFFF)
    assert commands(out)[0].seq == 0xFFFFFFFF
    (c,) = commands(s.on_datagram(status(0), 0.1))
    assert c.seq == 0


def test_end_decelerates_then_last_data_then_stops_output_after_bit0_clears() -> None:
    s, m, _ = open_streaming(first_seq=5)
    m.rest_after = 3
    s.request_end()
    assert m.rest_requested
    seq, last = 6, []
    for _ in range(6):
        cs = commands(s.on_datagram(status(seq), 0.1))
        seq += 1
        last += [c.last_data for c in cs]
        if s.phase == Phase.ENDING:
            break
    assert last[-1] == 1 and all(v == 0 for v in last[:-1])
    # No more commands after last data, and no stop packet while bit 0 is still set.
    assert s.on_datagram(status(seq), 0.2) == []
    assert s.on_datagram(status(seq + 1, bits=P.StatusBit.SYSRDY), 0.21) == [P.StatusStop().encode()]
    assert s.phase == Phase.CLOSED


def test_io_writes_queued_at_an_end_go_out_before_last_data() -> None:
    """Writes answered as sent in this stream go out in it: last data waits for them (one per command)."""
    s, m, _ = open_streaming(first_seq=5)
    for k in range(4):
        s.write_io(IoRequest(P.IoType.DO, 1 + 16 * k, 1, 1))
    m.rest_after = 0  # at rest at once: only the writes hold the end back
    s.request_end()
    sent: list[P.Command] = []
    seq = 6
    while s.phase != Phase.ENDING and seq < 20:
        sent += commands(s.on_datagram(status(seq), 0.1))
        seq += 1
    assert [c.write_io_index for c in sent if c.write_io_type] == [1, 17, 33, 49]
    assert sent[-1].last_data == 1 and sent[-1].write_io_type == 0
    assert all(c.last_data == 0 for c in sent[:-1])


def test_io_writes_a_faulted_stream_never_sent_are_not_sent_in_the_next() -> None:
    """A write waiting when the stream faulted is dropped: the next stream, maybe hours later, must not
    set an output (a gripper) at its start."""
    s, _, _ = open_streaming()
    for k in range(3):
        s.write_io(IoRequest(P.IoType.DO, 1 + 16 * k, 1, 1))
    s.on_idle(0.5)
    assert s.phase == Phase.FAULT
    s.open(1.0)
    s.arm()
    sent = commands(s.on_datagram(status(1), 1.01))
    s.begin_motion()
    for k in range(2, 8):
        sent += commands(s.on_datagram(status(k), 1.01 + 0.008 * k))
    assert s.phase == Phase.STREAMING and len(sent) == 7
    assert [c.write_io_type for c in sent] == [0] * 7


def test_bit0_dropping_mid_stream_is_a_fault() -> None:
    s, _, _ = open_streaming()
    assert s.on_datagram(status(6, bits=0), 0.1) == []
    assert s.phase == Phase.FAULT and "status bit 0" in s.fault_reason


def test_status_silence_is_a_fault() -> None:
    s, _, _ = open_streaming()
    s.on_idle(0.05)
    assert s.phase == Phase.STREAMING
    s.on_idle(0.5)
    assert s.phase == Phase.FAULT and "no status packet" in s.fault_reason


def test_malformed_datagram_is_counted_not_fatal() -> None:
    s, _, _ = open_streaming()
    assert s.on_datagram(b"\x00\x00\x00\x00\x00\x00\x00\x01junk", 0.1) == []
    assert s.stats.malformed == 1 and "length=12" in s.stats.last_error
    assert len(commands(s.on_datagram(status(6), 0.1))) == 1


def test_limit_tables_requested_one_per_interval_then_used() -> None:
    m = Hold()
    s = StreamSession(m, SessionConfig(table_axes=1, max_payload_kg=7.0))
    s.open(0.0)
    s.arm()
    seen: list[P.LimitTableRequest] = []
    seq = 1
    for i in range(3):
        out = s.on_datagram(status(seq, bits=P.StatusBit.SYSRDY), 0.3 * i)
        seq += 1
        reqs = [p for p in map(P.decode_from_pc, out) if isinstance(p, P.LimitTableRequest)]
        assert len(reqs) == 1
        seen += reqs
        r = reqs[0]
        s.on_datagram(P.LimitTableResponse(r.axis, r.limit_type, 2000, 5, (10.0 + r.limit_type,) * 20,
                                           (5.0,) * 20).encode(), 0.3 * i + 0.001)
    assert [(r.axis, r.limit_type) for r in seen] == [(1, 0), (1, 1), (1, 2)]
    s.on_datagram(status(seq), 1.0)
    s.begin_motion()
    assert s.tables is not None and s.tables.vmax == 2000
    assert m.tables is s.tables and s.phase == Phase.STREAMING
    assert s.tables.at_speed(1, 0.0, 0.0)[0] == pytest.approx(11.0)


def test_unanswered_limit_tables_fall_back_to_the_profile() -> None:
    m = Hold()
    s = StreamSession(m, SessionConfig(table_axes=1, table_retries=2, table_timeout_s=0.1))
    s.open(0.0)
    t, seq = 0.0, 1
    while s.phase == Phase.FETCHING_TABLES and t < 5:
        s.on_datagram(status(seq, bits=P.StatusBit.SYSRDY), t)
        t += 0.05
        seq += 1
    assert s.phase == Phase.CONNECTED and s.tables is None
    assert "using the profile's limits" in s.stats.last_error


# ------------------------------------------------------------------------- lost links (issue 13)


def test_a_status_sequence_restarting_at_1_mid_stream_is_a_fault() -> None:
    """Another host's status output start (or a restarted controller) resets the sequence to 1."""
    s, _, _ = open_streaming(first_seq=50)
    assert s.on_datagram(status(51), 0.024)  # the stream goes on
    assert s.on_datagram(status(1), 0.032) == []
    assert s.phase == Phase.FAULT and "restarted its status output (sequence 51 -> 1)" in s.fault_reason


def test_silence_after_status_output_start_is_a_fault_that_names_refused_datagrams() -> None:
    s = StreamSession(Hold(), SessionConfig(fetch_tables=False, link_timeout_s=1.0))
    s.open(0.0)
    s.on_datagram(b"\x00\x00\x00\x00\x00\x00\x00\x02" + bytes(124), 0.5)  # a version-2 status
    s.on_idle(0.9)
    assert s.phase == Phase.CONNECTED
    s.on_idle(1.1)
    assert s.phase == Phase.FAULT
    assert "no status packet for 1.100 s after status output start" in s.fault_reason
    assert "datagrams refused meanwhile" in s.fault_reason and "version" in s.fault_reason


def test_a_malformed_datagram_sends_and_records_nothing() -> None:
    s, _, out = open_streaming()
    assert len(out) == 1 and len(s.sent) == 1
    assert s.on_datagram(b"\x00" * 13, 0.020) == [] and s.sent == []
    assert s.stats.malformed == 1


def test_recover_after_a_lost_link_restarts_the_status_output() -> None:
    s, _, _ = open_streaming()
    s.on_idle(0.5)  # silence while streaming
    assert s.phase == Phase.FAULT
    assert s.recover(0.6) and s.phase == Phase.IDLE and s.fault_reason == ""
    assert s.open(0.7) == [P.StatusStart().encode()]  # the next start sends a fresh status output start
    assert s.phase == Phase.CONNECTED


def test_status_arriving_after_a_reset_shows_the_link_is_up() -> None:
    s, _, _ = open_streaming()
    s.abandon("controller alarm", 0.3)  # the controller's alarm stopped the stream; status still flows
    assert s.recover(0.31) and s.phase == Phase.IDLE
    s.on_datagram(status(40, bits=P.StatusBit.SYSRDY), 0.32)
    assert s.phase == Phase.CONNECTED
    s.arm()  # a start can stream from the next waiting status without a new status output start
    assert s.phase == Phase.WAITING_READY


def test_relink_after_a_failed_status_output_start_is_connected_without_a_new_one() -> None:
    """A status output start nobody answered within the link timeout (a frozen controller), then status
    after all (it took the start late): relinked, the link is connected with its failure forgotten,
    and a start streams from the next ready status without another status output start."""
    s = StreamSession(Hold(), SessionConfig(fetch_tables=False, link_timeout_s=1.0))
    s.open(0.0)
    s.on_idle(1.1)
    assert s.phase == Phase.FAULT and "after status output start" in s.fault_reason
    assert s.on_datagram(status(1, bits=P.StatusBit.SYSRDY), 1.3) == []
    assert s.phase == Phase.FAULT  # the session alone cannot tell a lost stream from a late answer
    assert s.relink(1.3) and s.phase == Phase.CONNECTED and s.fault_reason == ""
    assert not s.relink(1.31)  # only a failed link
    s.arm()
    out = s.on_datagram(status(2), 1.316)
    assert s.phase == Phase.STREAMING and [c.seq for c in commands(out)] == [2]
    s.on_idle(1.32)
    assert s.phase == Phase.STREAMING  # silence is measured from the status, not from the failure


def test_relink_fetches_the_limit_tables_a_failed_first_link_never_got() -> None:
    s = StreamSession(Hold(), SessionConfig(fetch_tables=True, link_timeout_s=1.0))
    s.open(0.0)
    s.on_idle(1.1)
    assert s.phase == Phase.FAULT and s.tables is None
    s.on_datagram(status(1), 1.3)
    assert s.relink(1.3) and s.phase == Phase.FETCHING_TABLES
    out = s.on_datagram(status(2), 1.308)
    assert [P.decode_from_pc(b) for b in out] == [P.LimitTableRequest(1, P.LimitType.VELOCITY)]


def test_the_first_commands_are_the_hold_position_sent_before_the_motion_is_set_up() -> None:
    """The motion source's set-up takes most of a 4 ms interval: the hold position goes out first."""
    m = Hold()
    s = StreamSession(m, SessionConfig(lead=2, fetch_tables=False))
    s.open(0.0)
    s.arm()
    cmds = commands(s.on_datagram(status(9), 0.004))
    assert [c.seq for c in cmds] == [9, 10, 11]  # one for the status, two of lead
    assert all(c.values[:6] == (1, 2, 3, 4, 5, 6) for c in cmds) and m.calls == 0 and m.q0 is None
    s.begin_motion()
    assert m.q0 is not None and list(m.q0) == [1, 2, 3, 4, 5, 6]
    (c,) = commands(s.on_datagram(status(10), 0.008))
    assert c.seq == 12 and m.calls == 1  # from here on the motion source computes every command
