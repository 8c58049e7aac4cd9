"""FANUC Stream Motion (J519, classic protocol, version 1) packets.

Layouts follow manual 61.3 tables 1-4 and Appendix B tables 5-6: big-endian, fixed sizes
8 / 132 / 64 / 8 / 16 / 184 bytes. Encoding is pure; decoding validates length, packet type and
version and raises :class:`PacketError` naming the offending field and value.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from enum import IntEnum

PROTOCOL_VERSION = 1
ROBOT_PORT = 60015
SEQ_MODULO = 1 << 32
N_AXES = 9
N_STAGES = 20


class PacketType(IntEnum):
    STATUS = 0  # status output start (PC -> robot) and status (robot -> PC) share type 0
    COMMAND = 1
    STOP = 2
    LIMIT_TABLE = 3


class DataFormat(IntEnum):
    CARTESIAN = 0
    JOINT = 1


class LimitType(IntEnum):
    VELOCITY = 0
    ACCELERATION = 1
    JERK = 2


class IoType(IntEnum):
    NONE = 0
    DI = 1
    DO = 2
    RI = 8
    RO = 9
    SI = 11
    SO = 12
    WI = 16
    WO = 17
    UI = 20
    UO = 21
    WSI = 26
    WSO = 27
    F = 35
    M = 36


class StatusBit(IntEnum):
    WAITING_FOR_COMMAND = 0x01  # bit 0: IBGN start executing, ready for command packets
    COMMAND_RECEIVED = 0x02  # bit 1: a command packet was received
    SYSRDY = 0x04  # bit 2
    MOVING = 0x08  # bit 3


class PacketError(ValueError):
    """A datagram that is not a valid packet; the message names the field and the value."""


def next_seq(seq: int) -> int:
    """The sequence number after ``seq``: 0xFFFFFFFF is followed by 0."""
    return (seq + 1) % SEQ_MODULO


def seq_diff(a: int, b: int) -> int:
    """Signed distance a - b on the 32-bit sequence circle."""
    d = (a - b) % SEQ_MODULO
    return d - SEQ_MODULO if d >= SEQ_MODULO // 2 else d


_HEADER = struct.Struct(">II")
_STATUS = struct.Struct(">IIIBBHHHI9f9f9f")
_COMMAND = struct.Struct(">IIIBBHHBBHHHH9f")
_LIMIT_REQUEST = struct.Struct(">IIII")
_LIMIT_RESPONSE = struct.Struct(">IIIIII20f20f")

STATUS_START_SIZE = _HEADER.size  # 8
STATUS_SIZE = _STATUS.size  # 132
COMMAND_SIZE = _COMMAND.size  # 64
STATUS_STOP_SIZE = _HEADER.size  # 8
LIMIT_REQUEST_SIZE = _LIMIT_REQUEST.size  # 16
LIMIT_RESPONSE_SIZE = _LIMIT_RESPONSE.size  # 184

_U8, _U16, _U32 = 0xFF, 0xFFFF, 0xFFFFFFFF

# Byte offsets within the packets, for code that answers a status without decoding it (the first
# command of a stream: StreamSession.first_command_early).
STATUS_HEADER = _HEADER.pack(PacketType.STATUS, PROTOCOL_VERSION)  # type and version of a status
SEQ_OFFSET = _HEADER.size  # u32, status and command alike
STATUS_BITS_OFFSET = struct.calcsize(">III")  # u8
STATUS_IO_OFFSET = struct.calcsize(">IIIB")  # read I/O type u8, index u16, mask u16, value u16
STATUS_TIME_OFFSET = struct.calcsize(">IIIBBHHH")  # u32, ms
STATUS_CARTESIAN_OFFSET = struct.calcsize(">IIIBBHHHI")  # 9 x f32
STATUS_JOINTS_OFFSET = struct.calcsize(">IIIBBHHHI9f")  # 9 x f32, J1..J9
COMMAND_LAST_DATA_OFFSET = struct.calcsize(">III")  # u8
COMMAND_FORMAT_OFFSET = struct.calcsize(">IIIBBHH")  # u8
COMMAND_WRITE_VALUE_OFFSET = struct.calcsize(">IIIBBHHBBHH")  # u16
COMMAND_VALUES_OFFSET = struct.calcsize(">IIIBBHHBBHHHH")  # 9 x f32


def _check_uint(name: str, value: int, top: int) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= top:
        raise PacketError(f"{name}={value!r} is not an unsigned integer in 0..{top}")


def _floats(name: str, values: tuple[float, ...] | list[float], n: int = N_AXES) -> tuple[float, ...]:
    vals = tuple(float(v) for v in values)
    if len(vals) > n:
        raise PacketError(f"{name} has {len(vals)} values, at most {n} fit")
    return vals + (0.0,) * (n - len(vals))


@dataclass(frozen=True)
class StatusStart:
    """Table 1: status output start (PC -> robot)."""

    version: int = PROTOCOL_VERSION

    def encode(self) -> bytes:
        return _HEADER.pack(PacketType.STATUS, self.version)


@dataclass(frozen=True)
class StatusStop:
    """Table 4: status output stop (PC -> robot)."""

    version: int = PROTOCOL_VERSION

    def encode(self) -> bytes:
        return _HEADER.pack(PacketType.STOP, self.version)


@dataclass(frozen=True)
class Status:
    """Table 2: status packet (robot -> PC). Positions are servo positions (mm, deg)."""

    seq: int
    status: int = 0
    read_io_type: int = 0
    read_io_index: int = 0
    read_io_mask: int = 0
    read_io_value: int = 0
    timestamp_ms: int = 0
    cartesian: tuple[float, ...] = (0.0,) * N_AXES  # X Y Z W P R E1 E2 E3
    joints: tuple[float, ...] = (0.0,) * N_AXES  # J1..J9
    currents: tuple[float, ...] = (0.0,) * N_AXES  # A
    version: int = PROTOCOL_VERSION

    @property
    def waiting_for_command(self) -> bool:
        return bool(self.status & StatusBit.WAITING_FOR_COMMAND)

    @property
    def command_received(self) -> bool:
        return bool(self.status & StatusBit.COMMAND_RECEIVED)

    @property
    def sysrdy(self) -> bool:
        return bool(self.status & StatusBit.SYSRDY)

    @property
    def moving(self) -> bool:
        return bool(self.status & StatusBit.MOVING)

    def encode(self) -> bytes:
        _check_uint("seq", self.seq, _U32)
        _check_uint("status", self.status, _U8)
        _check_uint("read_io_type", self.read_io_type, _U8)
        _check_uint("read_io_index", self.read_io_index, _U16)
        _check_uint("read_io_mask", self.read_io_mask, _U16)
        _check_uint("read_io_value", self.read_io_value, _U16)
        _check_uint("timestamp_ms", self.timestamp_ms, _U32)
        return _STATUS.pack(
            PacketType.STATUS,
            self.version,
            self.seq,
            self.status,
            self.read_io_type,
            self.read_io_index,
            self.read_io_mask,
            self.read_io_value,
            self.timestamp_ms,
            *_floats("cartesian", self.cartesian),
            *_floats("joints", self.joints),
            *_floats("currents", self.currents),
        )


@dataclass(frozen=True)
class Command:
    """Table 3: command packet (PC -> robot). ``values`` is X Y Z W P R E1-3 or J1..J9."""

    seq: int
    values: tuple[float, ...]
    data_format: int = DataFormat.JOINT
    last_data: int = 0
    read_io_type: int = 0
    read_io_index: int = 0
    read_io_mask: int = 0
    write_io_type: int = 0
    write_io_index: int = 0
    write_io_mask: int = 0
    write_io_value: int = 0
    version: int = PROTOCOL_VERSION
    unused: int = 0

    def encode(self) -> bytes:
        _check_uint("seq", self.seq, _U32)
        _check_uint("last_data", self.last_data, _U8)
        _check_uint("data_format", self.data_format, _U8)
        for name in ("read_io_type", "write_io_type"):
            _check_uint(name, getattr(self, name), _U8)
        for name in ("read_io_index", "read_io_mask", "write_io_index", "write_io_mask", "write_io_value"):
            _check_uint(name, getattr(self, name), _U16)
        return _COMMAND.pack(
            PacketType.COMMAND,
            self.version,
            self.seq,
            self.last_data,
            self.read_io_type,
            self.read_io_index,
            self.read_io_mask,
            self.data_format,
            self.write_io_type,
            self.write_io_index,
            self.write_io_mask,
            self.write_io_value,
            self.unused,
            *_floats("values", self.values),
        )

    def non_finite_axis(self) -> int | None:
        """1-based index of the first NaN/Inf value (what MOTN-605 reports), else None."""
        for i, v in enumerate(self.values, start=1):
            if not math.isfinite(v):
                return i
        return None


@dataclass(frozen=True)
class LimitTableRequest:
    """Table 5: request for one axis's allowable upper limit table."""

    axis: int
    limit_type: int
    version: int = PROTOCOL_VERSION

    def encode(self) -> bytes:
        _check_uint("axis", self.axis, _U32)
        _check_uint("limit_type", self.limit_type, _U32)
        return _LIMIT_REQUEST.pack(PacketType.LIMIT_TABLE, self.version, self.axis, self.limit_type)


@dataclass(frozen=True)
class LimitTableResponse:
    """Table 6: one axis's 20-stage limit table at no payload and at maximum payload."""

    axis: int
    limit_type: int
    vmax_mm_s: int
    check_time_s: int
    no_payload: tuple[float, ...] = field(default=(0.0,) * N_STAGES)
    max_payload: tuple[float, ...] = field(default=(0.0,) * N_STAGES)
    version: int = PROTOCOL_VERSION

    def encode(self) -> bytes:
        for name in ("axis", "limit_type", "vmax_mm_s", "check_time_s"):
            _check_uint(name, getattr(self, name), _U32)
        for name in ("no_payload", "max_payload"):
            if len(getattr(self, name)) != N_STAGES:
                raise PacketError(f"{name} has {len(getattr(self, name))} stages, expected {N_STAGES}")
        return _LIMIT_RESPONSE.pack(
            PacketType.LIMIT_TABLE,
            self.version,
            self.axis,
            self.limit_type,
            self.vmax_mm_s,
            self.check_time_s,
            *self.no_payload,
            *self.max_payload,
        )


_ZEROS = (0.0,) * N_AXES
_COMMAND_TYPE = int(PacketType.COMMAND)  # (an enum member looked up on its class: ~0.1 us a command here)


def pack_command(seq: int, values: tuple[float, ...] | list[float], data_format: int = DataFormat.JOINT,
                 last_data: int = 0, read_io: tuple[int, int, int] = (0, 0, 0),
                 write_io: tuple[int, int, int, int] = (0, 0, 0, 0)) -> bytes:
    """``Command(seq, values, data_format, last_data, *read_io, *write_io).encode()`` without building
    the Command: the same bytes for integer fields in range, in ~1 us instead of ~6 (the session makes
    one per status packet). ``read_io`` is (type, index, mask), ``write_io`` (type, index, mask, value).
    A field that does not fit goes through Command's checks, which raise PacketError naming it."""
    n = len(values)
    if n <= N_AXES:
        try:
            return _COMMAND.pack(_COMMAND_TYPE, PROTOCOL_VERSION, seq, last_data, *read_io, data_format,
                                 *write_io, 0, *values, *_ZEROS[n:])
        except struct.error:
            pass
    return Command(seq, tuple(values), data_format, last_data, *read_io, *write_io).encode()


RobotBound = Status | LimitTableResponse
ControllerBound = StatusStart | StatusStop | Command | LimitTableRequest


_new = object.__new__
_set_dict = object.__setattr__


def _check_version(version: int, expected: int | None) -> None:
    if expected is not None and version != expected:
        raise PacketError(f"version={version} is not supported, expected {expected}")


def decode_from_robot(data: bytes, version: int | None = PROTOCOL_VERSION) -> RobotBound:
    """Decode a datagram sent by the controller: a status packet or a limit-table response."""
    if not (len(data) == STATUS_SIZE and data[:SEQ_OFFSET] == STATUS_HEADER and version == PROTOCOL_VERSION):
        return _decode_checked(data, version)
    # The usual datagram, a status packet (its checks in one comparison). Every field straight into the
    # instance's __dict__, as the frozen dataclass's own __init__ would set them one object.__setattr__
    # at a time: half the cost of a status packet's decode.
    f = _STATUS.unpack(data)
    st = _new(Status)
    _set_dict(st, "__dict__", {"seq": f[2], "status": f[3], "read_io_type": f[4], "read_io_index": f[5],
                               "read_io_mask": f[6], "read_io_value": f[7], "timestamp_ms": f[8],
                               "cartesian": f[9:18], "joints": f[18:27], "currents": f[27:36], "version": f[1]})
    return st


def _decode_checked(data: bytes, version: int | None) -> RobotBound:
    """decode_from_robot for every datagram but a well-formed status packet of the protocol's version:
    a status of another version (``version=None``), a limit-table response, or a PacketError."""
    if len(data) < _HEADER.size:
        raise PacketError(f"length={len(data)} is too short for a packet header (8 bytes)")
    ptype, ver = _HEADER.unpack_from(data)
    if ptype == PacketType.STATUS:
        if len(data) != STATUS_SIZE:
            raise PacketError(f"length={len(data)} is wrong for a status packet, expected {STATUS_SIZE}")
        _check_version(ver, version)
        f = _STATUS.unpack(data)
        return Status(seq=f[2], status=f[3], read_io_type=f[4], read_io_index=f[5], read_io_mask=f[6],
                      read_io_value=f[7], timestamp_ms=f[8], cartesian=f[9:18], joints=f[18:27],
                      currents=f[27:36], version=ver)
    if ptype == PacketType.LIMIT_TABLE:
        if len(data) != LIMIT_RESPONSE_SIZE:
            raise PacketError(
                f"length={len(data)} is wrong for a limit table response, expected {LIMIT_RESPONSE_SIZE}"
            )
        _check_version(ver, version)
        f = _LIMIT_RESPONSE.unpack(data)
        return LimitTableResponse(
            axis=f[2],
            limit_type=f[3],
            vmax_mm_s=f[4],
            check_time_s=f[5],
            no_payload=tuple(f[6:26]),
            max_payload=tuple(f[26:46]),
            version=ver,
        )
    raise PacketError(f"packet_type={ptype} is not a packet the robot sends (0 status, 3 limit table)")


def decode_from_pc(data: bytes, version: int | None = PROTOCOL_VERSION) -> ControllerBound:
    """Decode a datagram sent to the controller.

    ``version=None`` accepts any version number (the simulator does this so that it can raise
    MOTN-607 itself with the received value, as the controller does).
    """
    if len(data) < _HEADER.size:
        raise PacketError(f"length={len(data)} is too short for a packet header (8 bytes)")
    ptype, ver = _HEADER.unpack_from(data)
    expected = {
        PacketType.STATUS: STATUS_START_SIZE,
        PacketType.COMMAND: COMMAND_SIZE,
        PacketType.STOP: STATUS_STOP_SIZE,
        PacketType.LIMIT_TABLE: LIMIT_REQUEST_SIZE,
    }.get(ptype)
    if expected is None:
        raise PacketError(f"packet_type={ptype} is unknown (0 start, 1 command, 2 stop, 3 limit table)")
    if len(data) != expected:
        name = PacketType(ptype).name.lower()
        raise PacketError(f"length={len(data)} is wrong for a {name} packet, expected {expected}")
    _check_version(ver, version)
    if ptype == PacketType.STATUS:
        return StatusStart(version=ver)
    if ptype == PacketType.STOP:
        return StatusStop(version=ver)
    if ptype == PacketType.LIMIT_TABLE:
        _, _, axis, limit_type = _LIMIT_REQUEST.unpack(data)
        return LimitTableRequest(axis=axis, limit_type=limit_type, version=ver)
    f = _COMMAND.unpack(data)
    return Command(
        seq=f[2],
        last_data=f[3],
        read_io_type=f[4],
        read_io_index=f[5],
        read_io_mask=f[6],
        data_format=f[7],
        write_io_type=f[8],
        write_io_index=f[9],
        write_io_mask=f[10],
        write_io_value=f[11],
        unused=f[12],
        values=tuple(f[13:22]),
        version=ver,
    )
