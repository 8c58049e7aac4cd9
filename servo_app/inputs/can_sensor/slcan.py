"""python-can's slcan bus, reading whatever the adapter has sent at once.

The stock reader (python-can 4.6) takes one byte per ``read`` call and, with nothing to read, wakes
every millisecond (its serial timeout): a force/torque sensor at 1 kHz on a USB-CAN adapter is
then ~25,000 calls a second, each taking the GIL from the service's other threads. This one waits
in ``select`` for the port and reads everything waiting; the protocol handling stays python-can's.

A line that does not parse (a byte garbled on the wire, noise) raises :class:`FrameProblem` with its
bytes, and the port stays open. python-can's reader decoded every line as UTF-8 inside its "could not
read" guard, so one non-ASCII byte became a CanOperationError: the adapter took the sensor for
unplugged and reopened the port, its readings stale meanwhile (the arm stopped); a bad hex digit
escaped as a bare ValueError.
"""

from __future__ import annotations

import math
import select
import time

import can
from can.exceptions import error_check
from can.interfaces.slcan import slcanBus

from servo_app.inputs.can_sensor.decoders import FrameProblem

_TERMINATORS = (ord("\r"), ord("\a"))  # slcan ends every message (and every reply) with CR, errors with BEL
# The longest slcan line is a CAN FD frame's (D/B, 8-digit id, 64 data bytes, a time stamp): ~150 bytes.
# Bytes with no terminator past this are noise (a wrong baud rate): dropped, so they cannot grow the buffer.
MAX_LINE = 256


class SlcanBus(slcanBus):
    _line = b""  # the raw line being parsed, for a FrameProblem
    _overlong = b""  # bytes dropped for want of a terminator within MAX_LINE

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._line = self._overlong = b""
        try:
            got = super()._recv_internal(timeout)
        except (ValueError, IndexError) as exc:
            raise FrameProblem(f"slcan line {self._line!r} does not parse: {exc}", self._line) from None
        if self._overlong:
            raise FrameProblem(f"slcan: {len(self._overlong)} bytes with no line end (CR) within {MAX_LINE}: "
                               "dropped; check the adapter's serial speed", self._overlong)
        return got

    def _read(self, timeout: float | None) -> str | None:
        port = self.serialPortOrig
        try:
            fd = port.fileno()
        except (AttributeError, OSError, ValueError):  # not a file descriptor (e.g. a socket:// URL)
            return super()._read(timeout)
        deadline = math.inf if timeout is None else time.monotonic() + timeout
        with error_check("Could not read from serial device"):
            while True:
                line = self._take_message()
                if line is not None:
                    return line
                wait = deadline - time.monotonic()
                if wait <= 0.0 or not select.select([fd], [], [], None if math.isinf(wait) else wait)[0]:
                    return None
                self._buffer.extend(port.read(max(1, port.in_waiting)))

    def _take_message(self) -> str | None:
        end = next((i for i, b in enumerate(self._buffer) if b in _TERMINATORS), -1)
        if end < 0 and len(self._buffer) <= MAX_LINE:
            return None
        if end < 0 or end >= MAX_LINE:  # noise, ended or not: dropped whole (_recv_internal raises it)
            cut = len(self._buffer) if end < 0 else end + 1
            self._overlong = bytes(self._buffer[:cut])
            del self._buffer[:cut]
            return ""  # no message
        self._line = bytes(self._buffer[: end + 1])
        del self._buffer[: end + 1]
        return self._line.decode("latin-1")  # never fails: a non-ASCII line is refused by the parsing
