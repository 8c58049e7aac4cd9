"""Controller alarms, as the embedded simulator reports them: forwarded to the servo process at once.

The J519 status carries no alarm code, so a real FANUC stop shows only as status bits; the embedded
simulator's alarm list supplies the code, with the backend's catalogue (cause, remedy). A monitor
thread polls it, whether or not anyone reads state, and forwards each new alarm fire-and-forget.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from typing import Any

from servo_app import messages as msg
from servo_app.backends import RobotBackend


class AlarmForwarder:
    def __init__(self, backend: RobotBackend, sim_call: Callable[..., Any], send: Callable[[msg.Request], None],
                 poll_s: float) -> None:
        self.backend = backend
        self._sim_call = sim_call
        self._send = send
        self._poll_s = poll_s
        self._seen = 0
        self._events: list[dict[str, Any]] = []
        self.faults: list[dict[str, Any]] = []  # every alarm (not warning) seen, and the service's own faults
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="sim-alarms", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def skip_past(self) -> None:
        """Alarms posted so far are not the next servo process's faults (it did not exist)."""
        with contextlib.suppress(TimeoutError, RuntimeError, OSError, EOFError), self._lock:
            self._seen = len(self._sim_call("events"))

    def record_fault(self, code: str, message: str) -> None:
        self.faults.append({"code": code, "message": message, "time_unix": time.time()})

    def _loop(self) -> None:
        while not self._stop.wait(self._poll_s):
            with contextlib.suppress(TimeoutError, RuntimeError, OSError, EOFError):
                self.forward()

    def forward(self) -> None:
        with self._lock:
            events = self._sim_call("events")
            for ev in events[self._seen:]:
                info = self.backend.alarm(ev["code"])
                if info is None or not info.warning:
                    self.faults.append(ev)
                # Fire-and-forget: this thread must not wait on the servo process; warnings go too.
                with contextlib.suppress(RuntimeError, OSError, TimeoutError):
                    self._send(msg.ControllerAlarm(code=ev["code"], message=ev["message"]))
            self._seen = len(events)
            self._events = events

    def alarms(self) -> list[dict[str, Any]]:
        """The last 20 alarms and warnings with their cause and remedy."""
        out = []
        for ev in self._events[-20:]:
            info = self.backend.alarm(ev["code"])
            out.append({**ev, "cause": info.cause if info else "", "remedy": info.remedy if info else "",
                        "warning": bool(info and info.warning)})
        return out
