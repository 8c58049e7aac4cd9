"""The robot side of the link, step by step as docs/janome_pointjob.txt does it (pure, no sockets).

The socket shell (``janome_sim``) sends :meth:`PointJob.hello`, feeds received bytes to
:meth:`receive`, asks :meth:`decide` what the point job does next, carries out the move or the hold,
and sends the status that :meth:`status` or :meth:`reject` builds. Robot behaviour modelled:

- the receive buffer holds 8 KB (manual 19); bytes beyond are lost and reported as BUFFER_OVERFLOW,
  after which the buffer is cleared (``clrCOM``);
- ``cmpCOM`` finds no "JRT1" at the head of the buffer -> the buffer is cleared, BAD_MAGIC;
- a whole frame with a wrong terminator or checksum is rejected (BAD_TERMINATOR / BAD_CHECKSUM), an
  unknown cmd / stop / arm value as BAD_COMMAND with the field number, an ack that is not the last
  status seq as BAD_SEQUENCE; each rejection is answered with an ERROR status and the link is kept,
  until ``max_errors`` rejections in a row, when the job says BYE (TOO_MANY_ERRORS) and disconnects;
- a target the arm cannot reach is refused (OUT_OF_RANGE with the axis, UNREACHABLE, BAD_SPEED);
- nothing within the ``setWTCOM`` time: BYE (RX_TIMEOUT) and disconnect (the shell times it).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from servo_app.janome.kinematics import Violation
from servo_app.janome.protocol import (
    FRAME_SIZE,
    N_VALUES,
    RECEIVE_BUFFER,
    TARGET_MAGIC,
    TERMINATOR,
    Cmd,
    ErrorCode,
    FrameError,
    RobotState,
    Status,
    Target,
    checksum,
)
from servo_app.sim.janome_robot import JanomeRobot, MovePlan

_FIELDS = struct.Struct(">13i")
_FIELD_NAMES = ("seq", "ack", "cmd", "stop", "x", "y", "z", "r", "speed", "rspeed", "cond", "arm")


@dataclass(frozen=True)
class PointJobSettings:
    receive_timeout_s: float = 2.0  # setWTCOM
    hold_delay_s: float = 0.05  # `delay` after a HOLD before the next status (keeps the link quiet)
    max_errors: int = 3  # rejections in a row before the job gives up
    buffer_bytes: int = RECEIVE_BUFFER

    def __post_init__(self) -> None:
        if not self.receive_timeout_s > 0 or self.hold_delay_s < 0 or self.max_errors < 1:
            raise ValueError(f"receive_timeout_s={self.receive_timeout_s} must be > 0, hold_delay_s="
                             f"{self.hold_delay_s} >= 0, max_errors={self.max_errors} >= 1")


@dataclass(frozen=True)
class Decision:
    kind: str  # "reject", "hold", "move", "end"
    target: Target | None = None
    plan: MovePlan | None = None
    error: ErrorCode = ErrorCode.NONE
    detail: int = 0
    message: str = ""


def _bad_field(f: tuple[int, ...]) -> int:
    """1-based number of the first field the point job cannot use, 0 if none (its own if-checks)."""
    checks = ((1, f[0] >= 0), (2, f[1] >= 0), (3, f[2] in {int(c) for c in Cmd}), (4, f[3] in (0, 1)),
              (9, f[8] >= 0), (10, f[9] >= 0), (11, 0 <= f[10] <= 99), (12, f[11] in (1, -1)))
    return next((i for i, ok in checks if not ok), 0)


class PointJob:
    def __init__(self, robot: JanomeRobot, settings: PointJobSettings | None = None) -> None:
        self.robot = robot
        self.settings = settings or PointJobSettings()
        self.seq = 0  # last status seq sent
        self.accepted = 0  # last target seq accepted
        self.errors = 0  # rejections in a row
        self.rx = bytearray()
        self.overflowed = 0
        self.gave_up = False

    # ------------------------------------------------------------------ buffer
    def receive(self, data: bytes) -> None:
        room = self.settings.buffer_bytes - len(self.rx)
        if len(data) > room:
            self.overflowed += len(data) - max(room, 0)
            data = data[: max(room, 0)]
        self.rx += data

    def decide(self) -> Decision | None:
        """What the job does with the buffer now; None while it still waits for bytes."""
        if self.overflowed:
            n, self.overflowed = self.overflowed, 0
            self.rx.clear()
            return Decision("reject", error=ErrorCode.BUFFER_OVERFLOW, detail=n,
                            message=f"{n} bytes beyond the {self.settings.buffer_bytes}-byte buffer lost")
        if len(self.rx) < len(TARGET_MAGIC):
            return None
        if self.rx[:4] != TARGET_MAGIC:  # cmpCOM unequal -> clrCOM
            head = bytes(self.rx[:4])
            self.rx.clear()
            return Decision("reject", error=ErrorCode.BAD_MAGIC, message=f"magic={head!r}, expected {TARGET_MAGIC!r}")
        if len(self.rx) < FRAME_SIZE:
            return None
        frame = bytes(self.rx[:FRAME_SIZE])
        del self.rx[:FRAME_SIZE]
        return self._check(frame)

    def _check(self, frame: bytes) -> Decision:
        if frame[-2:] != TERMINATOR:
            return Decision("reject", error=ErrorCode.BAD_TERMINATOR,
                            message=f"terminator={frame[-2:]!r}, expected {TERMINATOR!r}")
        fields = _FIELDS.unpack(frame[4:-2])
        want = checksum(fields[:N_VALUES])
        if fields[N_VALUES] != want:
            return Decision("reject", error=ErrorCode.BAD_CHECKSUM, message=f"checksum={fields[N_VALUES]}, "
                                                                            f"expected {want}")
        bad = _bad_field(fields)
        if bad:
            name = _FIELD_NAMES[bad - 1]
            return Decision("reject", error=ErrorCode.BAD_COMMAND, detail=bad,
                            message=f"field {bad} {name}={fields[bad - 1]} is not valid")
        try:
            t = Target.decode(frame)
        except FrameError as exc:  # not expected after the checks above
            return Decision("reject", error=ErrorCode.BAD_COMMAND, message=str(exc))
        if t.ack != self.seq or t.seq <= self.accepted:
            return Decision("reject", target=t, error=ErrorCode.BAD_SEQUENCE, detail=t.seq,
                            message=f"target seq={t.seq} ack={t.ack}; last status seq={self.seq}, "
                                    f"last target accepted={self.accepted}")
        self.accepted = t.seq
        if t.cmd == Cmd.END:
            return Decision("end", target=t)
        if t.stop or t.cmd == Cmd.HOLD:
            return Decision("hold", target=t)
        plan = self.robot.plan(t)
        if isinstance(plan, Violation):
            return Decision("reject", target=t, error=plan.code, detail=plan.axis, message=plan.message)
        return Decision("move", target=t, plan=plan)

    # ------------------------------------------------------------------ replies
    def hello(self) -> bytes:
        """The first frame after connect: protocol version and robot kind."""
        return self._status(RobotState.HELLO, detail=int(self.robot.profile.kind))

    def status(self, move_ms: int = 0) -> bytes:
        """READY after a move or a hold; resets the rejection count."""
        self.errors = 0
        return self._status(RobotState.READY, move_ms=move_ms)

    def reject(self, d: Decision) -> bytes:
        """ERROR for a rejected frame or target; BYE once too many came in a row."""
        self.errors += 1
        if self.errors >= self.settings.max_errors:
            return self.bye(ErrorCode.TOO_MANY_ERRORS, int(d.error))
        return self._status(RobotState.ERROR, d.error, d.detail)

    def bye(self, error: ErrorCode = ErrorCode.NONE, detail: int = 0) -> bytes:
        self.gave_up = error != ErrorCode.NONE
        return self._status(RobotState.BYE, error, detail)

    def _status(self, state: RobotState, error: ErrorCode = ErrorCode.NONE, detail: int = 0,
                move_ms: int = 0) -> bytes:
        self.seq += 1
        x, y, z, r = (float(v) for v in self.robot.position)
        return Status(seq=self.seq, ack=self.accepted, state=state, error=error, x=x, y=y, z=z, r=r,
                      arm=self.robot.arm, detail=detail, move_ms=move_ms).encode()
