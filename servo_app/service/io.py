"""I/O through the stream: reads and writes ride on command packets, values come back in status.

The backend's rules say what may be accessed (FANUC: 16-point windows within the assigned points,
else the controller posts PRIO-023); a refused access is an InvalidRequest (422) before anything is
sent. A read is answered by a later status packet: ``lead`` commands are queued ahead of it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from servo_app import messages as msg
from servo_app.backends import RobotBackend
from servo_app.errors import CommandRejected
from servo_app.inputs.actions import OutputToggle


class StreamIo:
    def __init__(self, backend: RobotBackend, request: Callable[[msg.Request], Any],
                 state: Callable[[], dict[str, Any]], lead: int) -> None:
        self.backend = backend
        self._request = request
        self._state = state
        self._lead = lead
        self._read_lock = threading.Lock()

    def write(self, io_type: str, index: int, mask: int, value: int) -> str:
        """Write with the next command packet; returns the type's canonical name (``do`` -> ``DO``)."""
        name = self.backend.check_io(io_type, index)
        self._request(msg.IoWrite(type=name, index=index, mask=mask, value=value))
        return name

    def read(self, io_type: str, index: int, mask: int = 0xFFFF, timeout: float = 1.0) -> int:
        """Read 16 points through the command packets: the value comes back in a later status packet."""
        name = self.backend.check_io(io_type, index)
        if self._state()["link"] != "streaming":
            raise CommandRejected("I/O is read through command packets: only while streaming; "
                                  "start a session first: POST /api/session/start")
        deadline = time.monotonic() + timeout
        # One read at a time: a command packet carries one read (the last asked for), so a second read
        # asked meanwhile replaced the first on the wire and the first never came back (503).
        if not self._read_lock.acquire(timeout=timeout):
            raise TimeoutError(f"the read of {name}[{index}] waited {timeout} s behind other reads; read again")
        try:
            pending = self._request(msg.IoRead(type=name, index=index, mask=mask))
            seq0 = self._state()["status_seq"]  # published just before the reply: the request's cycle
            # The read rides on the next command sent; with `lead` commands queued ahead, the controller
            # processes it lead + 1 statuses later. Writes queued before it go out one per command, so
            # its value is taken after those too (the servo process answers how many were waiting).
            delay = self.backend.io_read_delay(self._lead) + (pending if isinstance(pending, int) else 0)
            type_code = self.backend.io_type_code(name)
            want = (type_code, index, mask)
            while time.monotonic() < deadline:
                s = self._state()
                if s["link"] != "streaming":
                    raise CommandRejected(f"the stream stopped ({s['state']}) before the read came back; read "
                                          "again once a session streams: POST /api/session/start")
                echo = (s["io_read_type"], s["io_read_index"], s["io_read_mask"])
                if echo == want and s["status_seq"] - seq0 >= delay:
                    return int(s["io_read_value"])
                time.sleep(0.002)  # status packets come every 4-8 ms: poll the shared-memory state
        finally:
            self._read_lock.release()
        raise TimeoutError(f"no status packet echoed the read of {name}[{index}] within {timeout} s")

    def toggle(self, io_type: str, point: int) -> int:
        """Flip one output point (a device button's gripper): read it, then write it inverted; returns
        the new value."""
        index, bit = self.backend.io_window(io_type, point)
        new = (self.read(io_type, index, bit) & bit) ^ bit
        self.write(io_type, index, bit, new)
        return int(bool(new))

    def on_action(self, action: OutputToggle) -> int:
        return self.toggle(action.io_type, action.point)
