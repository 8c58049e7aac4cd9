"""Controller alarms: forwarded to the servo process at once, kept as active alarms and a history.

The J519 status carries no alarm code, so a real FANUC stop shows only as status bits; the embedded
simulator's alarm list supplies the code, with the backend's catalogue (cause, remedy). A monitor
thread polls it, whether or not anyone reads state, and forwards each new alarm fire-and-forget.
Janome's robot reports its errors over the link: they reach us as the servo process's fault with a
``JNM-nnn`` code, and are listed the same way.

Two lists (the API's ``alarms`` and ``alarm_history``): the active alarms and warnings, since the
last reset or the last new stream, and the last 50 of them, kept across resets. Each carries the
wall-clock time the service saw it and the controller's own time stamp (FANUC: the status packets'
clock at the alarm; null when the controller has none).

The forwarder also watches the servo process's safety view (``attach``): leaving ``fault`` (a
reset) or starting a new stream clears the active list, and each fault is counted by its cause
for ``/metrics``, as are the alarms by code.

The monitor thread outlives any poll: a simulator that does not answer in time (its process stopped
or starved), or answers something unexpected, costs that one poll. It is counted
(``poll_failures``, ``poll_error``), logged once when the polls start failing and once when they
succeed again, and the next poll comes as usual.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from servo_app import messages as msg
from servo_app.backends import RobotBackend

log = logging.getLogger(__name__)

HISTORY_LEN = 50
FAULTS_KEPT = 100
FAULT_GRACE_S = 1.0  # for the controller's alarm to name a fault we detected first (a 50 ms poll, under load)
# A new stream starts from one of these modes; stopped -> streaming is a resume (the alarms stay).
_IDLE_MODES = frozenset({None, "disconnected", "connected", "ready", "ended"})


def fault_cause(fault: dict[str, Any]) -> str:
    """A fault's cause as a short, bounded label (Prometheus): the controller's alarm code, else the
    kind of our own detection (the messages carry numbers and reasons, too many to be labels)."""
    if fault.get("code"):
        return str(fault["code"])
    text = str(fault.get("message") or "").lower()
    for words, label in (("servo process", "servo_process"), ("sysrdy", "sysrdy_off"),
                         ("status bit 0", "controller_stopped"), ("restarted its status", "status_restarted"),
                         ("connection lost", "connection_lost"), ("lost", "status_lost"),
                         ("no status", "status_lost"), ("not ready", "not_ready"), ("malformed", "protocol")):
        if words in text:
            return label
    return "other"


class AlarmForwarder:
    def __init__(self, backend: RobotBackend, sim_call: Callable[..., Any], send: Callable[[msg.Request], None],
                 poll_s: float) -> None:
        self.backend = backend
        self._sim_call = sim_call
        self._send = send
        self._poll_s = poll_s
        self._seen = 0
        self._active: list[dict[str, Any]] = []
        self._history: deque[dict[str, Any]] = deque(maxlen=HISTORY_LEN)
        self.faults: list[dict[str, Any]] = []  # every alarm (not warning) seen, and the service's own faults
        self.alarm_counts: Counter[str] = Counter()  # alarms and warnings by code, since the service started
        self.fault_counts: Counter[str] = Counter()  # faults by cause (fault_cause)
        self._safety: Callable[[], dict[str, Any]] = dict
        self._servo_fault: Callable[[], dict[str, Any] | None] = lambda: None
        self._status_time: Callable[[], int | None] = lambda: None
        self._mode: str | None = None
        self._in_fault = False
        self._fault_pending: dict[str, Any] | None = None  # a fault whose cause is not counted yet
        self._fault_since = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.RLock()  # the lists; never held across a call to the simulator
        self._poll_lock = threading.Lock()  # one reader of the simulator's alarm list at a time
        self.poll_failures = 0  # polls of the alarm list that failed (no answer in time, a bad answer)
        self.poll_error = ""  # the last one's reason ("" once a poll succeeds again)

    def attach(self, safety: Callable[[], dict[str, Any]], servo_fault: Callable[[], dict[str, Any] | None],
               status_time_ms: Callable[[], int | None]) -> None:
        """Where to watch the servo process: its safety view, the service's record of its death, and
        the controller's time stamp of the last status (for faults the controller gives no time of)."""
        self._safety, self._servo_fault, self._status_time = safety, servo_fault, status_time_ms

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
        """Alarms posted so far are not the next servo process's faults (it did not exist): they are
        listed (the old process's end left them), but not forwarded."""
        with contextlib.suppress(TimeoutError, RuntimeError, OSError, EOFError, TypeError), self._poll_lock:
            events = self._events()
            with self._lock:
                for ev in events[self._seen:]:
                    self._add(ev)
                self._seen = len(events)

    def record_fault(self, code: str, message: str) -> None:
        """The service's own fault (the servo process died)."""
        with self._lock:
            self._fault({"code": code, "message": message, "time_unix": time.time()})
            self.fault_counts[fault_cause({"message": message})] += 1

    def service_warning(self, code: str, message: str, cause: str, remedy: str) -> None:
        """A warning of the service's own (no controller posted it): listed as active and in the
        history, counted by code for /metrics, like the controller's warnings."""
        with self._lock:
            item = {"code": code, "message": message, "cause": cause, "remedy": remedy, "warning": True,
                    "time_unix": time.time(), "controller_time_ms": None}
            self._active.append(item)
            self._history.append(item)
            self.alarm_counts[code] += 1

    def clear_active(self) -> None:
        """A reset: the active alarms are gone (the history keeps them)."""
        with self._lock:
            self._active = []

    @property
    def alive(self) -> bool:
        """The monitor thread is running."""
        return self._thread is not None and self._thread.is_alive()

    def _loop(self) -> None:
        while not self._stop.wait(self._poll_s):
            try:
                self.forward()
            except RuntimeError:
                pass  # no embedded simulator (an external robot: nothing to poll), or a refusal
            except Exception as exc:  # whatever one poll met, the next one comes
                self._poll_failed(exc)
            else:
                if self.poll_error:
                    log.warning("sim-alarms: the controller's alarm list answers again (%d polls failed)",
                                self.poll_failures)
                    self.poll_error = ""

    def _poll_failed(self, exc: Exception) -> None:
        first = not self.poll_error
        self.poll_failures += 1
        self.poll_error = f"{type(exc).__name__}: {exc}"
        if first:  # once per run of failures, not every poll
            log.warning("sim-alarms: reading the controller's alarm list failed (%s); polling on",
                        self.poll_error, exc_info=not isinstance(exc, (TimeoutError, OSError, EOFError)))

    def _events(self) -> list[dict[str, Any]]:
        """The simulator's alarm list, all of it; TypeError if the answer is not one."""
        events = self._sim_call("events")
        if not isinstance(events, list) or not all(isinstance(e, dict) and "code" in e for e in events):
            raise TypeError(f"the simulator's alarm list is not a list of alarms: {events!r:.120}")
        return events

    def forward(self) -> None:
        with self._poll_lock:
            self.observe()  # a reset or a new stream first: the alarms seen now belong to what follows
            events = self._events()
            with self._lock:
                new = [self._add(ev) for ev in events[self._seen:]]
                self._seen = len(events)
            for item in new:
                # Fire-and-forget: this thread must not wait on the servo process; warnings go too.
                with contextlib.suppress(RuntimeError, OSError, TimeoutError):
                    self._send(msg.ControllerAlarm(code=item["code"], message=item["message"]))

    def _fault(self, item: dict[str, Any]) -> None:
        self.faults.append(item)
        del self.faults[:-FAULTS_KEPT]

    def _add(self, ev: dict[str, Any], controller_time_ms: int | None = None) -> dict[str, Any]:
        """One alarm or warning the controller posted: listed as active and in the history, counted."""
        info = self.backend.alarm(ev["code"])
        item = {**ev, "cause": ev.get("cause") or (info.cause if info else ""),
                "remedy": ev.get("remedy") or (info.remedy if info else ""),
                "warning": bool(info and info.warning), "time_unix": time.time(),
                "controller_time_ms": ev.get("controller_time_ms", controller_time_ms)}
        self._active.append(item)
        self._history.append(item)
        self.alarm_counts[item["code"]] += 1
        if not item["warning"]:
            self._fault(item)
        return item

    def observe(self) -> None:
        """Follow the servo process's safety view: a reset (leaving fault) or a new stream clears the
        active alarms; a fault is counted by cause once, and one carrying a code the controller did
        not post here (Janome's robot reports its errors over the link) is listed as an alarm."""
        with self._lock:
            safety = self._safety() or {}
            dead = self._servo_fault() is not None
            mode = "fault" if dead else safety.get("state")
            prev, self._mode = self._mode, mode
            if (prev == "fault" and mode != "fault") or (mode == "streaming" and prev in _IDLE_MODES):
                self._active = []
            fault = None if dead else safety.get("fault")
            if fault is None:
                if self._fault_pending is not None:  # left before its grace ran out: counted as it was
                    self._count_fault(self._fault_pending)
                self._fault_pending = None
                self._in_fault = dead  # a dead process's fault is counted by record_fault
                return
            if not self._in_fault:
                self._in_fault = True
                self._fault_pending, self._fault_since = fault, time.monotonic()
            if self._fault_pending is not None:
                self._fault_pending = fault
                # Our own detection (status bit 0 fell) often comes just before the controller's alarm
                # that explains it: wait a moment for the code before counting the cause.
                if fault.get("code") or time.monotonic() - self._fault_since >= FAULT_GRACE_S:
                    self._count_fault(fault)
                    self._fault_pending = None
            code = fault.get("code")
            if code and not any(a["code"] == code for a in self._active):
                self._add({"code": code, "message": fault.get("message") or code, "cause": fault.get("cause"),
                           "remedy": fault.get("remedy")}, self._status_time())

    def _count_fault(self, fault: dict[str, Any]) -> None:
        self.fault_counts[fault_cause(fault)] += 1
        if fault.get("code") is None:  # a coded one is listed with the controller's alarm
            # Our own detection has no controller code: the list names its cause instead.
            self._fault({**fault, "code": fault_cause(fault), "time_unix": time.time(),
                         "controller_time_ms": self._status_time()})

    def alarms(self) -> list[dict[str, Any]]:
        """The active alarms and warnings, oldest first: since the last reset or new stream."""
        with self._lock:
            self.observe()
            return list(self._active)

    def history(self) -> list[dict[str, Any]]:
        """The last 50 alarms and warnings, oldest first, across resets."""
        with self._lock:
            return list(self._history)

    def counts(self) -> tuple[dict[str, int], dict[str, int]]:
        """Alarms by code and faults by cause, since the service started (for /metrics)."""
        with self._lock:
            self.observe()
            return dict(self.alarm_counts), dict(self.fault_counts)
