"""The server side of the Janome point-job link as a pure state machine (no sockets, no clock).

The runner hands it the connection's bytes and ``now``; it returns the frames to send. It owns the
protocol rules, nothing else:

- handshake: the robot's first frame is HELLO (protocol version, robot kind = the profile's); a wrong
  one closes the connection with an error naming the field and the value;
- lock-step: every status frame gets exactly one target frame; status sequence numbers count up by
  one, and each status acknowledges the last target sent;
- a target the robot rejected as a frame (bad magic, checksum, terminator, sequence, overflow) is
  sent again with the same seq, at most ``max_retransmits`` times in a row; motion errors the robot
  reports (out of range, unreachable, speed, move failed) become :attr:`pending_alarm` for the
  supervisor;
- malformed status frames are counted and answered with HOLD so the point job goes on; too many in a
  row close the connection;
- time-outs: no HELLO within ``handshake_timeout_s`` of connecting; no status within the expected
  duration of the last move plus ``status_timeout_s`` (a stalled point job or network);
- ending: once the motion source is at rest, END; the robot answers BYE and disconnects.

Motion comes from a :class:`MotionSource` (:class:`servo_app.janome.motion.JanomeMotion`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Protocol

import numpy as np

from servo_app.errors import CommandRejected
from servo_app.janome.alarms import FRAME_ERRORS
from servo_app.janome.motion import Step
from servo_app.janome.protocol import (
    PROTOCOL_VERSION,
    STATUS_MAGIC,
    Cmd,
    ErrorCode,
    FrameError,
    FrameReader,
    RobotKind,
    RobotState,
    Status,
    Target,
)
from servo_app.janome.trapezoid import move_time


class Phase(StrEnum):
    """Values are names in servo_app.state.PHASES, so the published state reads the same for both families."""

    IDLE = "idle"  # no robot, or connected and waiting for its HELLO
    CONNECTED = "connected"  # handshake done: answering HOLD
    WAITING_READY = "waiting_ready"  # armed: streaming starts with the next status
    STREAMING = "streaming"
    ENDING = "ending"  # END due or sent: waiting for BYE
    CLOSED = "closed"  # the robot left after END
    FAULT = "fault"


class MotionSource(Protocol):
    stopped: bool

    def begin(self, xyzr: tuple[float, ...], arm: int) -> None:
        """Streaming starts at the robot's reported position and arm configuration."""

    def next_step(self) -> Step | None:
        """The next target, or None for no motion; one call per target frame."""

    def request_rest(self) -> None:
        """Send no further step (the session wants to end)."""

    def at_rest(self) -> bool:
        """True once no step is pending."""


@dataclass
class SessionConfig:
    kind: RobotKind = RobotKind.CARTESIAN
    status_timeout_s: float = 1.0  # beyond the expected move time
    handshake_timeout_s: float = 2.0
    max_retransmits: int = 3
    max_malformed: int = 3  # consecutive malformed status frames before the link is dropped
    cp_accel: float = 3000.0  # mm/s^2, to expect how long a step takes
    r_accel: float = 5000.0  # deg/s^2

    def __post_init__(self) -> None:
        for name in ("status_timeout_s", "handshake_timeout_s", "cp_accel", "r_accel"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"{name}={value!r} must be > 0")
        if self.max_retransmits < 0 or self.max_malformed < 1:
            raise ValueError(f"max_retransmits={self.max_retransmits} must be >= 0 and "
                             f"max_malformed={self.max_malformed} >= 1")


@dataclass
class SessionStats:
    status_received: int = 0
    status_lost: int = 0  # gaps in the status sequence
    status_duplicated: int = 0  # repeated or older status seq
    commands_sent: int = 0  # target frames, retransmissions included
    moves_sent: int = 0
    retransmits: int = 0
    malformed: int = 0
    connections: int = 0
    last_error: str = ""


@dataclass
class RobotAlarm:
    error: ErrorCode
    detail: int
    message: str


@dataclass
class JanomeSession:
    motion: MotionSource
    config: SessionConfig = field(default_factory=SessionConfig)
    phase: Phase = Phase.IDLE
    stats: SessionStats = field(default_factory=SessionStats)
    fault_reason: str = ""
    last_status: Status | None = None
    pending_alarm: RobotAlarm | None = None  # a robot error for the supervisor to turn into a fault
    warnings: list[str] = field(default_factory=list)  # for the supervisor's log; it empties the list

    def __post_init__(self) -> None:
        self.connected = False
        self.handshaken = False
        self.accepting = True
        self.want_close = False  # the runner closes the connection when set
        self.refused_hello: Status | None = None  # a HELLO refused: received, so logged (the runner's log)
        self.sent: list[Target] = []  # frames of the last call, for the runner's log
        self._reader = FrameReader(STATUS_MAGIC)
        self._armed = False
        self._end_requested = False
        self._end_sent = False
        self._next_seq = 1
        self._last_target: Target | None = None
        self._retransmits = 0
        self._malformed_run = 0
        self._since = 0.0  # connect time, or when the last frame went out
        self._expect_s = 0.0  # how long the robot needs for the last frame
        self._awaiting = False

    # ----------------------------------------------------------------- connection
    def on_connect(self, now: float) -> None:
        self.connected, self.handshaken, self.want_close = True, False, False
        self._reader = FrameReader(STATUS_MAGIC)
        self.last_status = self.refused_hello = None
        self._last_target = None
        self._next_seq = 1
        self._retransmits = self._malformed_run = 0
        self._end_sent = self._end_requested = False
        self._since, self._awaiting, self._expect_s = now, True, 0.0
        self.fault_reason = ""
        self.stats.connections += 1
        self.phase = Phase.IDLE

    def on_disconnect(self, reason: str, now: float) -> None:
        """The connection is gone (closed by either side)."""
        was = self.phase
        self.connected = self.handshaken = False
        self._awaiting = False
        self.want_close = False
        if was in (Phase.STREAMING, Phase.ENDING, Phase.WAITING_READY) and not self._end_sent:
            self._fault(f"connection lost: {reason}")
        elif was not in (Phase.CLOSED, Phase.FAULT):
            self.phase = Phase.IDLE

    # ------------------------------------------------------------------- requests
    def arm(self) -> None:
        """Stream from the next status frame on."""
        self._armed = True
        self._end_requested = self._end_sent = False
        if self.phase == Phase.CONNECTED:
            self.phase = Phase.WAITING_READY
            if self.last_status is not None:
                # The robot holds where its last status says (it is in its HOLD delay, or about to
                # send the next status): motion can start from there at once.
                self._begin(self.last_status)

    def request_end(self) -> None:
        """Stop stepping; send END once at rest."""
        self._end_requested = True
        self._armed = False
        self.motion.request_rest()
        if self.phase in (Phase.CONNECTED, Phase.WAITING_READY):
            self.phase = Phase.ENDING

    def abandon(self, reason: str) -> None:
        """Stop streaming. A healthy link stays up holding (the point job waits, the robot stands still);
        a broken one is closed so the point job leaves its loop."""
        self._armed = self._end_requested = False
        if self.phase == Phase.FAULT or not self.connected:
            self.want_close = self.connected
            return
        self.stats.last_error = reason
        self.phase = Phase.CONNECTED if self.handshaken else Phase.IDLE

    def close(self, reason: str) -> None:
        """Drop the connection (service shutting down); the point job sees it and ends."""
        self.accepting = False
        self._armed = False
        if self.connected:
            self.want_close = True
            self.stats.last_error = reason

    @property
    def output_on(self) -> bool:
        """A robot is connected (the FANUC session's "status output on")."""
        return self.connected

    @property
    def streaming(self) -> bool:
        return self.phase in (Phase.STREAMING, Phase.ENDING)

    # --------------------------------------------------------------------- inputs
    def take(self, data: bytes) -> list[Status | FrameError]:
        """Cut received bytes into decoded status frames and rejections (in order)."""
        self._reader.feed(data)
        out: list[Status | FrameError] = []
        while True:
            chunk = self._reader.next()
            if chunk is None:
                break
            if isinstance(chunk, FrameError):
                out.append(chunk)
                continue
            try:
                out.append(Status.decode(chunk))
            except FrameError as exc:
                out.append(_Complete(str(exc)))
        if self._reader.dropped:
            out.append(FrameError(f"{self._reader.dropped} bytes beyond the {self._reader.capacity}-byte "
                                  "buffer dropped"))
            self._reader.dropped = 0
        return out

    def on_bytes(self, data: bytes, now: float) -> list[bytes]:
        """Convenience for tests: take + handle every frame."""
        out: list[bytes] = []
        for item in self.take(data):
            out += self.on_malformed(item, now) if isinstance(item, FrameError) else self.on_status(item, now)
        return out

    def on_malformed(self, err: FrameError, now: float) -> list[bytes]:
        self.sent = []
        self.stats.malformed += 1
        self._malformed_run += 1
        self.stats.last_error = f"status frame rejected: {err}"
        if self._malformed_run >= self.config.max_malformed:
            self._fault(f"{self._malformed_run} malformed status frames in a row; last: {err}")
            return []
        if isinstance(err, _Complete) and self.handshaken and self.last_status is not None:
            # A whole frame arrived but is unusable: answer it with HOLD as if it were the next status,
            # so the point job (waiting for an answer) goes on instead of timing out.
            return [self._send(self._hold(self.last_status.seq + 1), now)]
        return []

    def on_status(self, st: Status, now: float) -> list[bytes]:
        self.sent = []
        self._malformed_run = 0
        if self.phase == Phase.FAULT or not self.connected:
            return []
        if not self.handshaken:
            return self._handshake(st, now)
        prev = self.last_status
        assert prev is not None
        if st.seq <= prev.seq:
            self.stats.status_duplicated += 1
            self.stats.last_error = f"status seq={st.seq} is not after {prev.seq}: ignored"
            return []
        if st.seq > prev.seq + 1:
            self.stats.status_lost += st.seq - prev.seq - 1
        self.stats.status_received += 1
        self.last_status = st
        self._awaiting = False
        if st.state == RobotState.HELLO:
            self._fault(f"status seq={st.seq}: state=HELLO again without a new connection")
            return []
        if st.state == RobotState.BYE:
            return self._on_bye(st)
        last_seq = self._last_target.seq if self._last_target else 0
        if st.state == RobotState.ERROR:
            return self._on_error(st, last_seq, now)
        if st.ack != last_seq:
            self._fault(f"status seq={st.seq} acknowledges target ack={st.ack}, but the last target sent was "
                        f"seq={last_seq}")
            return []
        self._retransmits = 0
        return [self._send(self._answer(st), now)]

    def on_idle(self, now: float) -> list[bytes]:
        """Call when nothing arrived for a while: time-outs live here."""
        self.sent = []
        if not self.connected or not self._awaiting or self.phase == Phase.FAULT:
            return []
        silent = now - self._since
        if not self.handshaken:
            if silent > self.config.handshake_timeout_s:
                self.stats.last_error = f"no HELLO frame within {self.config.handshake_timeout_s} s of connecting"
                self.want_close = True
                self._awaiting = False
            return []
        limit = self._expect_s + self.config.status_timeout_s
        if silent > limit:
            self._fault(f"no status frame for {silent:.2f} s (expected within {limit:.2f} s)")
        return []

    # ------------------------------------------------------------------ internals
    def _handshake(self, st: Status, now: float) -> list[bytes]:
        why = None
        if st.state != RobotState.HELLO:
            why = f"first frame has state={st.state.name}, expected HELLO"
        elif st.version != PROTOCOL_VERSION:
            why = (f"HELLO has version={st.version}, servo_app speaks {PROTOCOL_VERSION}: "
                   "update the point job from docs/janome_pointjob.txt")
        elif st.detail != self.config.kind:
            kind = RobotKind(st.detail).name if st.detail in RobotKind._value2member_map_ else "unknown"
            why = (f"HELLO has detail={st.detail} (robot kind {kind}), but the profile is "
                   f"{self.config.kind.name.lower()}: choose the matching --model")
        if why is not None:
            self.refused_hello = st
            self.stats.last_error = f"handshake refused: {why}"
            self.want_close = True
            self._awaiting = False
            return []
        self.handshaken = True
        self.stats.last_error = ""  # an earlier connection's end is history once a new one is up
        self.last_status = st
        self.stats.status_received += 1
        self._awaiting = False
        self.phase = Phase.WAITING_READY if self._armed else Phase.CONNECTED
        if self._end_requested:
            self.phase = Phase.ENDING
        return [self._send(self._answer(st), now)]

    def _on_bye(self, st: Status) -> list[bytes]:
        why = f"robot left its loop (BYE, error={st.error.name}, detail={st.detail})"
        if st.error != ErrorCode.NONE:
            self.pending_alarm = RobotAlarm(st.error, st.detail, f"{st.error.name} (detail {st.detail})")
        if self._end_sent:
            self.phase = Phase.CLOSED
        elif self.phase in (Phase.STREAMING, Phase.WAITING_READY, Phase.ENDING):
            self._fault(why)
        else:
            self.stats.last_error = why
            self.phase = Phase.IDLE
        self.want_close = True  # the point job disconnects next; no need to wait for it
        return []

    def _on_error(self, st: Status, last_seq: int, now: float) -> list[bytes]:
        what = f"robot rejected target seq={last_seq}: {st.error.name} (detail {st.detail})"
        t = self._last_target
        if st.error == ErrorCode.OUT_OF_RANGE and 1 <= st.detail <= 4 and t is not None:
            axis = "XYZR"[st.detail - 1]
            what = f"robot rejected target seq={last_seq}: {axis}={t.xyzr[st.detail - 1]:.3f} is OUT_OF_RANGE"
        self.stats.last_error = what
        if st.error in FRAME_ERRORS and self._last_target is not None and st.ack != last_seq:
            self._retransmits += 1
            if self._retransmits > self.config.max_retransmits:
                self.pending_alarm = RobotAlarm(st.error, st.detail, f"{what}, {self._retransmits} times in a row")
                return [self._send(self._hold(st.seq), now)]
            self.stats.retransmits += 1
            self.warnings.append(f"{what}: sent again")
            again = replace(self._last_target, ack=st.seq)
            return [self._send(again, now, retransmit=True)]
        if st.error in FRAME_ERRORS:  # our last frame was taken; the rejected bytes were not ours
            self.warnings.append(what)
            return [self._send(self._answer(st), now)]
        self.pending_alarm = RobotAlarm(st.error, st.detail, what)
        if self.streaming:
            self.motion.request_rest()
        return [self._send(self._hold(st.seq), now)]

    def _answer(self, st: Status) -> Target:
        if self.phase == Phase.WAITING_READY:
            self._begin(st)
        ending = self.phase == Phase.ENDING or (self.phase == Phase.STREAMING and self._end_requested)
        if ending and (self.motion.at_rest() or not self.streaming):
            self.phase = Phase.ENDING
            self._end_sent = True
            return Target(seq=self._take_seq(), ack=st.seq, cmd=Cmd.END, stop=True, x=st.x, y=st.y, z=st.z,
                          r=st.r, arm=st.arm)
        if self.phase != Phase.STREAMING:
            return self._hold(st.seq)
        try:
            step = self.motion.next_step()
        except CommandRejected as exc:
            self.stats.last_error = str(exc)
            self.warnings.append(str(exc))
            step = None
        if step is None:
            return self._hold(st.seq)
        x, y, z, r = step.xyzr
        return Target(seq=self._take_seq(), ack=st.seq, cmd=step.cmd, stop=False, x=x, y=y, z=z, r=r,
                      speed=step.speed, rspeed=step.rspeed, cond=step.cond, arm=step.arm)

    def _begin(self, st: Status) -> None:
        self.motion.begin(st.xyzr, st.arm)
        self._armed = False
        self.phase = Phase.STREAMING

    def _hold(self, ack: int) -> Target:
        p = self.last_status.xyzr if self.last_status else (0.0, 0.0, 0.0, 0.0)
        arm = self.last_status.arm if self.last_status else 1
        stop = self.phase != Phase.STREAMING or bool(getattr(self.motion, "stopped", False))
        return Target(seq=self._take_seq(), ack=ack, cmd=Cmd.HOLD, stop=stop, x=p[0], y=p[1], z=p[2], r=p[3],
                      arm=arm)

    def _take_seq(self) -> int:
        seq, self._next_seq = self._next_seq, self._next_seq + 1
        return seq

    def _send(self, t: Target, now: float, retransmit: bool = False) -> bytes:
        data = t.encode()
        self.sent.append(t)
        self._last_target = t
        self.stats.commands_sent += 1
        if t.moves and not retransmit:
            self.stats.moves_sent += 1
        self._since, self._awaiting = now, t.cmd != Cmd.END
        self._expect_s = self._expected_duration(t)
        return data

    def _expected_duration(self, t: Target) -> float:
        if not t.moves or self.last_status is None:
            return 0.0
        d = np.subtract(t.xyzr, self.last_status.xyzr)
        lin = float(np.linalg.norm(d[:3]))
        out = move_time(lin, t.speed, self.config.cp_accel) if lin > 0 and t.speed > 0 else 0.0
        if abs(d[3]) > 0 and t.rspeed > 0:
            out = max(out, move_time(abs(float(d[3])), t.rspeed, self.config.r_accel))
        return out

    def _fault(self, reason: str) -> None:
        self.fault_reason = reason
        self.stats.last_error = reason
        self.phase = Phase.FAULT
        self._awaiting = False
        self.want_close = self.connected


class _Complete(FrameError):
    """A whole 58-byte frame with the right magic that failed to decode."""
