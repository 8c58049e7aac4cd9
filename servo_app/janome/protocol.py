"""The Janome point-job link: fixed-length binary frames a point job can build and parse itself.

The robot runs a point job that is a TCP client (manual 21.1, Ethernet client function); servo_app
is the server. The exchange is lock-step: the robot sends a *status* frame, servo_app answers with
exactly one *target* frame, the robot carries it out (a short move, or nothing) and sends the next
status. So the robot's receive buffer (8 KB per port, manual 19) never holds more than one frame.

Both frames are 58 bytes, chosen so the point job needs only documented commands:

    magic   4 bytes ASCII  "JRS1" (status, robot -> servo_app) / "JRT1" (target, servo_app -> robot)
    fields  13 x int32 big-endian (the point job's str4SIBE()/val4SIBE() string functions)
    end     2 bytes CR LF

The point job checks the magic with ``cmpCOM`` (which waits up to the ``setWTCOM`` timeout), reads
each field with ``inCOM`` into a string and converts it with ``val4SIBE``. Lengths, positions and
speeds are integers in thousandths (0.001 mm, 0.001 deg, 0.001 mm/s, 0.001 deg/s); the point job
multiplies or divides by 1000.

The last field is a checksum the point job can compute with plain arithmetic:

    chk = S - 65521 * ip(S / 65521),   S = sum over the first 12 fields of (i * field_i), i = 1..12

(``ip`` truncates toward zero, so chk has the sign of S.) 65521 is prime, so a change of any one
byte of a field always changes chk, and the weights catch two fields swapped.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import ClassVar

PROTOCOL_VERSION = 1
STATUS_MAGIC = b"JRS1"
TARGET_MAGIC = b"JRT1"
TERMINATOR = b"\r\n"
N_VALUES = 12  # fields before the checksum
FRAME_SIZE = len(STATUS_MAGIC) + 4 * (N_VALUES + 1) + len(TERMINATOR)  # 58
SCALE = 1000  # wire units per mm, deg, mm/s or deg/s
CHECK_MODULUS = 65521
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1
RECEIVE_BUFFER = 8192  # bytes per port on the robot (manual 19, clrCOM)

_FIELDS = struct.Struct(">13i")


class FrameError(ValueError):
    """Bytes that are not a valid frame; the message names the field and the value."""


class Cmd(IntEnum):
    HOLD = 0  # no new target: stay where you are (also the handshake reply)
    LINE = 1  # lineMove (CP, straight line) to the target at `speed` (R-only: monoMove at `rspeed`)
    PTP = 2  # moveAPTP to the target with PTP condition `cond` and arm configuration `arm`
    END = 9  # leave the loop: reply BYE, disconnect, end the program


class RobotState(IntEnum):
    HELLO = 0  # first frame after connect; detail = RobotKind
    READY = 1  # last target carried out (or held): waiting for the next
    ERROR = 2  # the last frame was rejected or its move failed: `error`, `detail` say why
    BYE = 3  # leaving the loop (END received, or giving up): the robot disconnects next


class ErrorCode(IntEnum):
    NONE = 0
    BAD_MAGIC = 1  # cmpCOM did not find "JRT1": receive buffer cleared (clrCOM)
    BAD_CHECKSUM = 2
    BAD_TERMINATOR = 3
    BAD_SEQUENCE = 4  # target's ack is not the seq of the status it should answer
    BAD_COMMAND = 5  # unknown cmd, stop flag or arm value; detail = the field number (1-based)
    OUT_OF_RANGE = 6  # target outside a stroke; detail = axis (1 X, 2 Y, 3 Z, 4 R)
    UNREACHABLE = 7  # SCARA: no solution in the arm configuration, or the path leaves it
    BAD_SPEED = 8  # speed <= 0 or above the robot's maximum
    MOVE_FAILED = 9  # the move command itself reported an error
    RX_TIMEOUT = 10  # nothing (or not a whole frame) within the setWTCOM time: giving up (BYE)
    BUFFER_OVERFLOW = 11  # more than 8 KB waiting: receive buffer cleared
    TOO_MANY_ERRORS = 12  # consecutive rejected frames reached the job's limit: giving up (BYE)


class RobotKind(IntEnum):
    CARTESIAN = 1  # JR3000, JC-3: X Y Z R
    SCARA = 2  # JS3: J1 J2 Z R, commanded in X Y Z R with an arm configuration


class Arm(IntEnum):
    """moveAPTP's coordinate-system argument (manual 8.1.1): 1 righty, -1 lefty (JR3000/JC-3: always 1)."""

    RIGHTY = 1
    LEFTY = -1


def _enum_text(enum: type[IntEnum]) -> str:
    return ", ".join(f"{m.name}={m.value}" for m in enum)


def checksum(values: tuple[int, ...] | list[int]) -> int:
    """The frame checksum of the first 12 field values, exactly as the point job computes it."""
    s = sum((i + 1) * v for i, v in enumerate(values))
    r = abs(s) % CHECK_MODULUS
    return -r if s < 0 else r


def to_wire(name: str, value: float, what: str) -> int:
    """mm, deg, mm/s or deg/s -> int32 thousandths; rejects what the point job could not represent."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise FrameError(f"{what} frame: {name}={value!r} is not a finite number")
    n = round(value * SCALE)
    if not INT32_MIN <= n <= INT32_MAX:
        raise FrameError(f"{what} frame: {name}={value!r} does not fit an int32 in thousandths")
    return n


def _speed(name: str, value: float, what: str) -> int:
    n = to_wire(name, value, what)
    if n < 0:
        raise FrameError(f"{what} frame: {name}={value!r} must not be negative")
    return n


def _int_field(name: str, value: int, what: str, lo: int = INT32_MIN, hi: int = INT32_MAX) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise FrameError(f"{what} frame: {name}={value!r} must be an integer in {lo}..{hi}")
    return value


def _pack(magic: bytes, values: list[int]) -> bytes:
    return magic + _FIELDS.pack(*values, checksum(values)) + TERMINATOR


def _unpack(data: bytes, magic: bytes, what: str) -> tuple[int, ...]:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise FrameError(f"{what} frame: data of type {type(data).__name__} is not bytes")
    data = bytes(data)
    if len(data) != FRAME_SIZE:
        raise FrameError(f"{what} frame: length={len(data)}, expected {FRAME_SIZE}")
    if data[:4] != magic:
        raise FrameError(f"{what} frame: magic={data[:4]!r}, expected {magic!r}")
    if data[-2:] != TERMINATOR:
        raise FrameError(f"{what} frame: terminator={data[-2:]!r}, expected {TERMINATOR!r}")
    fields = _FIELDS.unpack(data[4:-2])
    want = checksum(fields[:N_VALUES])
    if fields[N_VALUES] != want:
        raise FrameError(f"{what} frame: checksum={fields[N_VALUES]}, expected {want} from the fields")
    return fields[:N_VALUES]


def _enum(enum: type[IntEnum], name: str, value: int, what: str) -> int:
    try:
        return int(enum(value))
    except ValueError:
        raise FrameError(f"{what} frame: {name}={value} is not one of {_enum_text(enum)}") from None


@dataclass(frozen=True)
class Target:
    """servo_app -> robot. Positions in mm / deg (absolute, robot coordinates), speeds in mm/s / deg/s."""

    seq: int
    ack: int  # seq of the status this answers
    cmd: Cmd = Cmd.HOLD
    stop: bool = False  # servo_app is stopped: do not move for this frame, whatever cmd says
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    r: float = 0.0
    speed: float = 0.0  # lineMove speed, mm/s
    rspeed: float = 0.0  # R speed for R-only steps (monoMove), deg/s
    cond: int = 0  # moveAPTP PTP condition number (0: the program's)
    arm: int = Arm.RIGHTY

    WHAT: ClassVar[str] = "target"

    @property
    def xyzr(self) -> tuple[float, float, float, float]:
        return (self.x, self.y, self.z, self.r)

    @property
    def moves(self) -> bool:
        return self.cmd in (Cmd.LINE, Cmd.PTP) and not self.stop

    def values(self) -> list[int]:
        w = self.WHAT
        return [
            _int_field("seq", self.seq, w, 0),
            _int_field("ack", self.ack, w, 0),
            _enum(Cmd, "cmd", self.cmd, w),
            int(bool(self.stop)),
            *(to_wire(n, v, w) for n, v in zip("xyzr", self.xyzr, strict=True)),
            _speed("speed", self.speed, w),
            _speed("rspeed", self.rspeed, w),
            _int_field("cond", self.cond, w, 0, 99),
            _enum(Arm, "arm", self.arm, w),
        ]

    def encode(self) -> bytes:
        return _pack(TARGET_MAGIC, self.values())

    @classmethod
    def decode(cls, data: bytes) -> Target:
        w = cls.WHAT
        seq, ack, cmd, stop, x, y, z, r, speed, rspeed, cond, arm = _unpack(data, TARGET_MAGIC, w)
        if seq < 0 or ack < 0:
            raise FrameError(f"{w} frame: seq={seq}, ack={ack} must not be negative")
        if stop not in (0, 1):
            raise FrameError(f"{w} frame: stop={stop} must be 0 or 1")
        if speed < 0 or rspeed < 0:
            raise FrameError(f"{w} frame: speed={speed / SCALE}, rspeed={rspeed / SCALE} must not be negative")
        if not 0 <= cond <= 99:
            raise FrameError(f"{w} frame: cond={cond} must be a PTP condition number 0..99")
        return cls(seq=seq, ack=ack, cmd=Cmd(_enum(Cmd, "cmd", cmd, w)), stop=bool(stop), x=x / SCALE,
                   y=y / SCALE, z=z / SCALE, r=r / SCALE, speed=speed / SCALE, rspeed=rspeed / SCALE, cond=cond,
                   arm=_enum(Arm, "arm", arm, w))


@dataclass(frozen=True)
class Status:
    """robot -> servo_app: where the robot is (currentCmdArmX..R, after the last move) and how it went."""

    seq: int  # 1 for HELLO, +1 per status
    ack: int  # seq of the last target frame accepted (0 before any)
    state: RobotState = RobotState.READY
    error: ErrorCode = ErrorCode.NONE
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    r: float = 0.0
    arm: int = Arm.RIGHTY
    detail: int = 0  # HELLO: RobotKind; ERROR: the axis or field concerned
    move_ms: int = 0  # duration of the last move, ms (the point job times it with a down timer)
    version: int = PROTOCOL_VERSION

    WHAT: ClassVar[str] = "status"

    @property
    def xyzr(self) -> tuple[float, float, float, float]:
        return (self.x, self.y, self.z, self.r)

    def values(self) -> list[int]:
        w = self.WHAT
        return [
            _int_field("seq", self.seq, w, 0),
            _int_field("ack", self.ack, w, 0),
            _enum(RobotState, "state", self.state, w),
            _enum(ErrorCode, "error", self.error, w),
            *(to_wire(n, v, w) for n, v in zip("xyzr", self.xyzr, strict=True)),
            _enum(Arm, "arm", self.arm, w),
            _int_field("detail", self.detail, w),
            _int_field("move_ms", self.move_ms, w, 0),
            _int_field("version", self.version, w, 0),
        ]

    def encode(self) -> bytes:
        return _pack(STATUS_MAGIC, self.values())

    @classmethod
    def decode(cls, data: bytes) -> Status:
        w = cls.WHAT
        seq, ack, state, error, x, y, z, r, arm, detail, move_ms, version = _unpack(data, STATUS_MAGIC, w)
        if seq < 0 or ack < 0 or move_ms < 0:
            raise FrameError(f"{w} frame: seq={seq}, ack={ack}, move_ms={move_ms} must not be negative")
        return cls(seq=seq, ack=ack, state=RobotState(_enum(RobotState, "state", state, w)),
                   error=ErrorCode(_enum(ErrorCode, "error", error, w)), x=x / SCALE, y=y / SCALE, z=z / SCALE,
                   r=r / SCALE, arm=_enum(Arm, "arm", arm, w), detail=detail, move_ms=move_ms, version=version)


class FrameReader:
    """Cuts a TCP byte stream into frames starting with ``magic``.

    ``next()`` gives one 58-byte chunk (not yet decoded), a :class:`FrameError` for bytes skipped to
    find the next magic (so a corrupted stream resynchronises), or None when more bytes are needed.
    Like the robot's buffer it holds at most ``capacity`` bytes; more is dropped and counted.
    """

    def __init__(self, magic: bytes, capacity: int = RECEIVE_BUFFER) -> None:
        self.magic = magic
        self.capacity = capacity
        self.buf = bytearray()
        self.dropped = 0

    def feed(self, data: bytes) -> None:
        room = self.capacity - len(self.buf)
        if len(data) > room:
            self.dropped += len(data) - max(room, 0)
            data = data[: max(room, 0)]
        self.buf += data

    def next(self) -> bytes | FrameError | None:
        if len(self.buf) < len(self.magic):
            return None
        at = self.buf.find(self.magic)
        if at != 0:
            skip = at if at > 0 else len(self.buf) - self._magic_prefix_at_end()
            if skip <= 0:
                return None
            junk = bytes(self.buf[:skip])
            del self.buf[:skip]
            return FrameError(f"{len(junk)} bytes without the magic {self.magic!r} skipped: {junk[:16]!r}"
                              + ("..." if len(junk) > 16 else ""))
        if len(self.buf) < FRAME_SIZE:
            return None
        chunk = bytes(self.buf[:FRAME_SIZE])
        del self.buf[:FRAME_SIZE]
        return chunk

    def _magic_prefix_at_end(self) -> int:
        """Length of the longest tail of the buffer that starts the magic (kept: the rest may follow)."""
        for n in range(len(self.magic) - 1, 0, -1):
            if self.buf.endswith(self.magic[:n]):
                return n
        return 0

    def clear(self) -> None:
        self.buf.clear()
