"""python-can's slcan bus, reading whatever the adapter has sent at once.

The stock reader (python-can 4.6) takes one byte per ``read`` call and, with nothing to read, wakes
every millisecond (its serial timeout): a force/torque sensor at 1 kHz on a USB-CAN adapter is
then ~25,000 calls a second, each taking the GIL from the service's other threads. This one waits
in ``select`` for the port and reads everything waiting; the protocol handling stays python-can's.
"""

from __future__ import annotations

import math
import select
import time

from can.exceptions import error_check
from can.interfaces.slcan import slcanBus

_TERMINATORS = (ord("\r"), ord("\a"))  # slcan ends every message (and every reply) with CR, errors with BEL


class SlcanBus(slcanBus):
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
        if end < 0:
            return None
        message = self._buffer[: end + 1].decode()
        del self._buffer[: end + 1]
        return message
