"""The servo process's end of its pipe to the parent, framed as ``multiprocessing.connection`` frames it.

The parent keeps its ``Connection`` (a reader thread, requests from any thread); the child reads and
writes the same frames on the same socket itself: a big-endian ``i32`` length, then the payload
(a length of -1: a ``u64`` length follows, for payloads above 2 GiB). Why: ``Connection.recv`` reads
a frame in two system calls through a dozen Python calls (``io.BytesIO`` per read), and
``send_bytes`` in six. A jog renewal (20 a second) cost the servo process ~156 us here with caches
cold, ~84 of them reading the request and sending the reply; this way ~63 (one run each of
bench/servo_loop.py's harness, timing those two steps). Here a read is one ``os.read`` of whatever
has arrived, split into whole frames (a frame cut short waits in a buffer for the rest: the next
read never blocks on it), and a write one ``os.write``.

:func:`split_frames` is the codec alone (no I/O): tested against ``Connection``'s own frames.
"""

from __future__ import annotations

import os
import struct
from multiprocessing.connection import Connection

_LEN = struct.Struct("!i")
_LEN64 = struct.Struct("!Q")
_READ_SIZE = 1 << 16  # one read takes what a burst of requests left, a frame above it comes in parts


def frame(payload: bytes) -> bytes:
    """``payload`` as one frame (``Connection.send_bytes``' header, then the payload)."""
    n = len(payload)
    if n > 0x7FFFFFFF:
        return _LEN.pack(-1) + _LEN64.pack(n) + payload
    return _LEN.pack(n) + payload


def split_frames(buf: bytearray) -> list[bytes]:
    """The whole frames at the start of ``buf``, removed from it (a frame cut short stays). A negative
    length other than -1 is no frame of ``Connection``'s: ValueError."""
    frames = []
    at, n = 0, len(buf)
    while n - at >= _LEN.size:
        (size,) = _LEN.unpack_from(buf, at)
        head = _LEN.size
        if size == -1:
            if n - at < _LEN.size + _LEN64.size:
                break
            (size,) = _LEN64.unpack_from(buf, at + _LEN.size)
            head += _LEN64.size
        elif size < 0:
            raise ValueError(f"pipe frame length {size} at byte {at}: not a multiprocessing frame")
        if n - at - head < size:
            break
        frames.append(bytes(buf[at + head: at + head + size]))
        at += head + size
    del buf[:at]
    return frames


class PipeEnd:
    """The child's side of ``conn`` (which keeps owning, and closes, the socket): :meth:`read` the
    frames that have arrived, :meth:`write` one. Never mixed with ``conn.recv``: bytes read ahead
    wait here."""

    def __init__(self, conn: Connection) -> None:
        self.fd = conn.fileno()
        self._pending = bytearray()

    def read(self) -> list[bytes]:
        """The whole frames that have arrived, from one ``os.read`` (call it when the socket is readable:
        it blocks otherwise). EOFError once the other end has closed and nothing whole is left."""
        data = os.read(self.fd, _READ_SIZE)
        if not data:
            raise EOFError("the pipe's other end is closed")
        if not self._pending and len(data) >= _LEN.size and _LEN.unpack_from(data)[0] == len(data) - _LEN.size:
            return [data[_LEN.size:]]  # the usual read: one whole request
        self._pending += data
        return split_frames(self._pending)

    def write(self, payload: bytes) -> None:
        """One frame, whole: ``os.write`` again for what a signal's interruption left unwritten."""
        view = memoryview(frame(payload))
        while view:
            view = view[os.write(self.fd, view):]
