"""Janome link codec: sizes, round trips, the point job's checksum, rejection of malformed frames."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from servo_app.janome import protocol as P

# positions within what int32 thousandths can carry, at the wire resolution
milli = st.integers(-2_000_000_000, 2_000_000_000).map(lambda n: n / 1000)
speed = st.integers(0, 2_000_000_000).map(lambda n: n / 1000)
seq = st.integers(0, P.INT32_MAX)

targets = st.builds(P.Target, seq=seq, ack=seq, cmd=st.sampled_from(list(P.Cmd)), stop=st.booleans(), x=milli,
                    y=milli, z=milli, r=milli, speed=speed, rspeed=speed, cond=st.integers(0, 99),
                    arm=st.sampled_from([1, -1]))
statuses = st.builds(P.Status, seq=seq, ack=seq, state=st.sampled_from(list(P.RobotState)),
                     error=st.sampled_from(list(P.ErrorCode)), x=milli, y=milli, z=milli, r=milli,
                     arm=st.sampled_from([1, -1]), detail=st.integers(P.INT32_MIN, P.INT32_MAX),
                     move_ms=st.integers(0, P.INT32_MAX), version=st.integers(0, 9))


def point_job_checksum(values: list[int]) -> int:
    """The checksum as the point job computes it: floating point, ip() truncating toward zero."""
    s = 0.0
    for i, v in enumerate(values):
        s = s + (i + 1) * float(v)
    return int(s - 65521 * math.trunc(s / 65521))


def test_frame_layout() -> None:
    assert P.FRAME_SIZE == 58
    t = P.Target(seq=0x01020304, ack=7, cmd=P.Cmd.LINE, x=1.5, y=-2.0, z=0.001, r=-90.0, speed=100.0, rspeed=30.0,
                 cond=2, arm=-1)
    b = t.encode()
    assert len(b) == 58 and b[:4] == b"JRT1" and b[-2:] == b"\r\n"
    fields = struct.unpack(">13i", b[4:56])
    assert fields[:12] == (0x01020304, 7, 1, 0, 1500, -2000, 1, -90000, 100000, 30000, 2, -1)
    assert fields[12] == point_job_checksum(list(fields[:12]))
    s = P.Status(seq=1, ack=0, state=P.RobotState.HELLO, detail=int(P.RobotKind.SCARA)).encode()
    assert s[:4] == b"JRS1" and struct.unpack(">i", s[4 + 4 * 11:4 + 4 * 12])[0] == P.PROTOCOL_VERSION


@given(targets)
def test_target_round_trip(t: P.Target) -> None:
    assert P.Target.decode(t.encode()) == t


@given(statuses)
def test_status_round_trip(s: P.Status) -> None:
    assert P.Status.decode(s.encode()) == s


@given(st.lists(st.integers(P.INT32_MIN, P.INT32_MAX), min_size=12, max_size=12))
def test_checksum_equals_the_point_job_arithmetic(values: list[int]) -> None:
    c = P.checksum(values)
    assert c == point_job_checksum(values)
    assert -P.CHECK_MODULUS < c < P.CHECK_MODULUS


@given(targets, st.integers(4, 4 + 4 * 13 - 1), st.integers(1, 255))
def test_any_one_corrupted_byte_is_caught(t: P.Target, index: int, xor: int) -> None:
    b = bytearray(t.encode())
    b[index] ^= xor
    with pytest.raises(P.FrameError, match="checksum="):
        P.Target.decode(bytes(b))


@given(targets)
def test_two_fields_swapped_are_caught(t: P.Target) -> None:
    b = bytearray(t.encode())
    x, y = b[4 + 4 * 4:4 + 4 * 5], b[4 + 4 * 5:4 + 4 * 6]
    if x == y:
        return
    b[4 + 4 * 4:4 + 4 * 5], b[4 + 4 * 5:4 + 4 * 6] = y, x
    with pytest.raises(P.FrameError, match="checksum="):
        P.Target.decode(bytes(b))


def _forge(magic: bytes, values: list[int], term: bytes = b"\r\n") -> bytes:
    return magic + struct.pack(">13i", *values, P.checksum(values)) + term


@pytest.mark.parametrize(("data", "message"), [
    (b"JRT1" + bytes(50), r"length=54, expected 58"),
    (b"XXXX" + bytes(54), r"magic=b'XXXX', expected b'JRT1'"),
    (P.Target(1, 1).encode()[:-2] + b"\n\n", r"terminator=b'\\n\\n'"),
    (_forge(b"JRT1", [1, 1, 7, 0, 0, 0, 0, 0, 0, 0, 0, 1]), r"cmd=7 is not one of HOLD=0, LINE=1, PTP=2, END=9"),
    (_forge(b"JRT1", [1, 1, 0, 2, 0, 0, 0, 0, 0, 0, 0, 1]), r"stop=2 must be 0 or 1"),
    (_forge(b"JRT1", [1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]), r"arm=0 is not one of RIGHTY=1, LEFTY=-1"),
    (_forge(b"JRT1", [1, 1, 1, 0, 0, 0, 0, 0, -5, 0, 0, 1]), r"speed=-0.005"),
    (_forge(b"JRT1", [1, 1, 1, 0, 0, 0, 0, 0, 5, 0, 100, 1]), r"cond=100"),
])
def test_malformed_targets_name_field_and_value(data: bytes, message: str) -> None:
    with pytest.raises(P.FrameError, match=message):
        P.Target.decode(data)


def test_malformed_status_names_field_and_value() -> None:
    with pytest.raises(P.FrameError, match=r"status frame: state=9 is not one of HELLO=0"):
        P.Status.decode(_forge(b"JRS1", [1, 0, 9, 0, 0, 0, 0, 0, 1, 0, 0, 1]))
    with pytest.raises(P.FrameError, match=r"status frame: error=99 is not one of"):
        P.Status.decode(_forge(b"JRS1", [1, 0, 1, 99, 0, 0, 0, 0, 1, 0, 0, 1]))
    with pytest.raises(P.FrameError, match=r"magic=b'JRT1', expected b'JRS1'"):
        P.Status.decode(P.Target(1, 1).encode())


@pytest.mark.parametrize(("kw", "message"), [
    ({"x": 3e6}, r"target frame: x=3000000.0 does not fit an int32 in thousandths"),
    ({"y": math.nan}, r"target frame: y=nan is not a finite number"),
    ({"speed": -1.0}, r"target frame: speed=-1.0 must not be negative"),
    ({"cond": 120}, r"target frame: cond=120 must be an integer in 0..99"),
    ({"seq": -1}, r"target frame: seq=-1 must be an integer in 0..2147483647"),
    ({"arm": 0}, r"target frame: arm=0 is not one of RIGHTY=1, LEFTY=-1"),
])
def test_encoding_refuses_what_the_point_job_cannot_hold(kw: dict, message: str) -> None:
    with pytest.raises(P.FrameError, match=message):
        P.Target(**{"seq": 1, "ack": 1, **kw}).encode()


@given(st.binary(max_size=40), st.lists(statuses, min_size=1, max_size=3), st.integers(1, 7))
def test_reader_resynchronises_after_garbage(junk: bytes, frames: list[P.Status], chunk: int) -> None:
    junk = junk.replace(b"J", b"j")  # no accidental magic inside the junk
    reader = P.FrameReader(P.STATUS_MAGIC)
    data = junk + b"".join(f.encode() for f in frames)
    got: list[P.Status] = []
    errors = 0
    for i in range(0, len(data), chunk):  # arrives in small pieces, as TCP may deliver it
        reader.feed(data[i:i + chunk])
        while (item := reader.next()) is not None:
            if isinstance(item, P.FrameError):
                errors += 1
                assert "without the magic" in str(item)
            else:
                got.append(P.Status.decode(item))
    assert got == frames
    assert (errors > 0) == (len(junk) > 0)


def test_reader_holds_at_most_its_capacity() -> None:
    reader = P.FrameReader(P.STATUS_MAGIC, capacity=100)
    reader.feed(bytes(150))
    assert reader.dropped == 50 and len(reader.buf) == 100
