"""The servo process's own pipe framing against multiprocessing's ``Connection`` on a real pipe: what
``send_bytes`` sends, ``PipeEnd.read`` returns, however the bytes arrive; what ``PipeEnd.write`` sends,
``recv_bytes`` returns."""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import select

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app import messages as msg
from servo_app.pipe_frames import PipeEnd, frame, split_frames

payloads = st.lists(st.binary(max_size=300), max_size=12)


def _raw(conn: mp.connection.Connection, n: int) -> bytes:
    """``n`` bytes exactly as they arrived on ``conn``'s socket."""
    out = b""
    while len(out) < n:
        out += os.read(conn.fileno(), n - len(out))
    return out


@settings(max_examples=60, deadline=None)
@given(payloads, st.lists(st.integers(1, 64), min_size=1, max_size=40))
def test_split_frames_returns_connections_frames_however_cut(items: list[bytes], cuts: list[int]) -> None:
    a, b = mp.Pipe()
    with a, b:
        for p in items:
            a.send_bytes(p)
        wire = _raw(b, sum(4 + len(p) for p in items))
    assert wire == b"".join(frame(p) for p in items)  # the same header as Connection's
    buf, got, at, k = bytearray(), [], 0, 0
    while at < len(wire):
        step = cuts[k % len(cuts)]
        k += 1
        buf += wire[at: at + step]
        at += step
        got += split_frames(buf)
    assert got == items and not buf


def test_a_long_frame_header_and_a_bad_length() -> None:
    buf = bytearray(frame(b"x" * 5)[:3])
    assert split_frames(buf) == [] and len(buf) == 3  # a header cut short waits
    buf = bytearray(b"\xff\xff\xff\xff" + (7).to_bytes(8, "big") + b"1234567" + b"\x00\x00")
    assert split_frames(buf) == [b"1234567"] and buf == b"\x00\x00"  # the -1 + u64 form
    with pytest.raises(ValueError, match="frame length -2"):
        split_frames(bytearray(b"\xff\xff\xff\xfe"))


@settings(max_examples=30, deadline=None)
@given(payloads)
def test_pipe_end_reads_what_send_bytes_sent_and_recv_bytes_reads_its_writes(items: list[bytes]) -> None:
    parent, child = mp.Pipe()
    with parent, child:
        end = PipeEnd(child)
        for p in items:
            parent.send_bytes(p)
        got: list[bytes] = []
        while len(got) < len(items):
            assert select.select([child], [], [], 5.0)[0], f"frames missing: {len(got)} of {len(items)}"
            got += [bytes(f) for f in end.read()]
        assert got == items
        for p in items:
            end.write(p)
        assert [parent.recv_bytes() for _ in items] == items
        assert not parent.poll(0)


def test_a_request_goes_through_whole_and_a_closed_parent_is_end_of_file() -> None:
    parent, child = mp.Pipe()
    end = PipeEnd(child)
    env = msg.Envelope(7, msg.Twist(linear=(40.0, 0.0, 0.0)))
    parent.send(env)
    big = msg.Envelope(8, msg.Twist(linear=(0.0, 1.0, 0.0), source="s" * 200_000))
    parent.send(big)  # ~200 kB: several reads, a frame cut short between them
    got: list[object] = []
    while len(got) < 2:
        assert select.select([child], [], [], 5.0)[0]
        got += [pickle.loads(f) for f in end.read()]
    assert got == [env, big]
    end.write(pickle.dumps(msg.Reply(7, True)))
    assert parent.recv() == msg.Reply(7, True)
    parent.close()
    assert select.select([child], [], [], 5.0)[0]
    with pytest.raises(EOFError):
        end.read()
    child.close()


def test_a_big_request_is_read_over_several_passes_of_the_servo_loop() -> None:
    """The servo process's request poll reads at most READS_PER_PASS times a pass: a request of
    megabytes (a long trajectory's plan) arrives over several passes, the statuses between them
    answered (read whole in one pass, 9.5 MB held a 4 ms cycle up ~17 ms: MOTN-603)."""
    import threading

    from servo_app.process_handle import READS_PER_PASS, ServoProcessHost

    class Host(ServoProcessHost):
        def __init__(self, conn: mp.connection.Connection) -> None:  # only the pipe's part
            self.pipe, self.parent_gone = PipeEnd(conn), False
            self._pipe_poll = select.poll()
            self._pipe_poll.register(conn.fileno(), select.POLLIN)
            self.handled: list[msg.Envelope] = []

        def _handle(self, env: msg.Envelope) -> None:
            self.handled.append(env)

    parent, child = mp.Pipe()
    with parent, child:
        host = Host(child)
        big = msg.Envelope(9, msg.Twist(linear=(0.0, 0.0, 0.0), source="s" * (4 * READS_PER_PASS << 16)))
        sender = threading.Thread(target=parent.send, args=(big,))  # (~4 passes' worth)
        sender.start()
        passes = 0
        while not host.handled:
            assert select.select([child], [], [], 5.0)[0] and passes < 100, passes
            host._poll_requests()
            passes += 1
        sender.join(5.0)
        assert host.handled == [big] and passes >= 4, passes
        small = [msg.Envelope(i, msg.Twist(linear=(float(i), 0.0, 0.0))) for i in range(3)]
        for env in small:  # the usual requests: one read each, all in one pass
            parent.send(env)
        host.handled.clear()
        while len(host.handled) < 3:
            assert select.select([child], [], [], 5.0)[0]
            host._poll_requests()
        assert host.handled == small

