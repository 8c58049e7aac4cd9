"""The client side of Stream Motion (manual 61.3, 61.4) as a pure state machine.

Feed it every datagram from the controller and a clock; it returns the datagrams to send. It owns the
protocol rules, nothing else:

- status output start; limit tables requested one per status interval (61.3 note 4: keep the total
  rate under 1 packet/ms); the profile's tables are used when the controller does not answer;
- wait for status bit 0, then the first command carries the sequence number of the status just
  received, each later command +1;
- exactly one command per status packet, plus an optional *lead* of N commands kept in the
  controller's buffer (61.4). The count to send is derived from the status sequence number, so a lost
  status packet is made up for on the next one and a duplicated one sends nothing;
- ending: the motion source decelerates to rest, a command with last data = 1 follows, and only when
  status bit 0 has cleared is the status output stopped (61.3 note 2, 61.4 note 2).

Motion itself comes from a :class:`MotionSource` (the servo cycle): this module never computes a
position, and it integrates nothing from the servo position.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Protocol

import numpy as np

from servo_app.fanuc.packets import (
    COMMAND_VALUES_OFFSET,
    SEQ_OFFSET,
    STATUS_BITS_OFFSET,
    STATUS_HEADER,
    STATUS_JOINTS_OFFSET,
    STATUS_SIZE,
    Command,
    DataFormat,
    LimitTableRequest,
    LimitTableResponse,
    LimitType,
    PacketError,
    Status,
    StatusBit,
    StatusStart,
    StatusStop,
    decode_from_robot,
    next_seq,
    pack_command,
    seq_diff,
)
from servo_app.motion.limit_tables import LimitTables, tables_from_rows

MAX_PKT_STACK = 10  # $PKT_STACK default and maximum (61.6): at most 9 unprocessed commands
# The status bits of a ready status, of those the session looks at: waiting for commands, SYSRDY, and
# neither a command received yet nor moving (see _maybe_start).
_READY_MASK = (StatusBit.WAITING_FOR_COMMAND | StatusBit.COMMAND_RECEIVED | StatusBit.SYSRDY
               | StatusBit.MOVING)
_READY_BITS = StatusBit.WAITING_FOR_COMMAND | StatusBit.SYSRDY
_JOINTS = struct.Struct(">9f")  # a status packet's J1..J9


def _floats(q: np.ndarray | tuple[float, ...] | list[float]) -> list[float]:
    """A command's values as Python floats (ndarray.tolist: one call, where a generator of float()
    took 1.5 us for six)."""
    return q.tolist() if isinstance(q, np.ndarray) else [float(v) for v in q]


class Phase(StrEnum):
    IDLE = "idle"  # status output off
    FETCHING_TABLES = "fetching_tables"
    CONNECTED = "connected"  # status flowing, not streaming
    WAITING_READY = "waiting_ready"  # armed: the first command goes out at the next ready status
    STREAMING = "streaming"
    ENDING = "ending"  # last data sent, waiting for status bit 0 to clear
    CLOSED = "closed"  # status output stopped
    FAULT = "fault"


# An enum member looked up on its class costs ~0.1 us here (more with caches cold): the per-status tests
# compare with these instead.
_STREAMING = Phase.STREAMING


class MotionSource(Protocol):
    """What the session asks of the servo cycle."""

    def begin(self, q_start: np.ndarray, tables: LimitTables | None) -> None:
        """Streaming starts at ``q_start`` (FANUC joint convention, deg) with the controller's tables."""

    def next_command(self, status: Status) -> np.ndarray:
        """The next commanded joint position (FANUC deg), one call per command packet."""

    def request_rest(self) -> None:
        """Decelerate to rest (the session wants to end)."""

    def at_rest(self) -> bool:
        """True once the commanded motion has come to rest."""


@dataclass
class IoRequest:
    """Read (sticky) and write (one-shot) I/O carried by command packets. Checked when made (PacketError
    naming the field), so that a bad one is refused with its request, never in a cycle's encode."""

    io_type: int
    index: int
    mask: int = 0xFFFF
    value: int = 0

    def __post_init__(self) -> None:
        for name, top in (("io_type", 0xFF), ("index", 0xFFFF), ("mask", 0xFFFF), ("value", 0xFFFF)):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= top:
                raise PacketError(f"{name}={v!r} is not an unsigned integer in 0..{top}")


@dataclass
class SessionConfig:
    n_axes: int = 6
    lead: int = 0  # extra commands kept in the controller's buffer
    fetch_tables: bool = True
    table_axes: int = 6
    table_timeout_s: float = 0.25
    table_retries: int = 3
    ready_timeout_s: float = 10.0  # no status bit 0 within this -> fault
    status_timeout_s: float = 0.1  # no status packet within this while streaming -> fault
    link_timeout_s: float = 1.0  # no status packet within this otherwise (status output on) -> fault
    max_payload_kg: float = 0.0  # for building LimitTables from responses

    def __post_init__(self) -> None:
        if not 0 <= self.lead <= MAX_PKT_STACK - 2:
            raise ValueError(f"lead={self.lead} must be in 0..{MAX_PKT_STACK - 2} ($PKT_STACK-1 buffer)")


@dataclass
class SessionStats:
    status_received: int = 0
    status_lost: int = 0  # gaps in the status sequence
    status_duplicated: int = 0  # repeated or out-of-order status packets
    commands_sent: int = 0
    malformed: int = 0
    last_error: str = ""


class SentCommand:
    """What went out in one datagram; the runner logs it. The fields the log needs are kept as made
    (the session packs the datagram straight from them, one per status packet); ``command`` builds
    the :class:`Command` they describe on demand. ``array``: the values as the array they were made
    from, when they were, to be read at once (it may be the motion source's own buffer): the runner
    copies them into its command history array to array (from the list, numpy's conversion cost
    ~15-20 us a status here, with caches cold)."""

    __slots__ = ("array", "data", "data_format", "early", "last_data", "read_io", "seq", "values", "write_io")

    def __init__(self, seq: int, values: tuple[float, ...] | list[float], data_format: int, last_data: int,
                 read_io: tuple[int, int, int], write_io: tuple[int, int, int, int], data: bytes,
                 early: bool = False, array: np.ndarray | None = None) -> None:
        self.seq, self.values, self.data_format, self.last_data = seq, values, data_format, last_data
        self.array = array
        self.read_io, self.write_io = read_io, write_io
        self.data = data
        self.early = early  # sent by the runner ahead of the rest (first_command_early)

    @property
    def write_io_value(self) -> int:
        return self.write_io[3]

    @property
    def command(self) -> Command:
        return Command(seq=self.seq, values=tuple(self.values), data_format=self.data_format,
                       last_data=self.last_data, read_io_type=self.read_io[0], read_io_index=self.read_io[1],
                       read_io_mask=self.read_io[2], write_io_type=self.write_io[0],
                       write_io_index=self.write_io[1], write_io_mask=self.write_io[2],
                       write_io_value=self.write_io[3])

    def __repr__(self) -> str:
        return f"SentCommand({self.command!r}, early={self.early})"


_NO_READ = (0, 0, 0)
_JOINT_FORMAT, _CARTESIAN_FORMAT = DataFormat.JOINT, DataFormat.CARTESIAN  # (no enum look-up per status)
_NO_WRITE = (0, 0, 0, 0)


def _ready_status_seq(data: bytes, mask: int) -> int | None:
    """The sequence number of datagram ``data`` if it is a well-formed status packet of the protocol's
    version whose status bits, masked by ``mask``, are bit 0 and SYSRDY, else None (read from the bytes,
    before any decode)."""
    if len(data) != STATUS_SIZE or data[:SEQ_OFFSET] != STATUS_HEADER or data[STATUS_BITS_OFFSET] & mask != _READY_BITS:
        return None
    return int.from_bytes(data[SEQ_OFFSET: SEQ_OFFSET + 4], "big")


@dataclass
class StreamSession:
    motion: MotionSource
    config: SessionConfig = field(default_factory=SessionConfig)
    phase: Phase = Phase.IDLE
    stats: SessionStats = field(default_factory=SessionStats)
    tables: LimitTables | None = None
    fault_reason: str = ""
    last_status: Status | None = None
    io_read: IoRequest | None = None
    close_after_end: bool = True  # stop the status output once the stream has ended
    # Cartesian format (data format 0): the flange X Y Z W P R (world) of each shaped joint position.
    to_cartesian: Callable[[np.ndarray], np.ndarray] | None = None

    def __post_init__(self) -> None:
        self._pending_tables: list[tuple[int, int]] = []
        self._table_rows: dict[tuple[int, int], LimitTableResponse] = {}
        self._table_sent_at = -1e9
        self._table_tries = 0
        self._phase_since = 0.0
        self._last_status_at = 0.0
        self._first_status_seq = 0  # status seq answered by the first command
        self._next_cmd_seq = 0
        self._sent_since_start = 0
        self._end_requested = False
        self._armed = False
        self._last_data_sent = False
        self._io_writes: list[IoRequest] = []
        self._q_last: np.ndarray | None = None
        self._malformed_at_status = 0  # malformed count at the last valid status packet
        # Streaming began and the motion source is still to be set up from this (start joints, tables).
        self._begin_with: tuple[np.ndarray, LimitTables | None] | None = None
        self.sent: list[SentCommand] = []  # filled per call, for the runner's log
        # The first command's packet, ready before its status arrives (prepare_first_command; None: none
        # is), and the one that went out ahead of on_datagram: (sequence number, bytes).
        self.first_command: bytearray | None = None
        self._early_key: tuple[object, ...] | None = None
        self._early_joints: bytes | None = None  # Cartesian format: the status joints it was made for
        self._early_sent: tuple[int, bytes] | None = None

    # ----------------------------------------------------------------- requests
    def open(self, now: float) -> list[bytes]:
        """Start the status output (and queue the limit-table requests)."""
        if self.phase not in (Phase.IDLE, Phase.CLOSED, Phase.FAULT):
            raise RuntimeError(f"open() in phase {self.phase}")
        self.last_status = None  # the controller restarts its sequence at 1
        if self.config.fetch_tables and self.tables is None:
            self._pending_tables = [(axis, lt) for axis in range(1, self.config.table_axes + 1)
                                    for lt in LimitType]
            self._enter(Phase.FETCHING_TABLES, now)
        else:
            self._enter(Phase.WAITING_READY if self._armed else Phase.CONNECTED, now)
        self._last_status_at = now
        return [StatusStart().encode()]

    def arm(self) -> None:
        """Stream from the next status packet that shows the controller waiting (bit 0, SYSRDY)."""
        if self.phase not in (Phase.CONNECTED, Phase.FETCHING_TABLES, Phase.FAULT):
            raise RuntimeError(f"cannot start streaming in phase {self.phase}")
        self._armed = True
        self._end_requested = False
        # Writes a stream that faulted never sent are dropped: carried into this stream, they would set
        # outputs (a gripper) at its start, long after they were asked for.
        self._io_writes.clear()
        if self.phase != Phase.FETCHING_TABLES:
            self.phase = Phase.WAITING_READY

    @property
    def output_on(self) -> bool:
        return self.phase not in (Phase.IDLE, Phase.CLOSED)

    @property
    def streaming_motion(self) -> bool:
        """Streaming, the motion source set up, and commands from it still to come (no last data yet)."""
        return self.phase == _STREAMING and self._begin_with is None and not self._last_data_sent

    def begin_motion(self) -> None:
        """Set the motion source up for the stream that began (``MotionSource.begin``), if not yet done.

        The first commands of a stream are the hold position and need no motion source: they leave at
        once, and the set-up (3.5 ms here, most of a 4 ms interval: the controller then already wanted
        the next sequence number and posted MOTN-600) follows them. The runner calls this right after
        sending; every other entry point calls it first, so a pure user never sees the difference."""
        if self._begin_with is not None:
            q0, tables = self._begin_with
            self._begin_with = None
            self.motion.begin(q0, tables)

    # ----------------------------------------------------------- the first command, ahead
    def prepare_first_command(self, starts: bool) -> None:
        """Off the cycle (while waiting for bit 0): the packet of the stream's first command, all but
        what comes from the ready status itself. ``starts``: the caller's word that the next ready
        status starts the stream (the supervisor's state machine would accept the start).

        At the ready status the hold position must leave at once: a command later than one interval
        answers a status that is no longer the latest, and a strict controller posts MOTN-600 (issue 15:
        0.35-1.2 ms from status to first command while the status was decoded, the safety transitions
        run and three commands encoded first)."""
        if (not starts or self.phase not in (Phase.CONNECTED, Phase.WAITING_READY) or self._io_writes
                or (self.phase == Phase.WAITING_READY and self._end_requested)):  # (arm() clears it)
            self.first_command = None
            return
        read = self.io_read
        # Cartesian format: the pose of the joints last reported, good while the arm reports them still.
        joints = self.last_status.joints if self.to_cartesian is not None and self.last_status else None
        key = (read, joints)
        if self.first_command is not None and key == self._early_key:
            return
        values: tuple[float, ...] = (0.0,) * self.config.n_axes  # joint format: copied from the status
        self._early_joints = None
        if joints is not None:
            values = self._pose(joints)
            self._early_joints = _JOINTS.pack(*joints)
        cmd = Command(seq=0, values=values,
                      data_format=DataFormat.JOINT if self.to_cartesian is None else DataFormat.CARTESIAN,
                      read_io_type=read.io_type if read else 0, read_io_index=read.index if read else 0,
                      read_io_mask=read.mask if read else 0)
        self.first_command, self._early_key = bytearray(cmd.encode()), key

    def _pose(self, joints: tuple[float, ...]) -> tuple[float, ...]:
        assert self.to_cartesian is not None
        return tuple(float(v) for v in self.to_cartesian(np.array(joints[: self.config.n_axes], dtype=float)))

    def first_command_early(self, data: bytes) -> bytes | None:
        """The stream's first command for datagram ``data`` if it is the ready status the prepared
        packet waits for, else None. The caller sends it at once, then hands ``data`` to
        ``on_datagram`` as usual: the session goes on as if it had sent it there (and does not send
        it again)."""
        p = self.first_command
        if p is None:
            return None
        seq = _ready_status_seq(data, _READY_MASK)
        if seq is None:
            return None
        last = self.last_status
        if last is not None and (seq == last.seq or (seq_diff(seq, last.seq) <= 0 and seq != 1)):
            return None  # a duplicate or reordered status is not answered (_on_status)
        joints = data[STATUS_JOINTS_OFFSET: STATUS_JOINTS_OFFSET + _JOINTS.size]
        if self.to_cartesian is None:  # J519 floats both ways: the hold position is the status's joints
            n = 4 * self.config.n_axes
            p[COMMAND_VALUES_OFFSET: COMMAND_VALUES_OFFSET + n] = joints[:n]
        elif joints != self._early_joints:  # not the joints the pose was made for (or none yet): now
            pose = self._pose(_JOINTS.unpack(joints))
            p[COMMAND_VALUES_OFFSET: COMMAND_VALUES_OFFSET + 4 * len(pose)] = struct.pack(f">{len(pose)}f", *pose)
        p[SEQ_OFFSET: SEQ_OFFSET + 4] = data[SEQ_OFFSET: SEQ_OFFSET + 4]  # the first command carries its seq
        out = bytes(p)
        self.first_command = None
        self._early_sent = (seq, out)
        return out

    def request_end(self) -> None:
        """Decelerate, send last data, then stop the status output."""
        self.begin_motion()
        self._end_requested = True
        self.motion.request_rest()

    def close_now(self) -> list[bytes]:
        """Stop the status output at once (only safe when not streaming)."""
        self._armed = False
        self._enter(Phase.CLOSED, self._phase_since)
        return [StatusStop().encode()]

    def abandon(self, reason: str, now: float) -> None:
        """Stop sending commands (the controller stopped, or will alarm); status output stays as it is."""
        self._armed = False
        self._fault(reason, now)

    def recover(self, now: float) -> bool:
        """After the operator's reset: a failed link starts afresh. It is idle, and the next start sends
        a status output start, which a restarted or taken-over controller needs and any other takes
        (its sequence restarts at 1). Whether status still trickles in cannot be known soon after a
        fault without waiting out a timeout, so it is not guessed. True if the link had failed."""
        if self.phase != Phase.FAULT:
            return False
        self.fault_reason = ""
        self._armed = False
        self._enter(Phase.IDLE, now)
        return True

    def relink(self, now: float) -> bool:
        """Status flows again on a failed link that had no stream to lose (its owner's word): the
        controller took the status output start late (it was frozen, or its network was), and its
        sequence began at 1. The link is up as after ``open``, its failure forgotten: a start streams
        from the next ready status without a new status output start. True if the link had failed."""
        if self.phase != Phase.FAULT:
            return False
        self.fault_reason = ""
        self._armed = False
        if self.config.fetch_tables and self.tables is None:
            self._pending_tables = [(axis, lt) for axis in range(1, self.config.table_axes + 1)
                                    for lt in LimitType]
            self._table_tries, self._table_sent_at = 0, -1e9
            self._enter(Phase.FETCHING_TABLES, now)
        else:
            self._enter(Phase.CONNECTED, now)
        return True

    def write_io(self, req: IoRequest) -> None:
        self._io_writes.append(req)

    @property
    def end_requested(self) -> bool:
        """An end is under way: last data follows once the arm is at rest and the queued writes are out."""
        return self._end_requested

    @property
    def io_writes_pending(self) -> int:
        """I/O writes queued for the next commands (one per command packet)."""
        return len(self._io_writes)

    # ------------------------------------------------------------------ inputs
    def decode(self, data: bytes) -> Status | LimitTableResponse | None:
        """Decode a datagram from the controller; a malformed one is counted and gives None."""
        try:
            return decode_from_robot(data)
        except PacketError as exc:
            self.stats.malformed += 1
            self.stats.last_error = str(exc)
            return None

    def on_datagram(self, data: bytes, now: float) -> list[bytes]:
        self.sent = []
        packet = self.decode(data)
        return [] if packet is None else self.on_packet(packet, now)

    def on_usual_status(self, data: bytes, now: float) -> list[bytes] | None:
        """``on_datagram`` for the usual datagram of a running stream, without its general path: a
        well-formed status packet whose sequence number follows the last one's, with bit 0 and SYSRDY
        set, due exactly one command, while nothing else is under way (the first commands, one sent
        ahead, an end). None for any other datagram, with nothing changed: ``on_datagram`` then (tested
        to send and record the same as it on random streams).

        Why: the general path is several calls and tests deep (decode, sequence arithmetic, phase,
        commands due); with caches cold after the wait for the packet, the usual status through one
        flat method and the supervisor's cost the servo process 6 % less per status (bench/servo_loop.py,
        mean 157 -> 148 us, five rounds each way)."""
        prev = self.last_status
        if (self.phase != _STREAMING or prev is None or self._begin_with is not None or self._early_sent is not None
                or self._end_requested or self._last_data_sent):
            return None
        seq = _ready_status_seq(data, _READY_BITS)
        if seq is None or seq != next_seq(prev.seq) or self._due(seq) != 1:
            return None
        st = decode_from_robot(data)
        assert isinstance(st, Status)  # (its length, type and version were checked above)
        self.sent = []
        self._accept(st, now)
        out = self._command(st)
        return [] if out is None else [out]

    def on_packet(self, packet: Status | LimitTableResponse, now: float) -> list[bytes]:
        if self._begin_with is not None:  # (the runner has done it already: no call per status)
            self.begin_motion()
        self.sent = []
        if isinstance(packet, LimitTableResponse):
            self._on_table(packet)
            return []
        out = self._on_status(packet, now)
        if self._early_sent is not None:
            # A first command went out ahead for this status, but no stream started on it: the
            # controller now waits for the next commands, which will not come. A bug: stop here.
            self._early_sent = None
            self._fault("a first command was sent ahead, but the stream did not start", now)
        return out

    def on_idle(self, now: float) -> list[bytes]:
        """Call when no datagram arrived for a while: time-outs live here."""
        self.begin_motion()
        self.sent = []
        silent = now - self._last_status_at
        if self.phase in (Phase.STREAMING, Phase.ENDING) and silent > self.config.status_timeout_s:
            self._fault(f"no status packet for {silent:.3f} s{self._refused_note()}", now)
        elif self.phase == Phase.WAITING_READY and now - self._phase_since > self.config.ready_timeout_s:
            self._fault(f"controller not ready (status bit 0) within {self.config.ready_timeout_s} s", now)
        elif self.phase in (Phase.FETCHING_TABLES, Phase.CONNECTED, Phase.WAITING_READY) \
                and silent > self.config.link_timeout_s:
            what = "after status output start" if self.last_status is None else "while connected"
            self._fault(f"no status packet for {silent:.3f} s {what}: is the controller running and "
                        f"reachable?{self._refused_note()}", now)
        return []

    def _refused_note(self) -> str:
        """Datagrams that came but were refused (a version mismatch, a wrong length) explain a silence."""
        if self.stats.malformed > self._malformed_at_status and self.stats.last_error:  # (a reset clears it)
            return f" (datagrams refused meanwhile: {self.stats.last_error})"
        return ""

    # --------------------------------------------------------------- internals
    def _enter(self, phase: Phase, now: float) -> None:
        self.phase = phase
        self._phase_since = now

    def _fault(self, reason: str, now: float) -> None:
        self.fault_reason = reason
        self._enter(Phase.FAULT, now)

    def _on_table(self, resp: LimitTableResponse) -> None:
        key = (resp.axis, resp.limit_type)
        if self._pending_tables and self._pending_tables[0] == key:
            self._table_rows[key] = resp
            self._pending_tables.pop(0)
            self._table_tries = 0
            self._table_sent_at = -1e9  # ask for the next one at the next status packet

    def _table_requests(self, now: float) -> list[bytes]:
        """One request per status interval; move on to streaming when all are in or given up."""
        if self._pending_tables and now - self._table_sent_at >= self.config.table_timeout_s:
            if self._table_tries >= self.config.table_retries:
                self.stats.last_error = (f"no limit table for axis {self._pending_tables[0][0]} type "
                                         f"{self._pending_tables[0][1]}: using the profile's limits")
                self._pending_tables = []
            else:
                self._table_tries += 1
                self._table_sent_at = now
                axis, lt = self._pending_tables[0]
                return [LimitTableRequest(axis, lt).encode()]
        if not self._pending_tables:
            self.tables = self._assemble_tables()
            self._enter(Phase.WAITING_READY if self._armed else Phase.CONNECTED, now)
        return []

    def _assemble_tables(self) -> LimitTables | None:
        n = self.config.table_axes
        if len(self._table_rows) != n * len(LimitType):
            return None
        rows = [[(self._table_rows[(a, lt)].no_payload, self._table_rows[(a, lt)].max_payload)
                 for a in range(1, n + 1)] for lt in LimitType]
        first = self._table_rows[(1, LimitType.VELOCITY)]
        return tables_from_rows(first.vmax_mm_s, first.check_time_s, self.config.max_payload_kg, rows)

    def _on_status(self, st: Status, now: float) -> list[bytes]:
        prev = self.last_status
        if prev is not None:
            gap = seq_diff(st.seq, prev.seq)
            if st.seq == 1 and gap != 1 and self.phase in (Phase.STREAMING, Phase.ENDING):
                # Sending status output start resets the sequence to 1 (Table 2): somebody else did,
                # or the controller restarted. The stream it belonged to is gone either way.
                self._fault(f"the controller restarted its status output (sequence {prev.seq} -> 1): another "
                            "host sent a status output start, or the controller restarted", now)
                return []
            if gap <= 0 and st.seq != 1:  # duplicate or reordered (seq 1 = output restarted)
                self.stats.status_duplicated += 1
                return []
            if gap > 1:
                self.stats.status_lost += gap - 1
        self._accept(st, now)
        phase = self.phase
        if phase == _STREAMING:  # the usual case first: no branch below leads to it or from it
            if st.status & _READY_BITS != _READY_BITS:  # bit 0 or SYSRDY cleared
                self._fault("controller stopped the stream (status bit 0 or SYSRDY cleared): see its alarm "
                            "history", now)
                return []
            return self._send_due(st)
        if phase == Phase.IDLE:  # after a reset: status still flows, so the link is up
            self._enter(Phase.CONNECTED, now)
        if self.phase == Phase.FETCHING_TABLES:
            out = self._table_requests(now)
            if self.phase == Phase.FETCHING_TABLES:
                return out
        if self.phase == Phase.WAITING_READY:
            if self._end_requested:  # ended before streaming began: nothing to drain
                self._armed = False
                self._enter(Phase.CLOSED, now)
                return [StatusStop().encode()]
            return self._maybe_start(st)
        if self.phase == Phase.ENDING and not st.waiting_for_command:
            if not self.close_after_end:
                self._enter(Phase.CONNECTED, now)
                return []
            self._enter(Phase.CLOSED, now)
            return [StatusStop().encode()]
        return []

    def _accept(self, st: Status, now: float) -> None:
        """A new status packet, in sequence or after a gap: the session's last from now on."""
        self._malformed_at_status = self.stats.malformed
        self.stats.status_received += 1
        self.last_status = st
        self._last_status_at = now

    def _maybe_start(self, st: Status) -> list[bytes]:
        # Ready: waiting for commands, none received yet in this run of IBGN start, servo ready.
        if not (st.waiting_for_command and st.sysrdy) or st.command_received or st.moving:
            return []
        self._armed = False
        q0 = np.array(st.joints[: self.config.n_axes], dtype=float)
        self._begin_with = (q0, self.tables)  # set up after the hold commands have gone (begin_motion)
        self._first_status_seq = st.seq
        self._next_cmd_seq = st.seq
        self._sent_since_start = 0
        self._last_data_sent = False
        self.phase = Phase.STREAMING
        return self._send_due(st)

    def _send_due(self, st: Status) -> list[bytes]:
        """Send as many commands as the status sequence says the controller will have consumed, + lead."""
        due = self._due(st.seq)
        if due == 1 and not self._last_data_sent:  # the usual status: its one command (the loop below, once)
            data = self._command(st)
            return [] if data is None else [data]
        out: list[bytes] = []
        for _ in range(max(due, 0)):
            if self._last_data_sent:
                break
            data = self._command(st)
            if data is not None:
                out.append(data)
        return out

    def _due(self, seq: int) -> int:
        """The commands due on status ``seq``: those the controller will have consumed by then, + lead,
        less those sent."""
        return seq_diff(seq, self._first_status_seq) + 1 + self.config.lead - self._sent_since_start

    def _command(self, st: Status) -> bytes | None:
        """Make the next command; its bytes to send, or None when it went out ahead already."""
        last = 0
        if self._begin_with is not None:  # the stream's first commands: the hold position itself
            q = self._begin_with[0]
        elif self._end_requested and self.motion.at_rest() and not self._io_writes:
            # (Writes still queued go out first, one per command: each was answered as sent in this stream.)
            last = 1
            q = self._q_last if self._q_last is not None else self.motion.next_command(st)
        else:
            q = self.motion.next_command(st)
        self._q_last = q
        write = self._io_writes.pop(0) if self._io_writes else None
        read = self.io_read
        seq = self._next_cmd_seq
        if self.to_cartesian is None:
            fmt, array = _JOINT_FORMAT, q
        else:
            fmt, array = _CARTESIAN_FORMAT, self.to_cartesian(q)
        values = _floats(array)
        read_io = _NO_READ if read is None else (read.io_type, read.index, read.mask)
        write_io = _NO_WRITE if write is None else (write.io_type, write.index, write.mask, write.value)
        early = self._early_sent
        ahead = early is not None and early[0] == seq
        if early is not None and ahead:  # it went out before this status was decoded: not again
            self._early_sent = None
            data = early[1]
        else:
            data = pack_command(seq, values, fmt, last, read_io, write_io)
        self.sent.append(SentCommand(seq, values, fmt, last, read_io, write_io, data, ahead,
                                     array if type(array) is np.ndarray else None))
        self._next_cmd_seq = next_seq(seq)
        self._sent_since_start += 1
        self.stats.commands_sent += 1
        if last:
            self._last_data_sent = True
            self.phase = Phase.ENDING
        return None if ahead else data
