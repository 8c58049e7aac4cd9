"""The servo process's usual log write (a status and the one command that answered it) packs the same
bytes as the two records made one by one."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.session_log import RECORD_SIZE, command_record, pack_status_and_command, status_record

f32 = st.floats(-1e6, 1e6, width=32)
u32 = st.integers(0, 2**32 - 1)


@settings(max_examples=300, deadline=None)
@given(t_status=st.floats(0, 1e6), seq=u32, bits=st.integers(0, 255), io=st.integers(0, 0xFFFF),
       joints=st.lists(f32, min_size=0, max_size=9), t=st.floats(0, 1e6), command_seq=u32,
       last_data=st.integers(0, 1), data_format=st.integers(0, 1), command_io=st.integers(0, 0xFFFF),
       latency_us=st.floats(0, 1e5, width=32), values=st.lists(f32, min_size=0, max_size=9))
def test_the_pair_is_the_two_records(t_status: float, seq: int, bits: int, io: int, joints: list[float], t: float,
                                     command_seq: int, last_data: int, data_format: int, command_io: int,
                                     latency_us: float, values: list[float]) -> None:
    buf = bytearray(2 * RECORD_SIZE)
    pack_status_and_command(buf, t_status, seq, bits, io, tuple(joints), t, command_seq, last_data, data_format,
                            command_io, latency_us, values)
    want = (status_record(t_status, seq, bits, io, tuple(joints))
            + command_record(t, command_seq, last_data, data_format, command_io, latency_us, values))
    assert bytes(buf) == want
