"""A pure model of a FANUC controller running Stream Motion (J519): no sockets, no clock.

The UDP server (:mod:`servo_app.sim.fanuc_server`) feeds it datagrams (``on_datagram``) and calls
``tick`` once per communication interval; everything else here is plain state, so protocol tests
can drive it cycle by cycle.

Behaviour (manual chapter 61) and the choices where the manual is silent:

- Status output: a start packet (type 0) starts status packets to the address it came from and
  resets the sequence number to 1; a stop packet (type 2) ends them at once. Sequence numbers wrap
  0xFFFFFFFF -> 0; the timestamp is ms since the model started, 2 ms resolution, wrapping likewise.
- The "IBGN start" program is a simulator control: ``start_program``, ``set_mode``, ``set_override``.
  Starting outside AUTO / 100 % posts MOTN-606; so does changing the override (or, our choice, the
  mode) while it runs. With ``auto_start`` (the standalone default) the program is running and
  loops: after the last data (or ``reset()`` after an alarm) it passes IBGN end and comes back to
  IBGN start after ``restart_delay_s``.
- Status bits: bit 0 while IBGN start waits for / runs on commands; bit 1 from the first command
  received until bit 0 clears; bit 2 SYSRDY (off while an alarm is active); bit 3 while the arm
  moves (servo speed above 0.05 deg/s, or a jog in progress).
- The first command must carry the sequence number of the status packet sent just before it. We
  accept the last sent status sequence number and the one before it: a command answering status k
  may arrive after status k+1 left (the race every client has). ``ControllerConfig.strict_first_seq``
  models the stricter controller of issue 15: only the latest status's sequence number is taken, so
  a first command that arrives after the next status left posts MOTN-600 (first command 20, status 21).
  Later commands must be the previous command + 1, checked when processed (FAQ), else MOTN-600
  "PC <got>, Rob <expected>".
- Commands are buffered ($PKT_STACK - 1 unprocessed, MOTN-604 beyond); motion starts once
  $START_MOVE are buffered; from then on each control cycle needs one in the buffer (MOTN-603).
  Processing checks, in order: sequence (600), data format (602 unless 0/1), Cartesian format
  on a model without it (619), NaN/Inf (605), I/O assignment (PRIO-023), for Cartesian format the
  conversion to joints (156, 018), then the controller limit checker (609/610/611/617, joint range
  MOTN-017, warnings 612/613/614).
- Cartesian format (data format 0): X Y Z W P R of the flange centre in the world frame (61.7),
  converted by :mod:`servo_app.motion.cartesian` (the code ``servo-app check`` uses): the IK
  solution nearest the previous command position, whose configuration (turn numbers included) must
  be the one of the command position when the stream began (MOTN-156 otherwise); no solution at all
  is MOTN-018 "Position not reachable" (our choice of code). The converted joints then get exactly
  the joint-format checks (FAQ), MOTN-617 on the first command included; the command position, the
  status joints and the status Cartesian pose (always the FK of the servo joints) are joints as usual.
  Formats may be mixed within one stream (our choice; the manual is silent): each command is
  converted on its own, continuing from the previous command position whatever its format, and the
  held configuration stays the one of the stream's start. ``ControllerConfig.cartesian_supported``
  = False models a robot without Cartesian support (MOTN-619 for every format-0 command); so does a
  profile the kinematics cannot handle.
- Last data = 1 ends control once that command is processed (an Appendix B window still open is
  judged then). Commands arriving while the program is not waiting are ignored and counted.
- A stop packet while commands are being processed (bit 1 set) posts MOTN-608 (note 2 of 61.3:
  "an alarm may occur if the status packet communication is terminated before the command packet
  communication"); while only waiting (bit 0, no command yet) it just stops the status output.
- Any packet with a protocol version other than 1 posts MOTN-607 "PC <got>, Rob 1" and is dropped.
  Datagrams that do not decode (wrong length or type) are dropped and counted (``bad_packets``).
- Limit-table requests (type 3) are answered from the very tables the checker enforces. Axes 7-9
  (no extended axes on the supported arms) answer zero tables with the same Vmax and check time;
  an axis outside 1..9 or a type outside 0..2 gets no answer (counted in ``bad_requests``).
- An alarm is a power-off stop (FAQ): the arm brakes where it is (servo position frozen, and the
  command position set to it, as the controller re-reads it after the stop), bits 0, 1, 3 clear,
  SYSRDY off, the program is aborted; ``reset()`` clears it. Warnings are only posted.
- Every alarm and warning is written as one line (``format_alarm``) to ``log`` (stderr by default)
  and kept in ``events``.
"""

from __future__ import annotations

import enum
import math
import sys
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from servo_app.fanuc.alarms import ALARMS, AlarmEvent, format_alarm
from servo_app.fanuc.packets import (
    PROTOCOL_VERSION,
    SEQ_MODULO,
    Command,
    DataFormat,
    LimitTableRequest,
    LimitTableResponse,
    PacketError,
    Status,
    StatusBit,
    StatusStart,
    StatusStop,
    decode_from_pc,
    next_seq,
)
from servo_app.motion.cartesian import CartesianConverter
from servo_app.motion.checker import ControllerLimitChecker, Violation
from servo_app.motion.limit_tables import N_STAGES, LimitTables, default_tables
from servo_app.robots.profile import RobotProfile, load_profile
from servo_app.sim.fanuc_io import IoError, IoTable
from servo_app.sim.fanuc_servo import N_JOINTS, ServoModel
from servo_app.sim.kin import SimKinematics, load_kinematics

MODES = ("AUTO", "T1", "T2")


class ProgramState(enum.Enum):
    IDLE = "idle"  # no program running
    WAITING = "ibgn_start"  # executing IBGN start: waiting for / running on command packets
    ENDED = "ibgn_end"  # passed IBGN end; loops back to IBGN start when auto_start
    ABORTED = "aborted"  # stopped by an alarm


class SimControlError(RuntimeError):
    """A simulator control request that the controller would refuse (e.g. jog while streaming)."""


@dataclass(frozen=True)
class ControllerConfig:
    """The controller's settings ($STMO system variables) and the simulator's own knobs."""

    interval_ms: int | None = None  # None: the profile's ($COM_INT)
    pkt_stack: int = 10  # $PKT_STACK (2..10): buffer holds pkt_stack - 1 unprocessed commands
    start_move: int = 1  # $START_MOVE (1..pkt_stack - 1)
    warn_lim_pct: float = 80.0  # $WARN_LIM
    payload_kg: float | None = None  # None: never set -> maximum payload (Appendix B)
    auto_start: bool = True  # standalone: IBGN start program running and looping
    restart_delay_s: float = 0.2  # IBGN end -> IBGN start again
    servo_delay_cycles: int = 2
    servo_tau_cycles: float = 3.0
    io_points: Mapping[int, int] | None = None  # None: fanuc_io.DEFAULT_IO_POINTS
    first_jump_cycles: float = 1.0  # MOTN-617 thresholds, see motion.checker
    jump_cycles: float = 2.0
    timestamp_offset_ms: int = 0  # added to the status timestamp (to test its wrap)
    jog_speed_fraction: float = 0.2  # of the velocity / stage-1 acceleration limits
    cartesian_supported: bool = True  # False: the robot model posts MOTN-619 for Cartesian format
    # True: the first command must answer the latest status (a controller seen posting MOTN-600 when the
    # first command came one interval late); False: the latest or the one before it.
    strict_first_seq: bool = False

    def __post_init__(self) -> None:
        if not 2 <= self.pkt_stack <= 10:
            raise ValueError(f"pkt_stack={self.pkt_stack} must be in 2..10")
        if not 1 <= self.start_move <= self.pkt_stack - 1:
            raise ValueError(f"start_move={self.start_move} must be in 1..{self.pkt_stack - 1}")
        if self.interval_ms is not None and self.interval_ms <= 0:
            raise ValueError(f"interval_ms={self.interval_ms} must be > 0")


def stderr_line(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class _Jog:
    """A minimum-jerk (quintic) move of the command position, one sample per control cycle."""

    def __init__(self, start: np.ndarray, goal: np.ndarray, cycles: int) -> None:
        self.start, self.goal, self.cycles, self.k = start, goal, max(1, cycles), 0

    def next(self) -> tuple[np.ndarray, bool]:
        self.k += 1
        t = min(1.0, self.k / self.cycles)
        s = t * t * t * (10.0 + t * (-15.0 + 6.0 * t))
        return self.start + (self.goal - self.start) * s, t >= 1.0


class FanucControllerModel:
    """The controller: ``on_datagram(data, now, addr) -> replies`` and ``tick(now) -> status bytes``.

    ``now`` is any monotonic clock in seconds (the server passes ``time.perf_counter()``).
    """

    def __init__(
        self,
        profile: RobotProfile | str = "lrmate200id",
        config: ControllerConfig | None = None,
        *,
        tables: LimitTables | None = None,
        kinematics: SimKinematics | None = None,
        initial_joints: Sequence[float] | None = None,
        log: Callable[[str], None] | None = stderr_line,
    ) -> None:
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.config = config or ControllerConfig()
        self.interval_ms = self.config.interval_ms or self.profile.interval_ms
        self.interval_s = self.interval_ms / 1000.0
        self.tables = tables if tables is not None else default_tables(self.profile)
        self.kin = kinematics if kinematics is not None else load_kinematics(self.profile)
        self.log = log
        self.checker = ControllerLimitChecker.for_profile(
            self.profile, self.kin.flange_xyz_mm, tables=self.tables, interval_s=self.interval_s,
            payload_kg=self.config.payload_kg, warn_lim_pct=self.config.warn_lim_pct,
            first_jump_cycles=self.config.first_jump_cycles, jump_cycles=self.config.jump_cycles,
            check_max_spd=False,
        )
        self.cartesian = (CartesianConverter(self.kin.arm)
                          if self.config.cartesian_supported and self.kin.arm is not None else None)
        self.io = IoTable(self.config.io_points)
        q0 = np.zeros(N_JOINTS)
        if initial_joints is not None:
            vals = np.asarray(initial_joints, dtype=float)[:6]
            q0[: len(vals)] = vals
        self.cmd_q = q0
        self.servo = ServoModel(q0, self.interval_s, delay_cycles=self.config.servo_delay_cycles,
                                tau_cycles=self.config.servo_tau_cycles, j23_factor=self.profile.j23_factor)
        self.events: list[AlarmEvent] = []
        # Status output.
        self.status_active = False
        self.status_addr: object = None
        self._next_status_seq = 1
        self.last_status_seq: int | None = None
        self.prev_status_seq: int | None = None
        self._t0: float | None = None
        self.now = 0.0
        # Program and controller state.
        self.mode = "AUTO"
        self.override = 100
        self.alarm_active = False
        self.program = ProgramState.IDLE
        self._restart_at: float | None = None
        self.waiting = False  # status bit 0
        self.command_received = False  # status bit 1
        self.motion_started = False
        self.buffer: deque[Command] = deque()
        self._last_cmd_seq: int | None = None
        self._read_io = (0, 0, 0)
        self._jog: _Jog | None = None
        self._moved = False
        # Counters.
        self.ignored_commands = 0
        self.bad_packets = 0
        self.bad_requests = 0
        self.processed_commands = 0
        self.status_sent = 0
        if self.config.auto_start:
            self.program = ProgramState.ENDED  # comes to IBGN start at the first tick
            self._restart_at = -math.inf

    # ---- clock ----------------------------------------------------------------------------------

    def _clock(self, now: float) -> None:
        if self._t0 is None:
            self._t0 = now
        self.now = now

    # ---- datagrams ------------------------------------------------------------------------------

    def on_datagram(self, data: bytes, now: float, addr: object = None) -> list[bytes]:
        """Handle one datagram from a client at ``addr``; returns datagrams to send back to it."""
        self._clock(now)
        try:
            pkt = decode_from_pc(data, version=None)
        except PacketError:
            self.bad_packets += 1
            return []
        if pkt.version != PROTOCOL_VERSION:
            self._alarm("MOTN-607", pc=pkt.version, rob=PROTOCOL_VERSION)
            return []
        if isinstance(pkt, StatusStart):
            self.status_active = True
            self.status_addr = addr
            self._next_status_seq = 1
        elif isinstance(pkt, StatusStop):
            self.status_active = False
            if self.command_received:
                self._alarm("MOTN-608")
        elif isinstance(pkt, LimitTableRequest):
            return self._limit_table(pkt)
        elif isinstance(pkt, Command):
            self._receive(pkt)
        return []

    def _limit_table(self, req: LimitTableRequest) -> list[bytes]:
        if not 1 <= req.axis <= 9 or req.limit_type not in (0, 1, 2):
            self.bad_requests += 1
            return []
        t = self.tables
        if req.axis <= t.n_axes:
            table = t.tables[req.limit_type][req.axis - 1]
            no, mx = tuple(table.no_payload), tuple(table.max_payload)
        else:
            no = mx = (0.0,) * N_STAGES
        resp = LimitTableResponse(axis=req.axis, limit_type=req.limit_type, vmax_mm_s=round(t.vmax),
                                  check_time_s=round(t.check_time_s), no_payload=no, max_payload=mx)
        return [resp.encode()]

    def _receive(self, cmd: Command) -> None:
        if not self.waiting:
            self.ignored_commands += 1
            return
        if not self.command_received:
            accepted = (self.last_status_seq,) if self.config.strict_first_seq else (
                self.last_status_seq, self.prev_status_seq)
            if self.last_status_seq is None or cmd.seq not in accepted:
                self._alarm("MOTN-600", pc=cmd.seq, rob=self.last_status_seq)
                return
            self.command_received = True
            self._jog = None  # streaming takes over from a jog in progress
        if len(self.buffer) >= self.config.pkt_stack - 1:
            self._alarm("MOTN-604")
            return
        self.buffer.append(cmd)

    # ---- control cycle --------------------------------------------------------------------------

    def tick(self, now: float) -> bytes | None:
        """One communication interval: run the control cycle; the status packet if output is on."""
        self._clock(now)
        self._moved = False
        if (self.program is ProgramState.ENDED and self._restart_at is not None
                and now >= self._restart_at and not self.alarm_active):
            self._restart_at = None
            self._begin_ibgn()
        if self.command_received:
            self._control_cycle()
        elif self._jog is not None:
            q, done = self._jog.next()
            self.cmd_q[:6] = q
            self._moved = True
            if done:
                self._jog = None
        self.servo.update(self.cmd_q)
        if not self.status_active:
            return None
        return self._status_packet(now)

    def _control_cycle(self) -> None:
        if not self.motion_started:
            if len(self.buffer) < self.config.start_move:
                return
            self.motion_started = True
        if not self.buffer:
            self._alarm("MOTN-603")
            return
        self._process(self.buffer.popleft())

    def _process(self, cmd: Command) -> None:
        if self._last_cmd_seq is not None and cmd.seq != next_seq(self._last_cmd_seq):
            self._alarm("MOTN-600", pc=cmd.seq, rob=next_seq(self._last_cmd_seq))
            return
        first = self._last_cmd_seq is None
        self._last_cmd_seq = cmd.seq
        if cmd.data_format not in (DataFormat.CARTESIAN, DataFormat.JOINT):
            self._alarm("MOTN-602")
            return
        cartesian = cmd.data_format == DataFormat.CARTESIAN
        if cartesian and self.cartesian is None:
            self._alarm("MOTN-619")
            return
        axis = cmd.non_finite_axis()
        if axis is not None:
            self._alarm("MOTN-605", axis=axis, seq=cmd.seq)
            return
        try:
            self.io.check(cmd.read_io_type, cmd.read_io_index)
            self.io.write(cmd.write_io_type, cmd.write_io_index, cmd.write_io_mask, cmd.write_io_value)
        except IoError:
            self._alarm("PRIO-023", seq=cmd.seq)
            return
        self._read_io = (cmd.read_io_type, cmd.read_io_index, cmd.read_io_mask)
        if first:
            self.checker.reset(start_q_deg=self.cmd_q[:6])
            if self.cartesian is not None:  # held for the whole stream, whatever the formats
                self.cartesian.reset(self.cmd_q[:6])
        if cartesian:
            assert self.cartesian is not None
            conv = self.cartesian.convert(cmd.values[:6], self.cmd_q[:6])
            if conv.joints_deg is None:
                assert conv.code is not None
                self._alarm(conv.code, seq=cmd.seq)
                return
            q = conv.joints_deg
        else:
            q = np.asarray(cmd.values[:6], dtype=float)
        if self._post(self.checker.step(q, cmd.seq)):
            return
        self.processed_commands += 1
        self._moved = bool(np.any(self.cmd_q[:6] != q))
        self.cmd_q[:6] = q
        if cmd.last_data:
            if self._post(self.checker.finish(cmd.seq)):
                return
            self._end_control()

    def _post(self, found: list[Violation]) -> bool:
        """Post the checker's records; True when one was an alarm (the robot stopped)."""
        stopped = False
        for v in found:
            if not stopped:
                self._alarm(v.code, axis=v.axis, seq=v.seq)
                stopped = not v.warning
        return stopped

    def _end_control(self) -> None:
        """Last data processed: IBGN end (and, when looping, IBGN start again after a delay)."""
        self._leave_control()
        self.program = ProgramState.ENDED
        self._restart_at = self.now + self.config.restart_delay_s if self.config.auto_start else None

    def _leave_control(self) -> None:
        self.waiting = False
        self.command_received = False
        self.motion_started = False
        self.buffer.clear()
        self._last_cmd_seq = None
        self._read_io = (0, 0, 0)

    def _begin_ibgn(self) -> bool:
        if self.mode != "AUTO" or self.override != 100:
            self._alarm("MOTN-606")
            return False
        self.program = ProgramState.WAITING
        self._leave_control()
        self.waiting = True
        return True

    # ---- status ---------------------------------------------------------------------------------

    @property
    def status_bits(self) -> int:
        bits = 0
        if self.waiting:
            bits |= StatusBit.WAITING_FOR_COMMAND
        if self.command_received:
            bits |= StatusBit.COMMAND_RECEIVED
        if not self.alarm_active:
            bits |= StatusBit.SYSRDY
        if self._moved or self._jog is not None or self.servo.moving:
            bits |= StatusBit.MOVING
        return bits

    def _status_packet(self, now: float) -> bytes:
        seq = self._next_status_seq
        self._next_status_seq = next_seq(seq)
        self.prev_status_seq, self.last_status_seq = self.last_status_seq, seq
        self.status_sent += 1
        rtype, ridx, rmask = self._read_io
        try:
            rval = self.io.read(rtype, ridx, rmask)
        except IoError:
            rval = 0
        cart = np.zeros(N_JOINTS)
        if self.kin.pose_xyzwpr is not None:
            cart[:6] = self.kin.pose_xyzwpr(self.servo.q[:6])
        return Status(
            seq=seq,
            status=self.status_bits,
            read_io_type=rtype,
            read_io_index=ridx,
            read_io_mask=rmask,
            read_io_value=rval,
            timestamp_ms=self.timestamp_ms(now),
            cartesian=tuple(cart.tolist()),
            joints=tuple(self.servo.q.tolist()),
            currents=tuple(self.servo.currents().tolist()),
        ).encode()

    def timestamp_ms(self, now: float) -> int:
        """The controller's clock as status packets carry it: ms since the first datagram, in 2 ms steps."""
        ms = int((now - (self._t0 or 0.0)) * 1000.0) + self.config.timestamp_offset_ms
        return (ms - ms % 2) % SEQ_MODULO

    # ---- alarms ---------------------------------------------------------------------------------

    def _alarm(self, code: str, *, axis: int | None = None, seq: int | None = None, pc: object = None,
               rob: object = None) -> None:
        """Post an alarm or warning; an alarm is a power-off stop."""
        line = format_alarm(code, axis=axis, seq=seq, pc=pc, rob=rob)
        self.events.append(AlarmEvent(code, line, self.now, axis, seq, controller_time_ms=self.timestamp_ms(self.now)))
        if self.log is not None:
            self.log(line)
        if ALARMS[code].warning:
            return
        self.alarm_active = True
        self._leave_control()
        self.program = ProgramState.ABORTED
        self._restart_at = None
        self._jog = None
        self._moved = False
        # Brakes hold the arm where it is; the command position is re-read from it.
        self.cmd_q = self.servo.q.copy()
        self.servo.set_position(self.cmd_q)

    def alarms(self) -> list[AlarmEvent]:
        return [e for e in self.events if not e.warning]

    def warnings(self) -> list[AlarmEvent]:
        return [e for e in self.events if e.warning]

    # ---- simulator controls (the teach pendant) ---------------------------------------------------

    def reset(self) -> None:
        """RESET: clear the alarm (SYSRDY on); a looping program comes back to IBGN start."""
        self.alarm_active = False
        if self.program is ProgramState.ABORTED:
            self.program = ProgramState.ENDED if self.config.auto_start else ProgramState.IDLE
            self._restart_at = self.now + self.config.restart_delay_s if self.config.auto_start else None

    def start_program(self) -> bool:
        """Run the program to IBGN start. False if refused (alarm active, or MOTN-606 posted)."""
        if self.alarm_active:
            return False
        if self.program is ProgramState.WAITING:
            return True
        self._restart_at = None
        return self._begin_ibgn()

    def abort_program(self) -> None:
        """ABORT (FCTN menu): the program stops; an active stream ends without an alarm."""
        self._leave_control()
        self.program = ProgramState.IDLE
        self._restart_at = None

    def set_mode(self, mode: str) -> None:
        """AUTO, T1 or T2; changing it while the program runs aborts it with MOTN-606 (our choice)."""
        mode = mode.upper()
        if mode not in MODES:
            raise ValueError(f"mode={mode!r} must be one of {', '.join(MODES)}")
        changed = mode != self.mode
        self.mode = mode
        if changed and self.program is ProgramState.WAITING:
            self._alarm("MOTN-606")

    def set_payload(self, payload_kg: float | None) -> None:
        """The payload the limit checker judges at (None: the maximum), as a PAYLOAD[] instruction sets
        it on a controller; the service sets it when the active tool changes (servo_app.robots.tool)."""
        if payload_kg is not None and not 0.0 < payload_kg <= self.profile.max_payload_kg:
            raise ValueError(f"payload_kg={payload_kg} must be in (0, {self.profile.max_payload_kg:g}]")
        self.checker.set_payload(payload_kg)

    def set_override(self, pct: int) -> None:
        """Override 1..100 %; changing it while the program runs posts MOTN-606 (61.9)."""
        if not 1 <= pct <= 100:
            raise ValueError(f"override={pct} must be in 1..100")
        changed = pct != self.override
        self.override = int(pct)
        if changed and self.program is ProgramState.WAITING:
            self._alarm("MOTN-606")

    def set_joints(self, q_deg: Sequence[float]) -> None:
        """Place the arm at rest at ``q_deg`` (FANUC deg), e.g. the initial position of a test."""
        self._require_idle_motion("set joints")
        q = np.zeros(N_JOINTS)
        vals = np.asarray(q_deg, dtype=float)[:6]
        q[: len(vals)] = vals
        self.cmd_q = q
        self.servo.set_position(q)
        self._jog = None

    def jog_to(self, q_deg: Sequence[float], duration_s: float | None = None) -> float:
        """Move the command position smoothly to ``q_deg`` while no stream is active; returns the
        duration. Default duration: quintic at ``jog_speed_fraction`` of the velocity and stage-1
        acceleration limits."""
        self._require_idle_motion("jog")
        goal = np.asarray(q_deg, dtype=float)[:6]
        start = self.cmd_q[:6].copy()
        dist = np.abs(goal - start)
        if duration_s is None:
            f = self.config.jog_speed_fraction
            # Quintic peaks: velocity 1.875 d / T, acceleration 5.77 d / T^2.
            t_vel = float(np.max(1.875 * dist / (f * self.checker.vel_lim)))
            t_acc = float(np.max(np.sqrt(5.774 * dist / (f * self.checker.acc1))))
            duration_s = max(t_vel, t_acc, 2 * self.interval_s)
        self._jog = _Jog(start, goal, round(duration_s / self.interval_s))
        return duration_s

    @property
    def jogging(self) -> bool:
        return self._jog is not None

    def _require_idle_motion(self, what: str) -> None:
        if self.command_received:
            raise SimControlError(f"cannot {what}: a command stream is active")
        if self.alarm_active:
            raise SimControlError(f"cannot {what}: an alarm is active (reset first)")

    # ---- views and test hooks ---------------------------------------------------------------------

    @property
    def status_output_on(self) -> bool:
        """Status packets are being sent (a start packet came, no stop packet since)."""
        return self.status_active

    @property
    def command_position(self) -> np.ndarray:
        return self.cmd_q.copy()

    @property
    def servo_position(self) -> np.ndarray:
        return self.servo.q.copy()

    def set_next_status_seq(self, seq: int) -> None:
        """Test hook: the sequence number of the next status packet (to cross the 32-bit wrap)."""
        self._next_status_seq = seq % SEQ_MODULO
