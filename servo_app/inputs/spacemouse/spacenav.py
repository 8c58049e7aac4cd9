"""Client side of the spacenavd daemon's UNIX socket protocol.

Each event is 8 native-endian int32: the type (0 motion, 1 button press, 2 button release), then for
motion x y z rx ry rz and the period in ms since the previous motion event, for buttons the button
number. The daemon sends a motion event when the values change (a zero event on release) and
nothing while the cap rests. A client that does not send a request is served this plain protocol.
"""

from __future__ import annotations

import socket
import struct
from dataclasses import dataclass

DEFAULT_SOCKET = "/var/run/spnav.sock"
EVENT = struct.Struct("=8i")
MOTION, PRESS, RELEASE = 0, 1, 2


class MalformedEvent(ValueError):
    def __init__(self, message: str, data: bytes) -> None:
        super().__init__(message)
        self.data = data


@dataclass(frozen=True, slots=True)
class MotionEvent:
    translation: tuple[int, int, int]
    rotation: tuple[int, int, int]
    period_ms: int


@dataclass(frozen=True, slots=True)
class ButtonChange:
    button: int
    pressed: bool


def decode_event(data: bytes) -> MotionEvent | ButtonChange:
    if len(data) != EVENT.size:
        raise MalformedEvent(f"event of {len(data)} bytes, expected {EVENT.size}", data)
    v = EVENT.unpack(data)
    if v[0] == MOTION:
        return MotionEvent(v[1:4], v[4:7], v[7])
    if v[0] in (PRESS, RELEASE):
        if v[1] < 0:
            raise MalformedEvent(f"negative button number {v[1]}", data)
        return ButtonChange(v[1], v[0] == PRESS)
    raise MalformedEvent(f"unknown event type {v[0]}", data)


def encode_motion(translation: tuple[int, int, int], rotation: tuple[int, int, int], period_ms: int = 8) -> bytes:
    return EVENT.pack(MOTION, *translation, *rotation, period_ms)


def encode_button(button: int, pressed: bool) -> bytes:
    return EVENT.pack(PRESS if pressed else RELEASE, button, 0, 0, 0, 0, 0, 0)


class SpnavClient:
    """Connects to the daemon and returns whole events; partial reads are kept for the next call."""

    def __init__(self, path: str = DEFAULT_SOCKET) -> None:
        self.path = path
        self._sock: socket.socket | None = None
        self._buf = bytearray()

    def connect(self, timeout_s: float = 1.0) -> None:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(timeout_s)
        try:
            s.connect(self.path)
        except OSError:
            s.close()
            raise
        self._sock = s
        self._buf.clear()

    def close(self) -> None:
        s, self._sock = self._sock, None
        if s is not None:
            s.close()

    def receive(self, timeout_s: float) -> list[bytes]:
        """Whole 32-byte events received within timeout_s (maybe none); raises OSError when the daemon hangs up."""
        if self._sock is None:
            raise ConnectionError("not connected")
        self._sock.settimeout(timeout_s)
        try:
            chunk = self._sock.recv(4096)
        except TimeoutError:
            return []
        if not chunk:
            raise ConnectionResetError("spacenavd closed the connection")
        self._buf.extend(chunk)
        # Take whatever else is already there without waiting, so we see the newest state.
        self._sock.setblocking(False)
        try:
            while chunk:
                try:
                    chunk = self._sock.recv(4096)
                except BlockingIOError:
                    break
                self._buf.extend(chunk)
        finally:
            self._sock.setblocking(True)
        n = len(self._buf) // EVENT.size * EVENT.size
        events = [bytes(self._buf[i:i + EVENT.size]) for i in range(0, n, EVENT.size)]
        del self._buf[:n]
        return events
