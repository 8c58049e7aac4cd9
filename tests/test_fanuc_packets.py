"""J519 packet codec: exact sizes and offsets, round trips, rejection of malformed datagrams."""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from servo_app.fanuc import packets as P

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
f32 = st.floats(width=32, allow_nan=False)
nine = st.lists(f32, min_size=9, max_size=9).map(tuple)
twenty = st.lists(f32, min_size=20, max_size=20).map(tuple)


def test_sizes_match_the_manual() -> None:
    assert P.STATUS_START_SIZE == 8
    assert P.STATUS_SIZE == 132
    assert P.COMMAND_SIZE == 64
    assert P.STATUS_STOP_SIZE == 8
    assert P.LIMIT_REQUEST_SIZE == 16
    assert P.LIMIT_RESPONSE_SIZE == 184


def test_start_and_stop_bytes() -> None:
    assert P.StatusStart().encode() == bytes.fromhex("0000000000000001")
    assert P.StatusStop().encode() == bytes.fromhex("0000000200000001")
    assert P.LimitTableRequest(3, 2).encode() == bytes.fromhex("00000003000000010000000300000002")


def test_command_field_offsets_big_endian() -> None:
    cmd = P.Command(seq=0x01020304, values=(1.0, -2.5), last_data=1, read_io_type=2, read_io_index=0x0A0B,
                    read_io_mask=0xFFFF, data_format=1, write_io_type=35, write_io_index=7, write_io_mask=3,
                    write_io_value=1)
    b = cmd.encode()
    assert b[0:4] == b"\x00\x00\x00\x01" and b[4:8] == b"\x00\x00\x00\x01"
    assert b[8:12] == b"\x01\x02\x03\x04"
    assert b[12] == 1 and b[13] == 2 and b[14:16] == b"\x0a\x0b" and b[16:18] == b"\xff\xff"
    assert b[18] == 1 and b[19] == 35 and b[20:22] == b"\x00\x07" and b[22:24] == b"\x00\x03"
    assert b[24:26] == b"\x00\x01" and b[26:28] == b"\x00\x00"
    assert struct.unpack(">f", b[28:32])[0] == 1.0 and struct.unpack(">f", b[32:36])[0] == -2.5
    assert b[36:64] == bytes(28)


def test_status_field_offsets() -> None:
    s = P.Status(seq=5, status=0b1101, read_io_type=1, read_io_index=2, read_io_mask=3, read_io_value=4,
                 timestamp_ms=1234, cartesian=(465.0,), joints=(0.0, 1.0), currents=(0.5,))
    b = s.encode()
    assert struct.unpack(">IIIBBHHHI", b[:24]) == (0, 1, 5, 0b1101, 1, 2, 3, 4, 1234)
    assert struct.unpack(">f", b[24:28])[0] == 465.0
    assert struct.unpack(">f", b[60 + 4:60 + 8])[0] == 1.0  # J2 at 24 + 36 + 4
    assert struct.unpack(">f", b[96:100])[0] == 0.5
    d = P.decode_from_robot(b)
    assert isinstance(d, P.Status) and d.waiting_for_command and not d.command_received and d.sysrdy and d.moving


@given(seq=u32, status=u8, rt=u8, ri=u16, rm=u16, rv=u16, ts=u32, cart=nine, joints=nine, cur=nine)
def test_status_round_trip(seq, status, rt, ri, rm, rv, ts, cart, joints, cur) -> None:
    s = P.Status(seq, status, rt, ri, rm, rv, ts, cart, joints, cur)
    assert P.decode_from_robot(s.encode()) == s


@given(seq=u32, values=nine, fmt=u8, last=u8, rt=u8, ri=u16, rm=u16, wt=u8, wi=u16, wm=u16, wv=u16)
def test_command_round_trip(seq, values, fmt, last, rt, ri, rm, wt, wi, wm, wv) -> None:
    c = P.Command(seq=seq, values=values, data_format=fmt, last_data=last, read_io_type=rt, read_io_index=ri,
                  read_io_mask=rm, write_io_type=wt, write_io_index=wi, write_io_mask=wm, write_io_value=wv)
    assert P.decode_from_pc(c.encode()) == c


@given(axis=u32, lt=u32, vmax=u32, check=u32, no=twenty, mx=twenty)
def test_limit_table_round_trip(axis, lt, vmax, check, no, mx) -> None:
    r = P.LimitTableResponse(axis, lt, vmax, check, no, mx)
    assert P.decode_from_robot(r.encode()) == r
    q = P.LimitTableRequest(axis, lt)
    assert P.decode_from_pc(q.encode()) == q


def test_start_stop_decode() -> None:
    assert P.decode_from_pc(P.StatusStart().encode()) == P.StatusStart()
    assert P.decode_from_pc(P.StatusStop().encode()) == P.StatusStop()


def test_nan_survives_the_wire_and_is_located() -> None:
    c = P.Command(seq=1, values=(0.0, 0.0, math.nan, math.inf))
    d = P.decode_from_pc(c.encode())
    assert isinstance(d, P.Command) and d.non_finite_axis() == 3


def test_sequence_wraps() -> None:
    assert P.next_seq(0xFFFFFFFF) == 0
    assert P.next_seq(7) == 8
    assert P.seq_diff(0, 0xFFFFFFFF) == 1
    assert P.seq_diff(0xFFFFFFFF, 0) == -1


@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        (b"\x00\x00", "length=2"),
        (P.Status(seq=1).encode()[:-1], "length=131"),
        (b"\x00\x00\x00\x07\x00\x00\x00\x01", "packet_type=7"),
        (b"\x00\x00\x00\x01" + b"\x00\x00\x00\x01" + bytes(56), "packet_type=1"),
        (b"\x00\x00\x00\x00\x00\x00\x00\x02" + bytes(124), "version=2"),
    ],
)
def test_decode_from_robot_rejects(data: bytes, fragment: str) -> None:
    with pytest.raises(P.PacketError, match=fragment.replace("=", "=")):
        P.decode_from_robot(data)


@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        (b"\x00\x00\x00\x01\x00\x00\x00\x01" + bytes(50), "length=58"),
        (b"\x00\x00\x00\x09\x00\x00\x00\x01", "packet_type=9"),
        (b"\x00\x00\x00\x00\x00\x00\x00\x03", "version=3"),
    ],
)
def test_decode_from_pc_rejects(data: bytes, fragment: str) -> None:
    with pytest.raises(P.PacketError, match=fragment):
        P.decode_from_pc(data)


def test_decode_from_pc_any_version_for_the_simulator() -> None:
    d = P.decode_from_pc(b"\x00\x00\x00\x00\x00\x00\x00\x03", version=None)
    assert isinstance(d, P.StatusStart) and d.version == 3


@pytest.mark.parametrize("field", ["seq", "last_data", "write_io_value"])
def test_encode_rejects_out_of_range_fields(field: str) -> None:
    kwargs = {"seq": 1, "values": (0.0,), field: -1}
    with pytest.raises(P.PacketError, match=f"{field}=-1"):
        P.Command(**kwargs).encode()


def test_encode_rejects_too_many_values() -> None:
    with pytest.raises(P.PacketError, match="values has 10"):
        P.Command(seq=1, values=(0.0,) * 10).encode()


def _encode_or_error(make: Any) -> bytes | str:
    try:
        return make()
    except P.PacketError as exc:
        return f"PacketError: {exc}"


# Fields that go over their range now and then (and below zero): either both ways pack the same bytes,
# or both raise the same PacketError naming the field.
wide8, wide16, wide32 = (st.integers(-2, top + 2) | st.sampled_from([0, top]) for top in (255, 65535, 2**32 - 1))


@given(seq=wide32, values=st.lists(st.floats(width=32), max_size=10), fmt=wide8, last=wide8, rt=wide8,
       ri=wide16, rm=wide16, wt=wide8, wi=wide16, wm=wide16, wv=wide16)
def test_pack_command_is_command_encode(seq, values, fmt, last, rt, ri, rm, wt, wi, wm, wv) -> None:
    fast = _encode_or_error(lambda: P.pack_command(seq, values, fmt, last, (rt, ri, rm), (wt, wi, wm, wv)))
    plain = _encode_or_error(lambda: P.Command(
        seq=seq, values=tuple(values), data_format=fmt, last_data=last, read_io_type=rt, read_io_index=ri,
        read_io_mask=rm, write_io_type=wt, write_io_index=wi, write_io_mask=wm, write_io_value=wv).encode())
    assert fast == plain
