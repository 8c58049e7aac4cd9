"""What the API shows: the state (the servo process's published vector plus its safety view and
the service's own facts), the limits, the robot's drawing, the session logs."""

from __future__ import annotations

import threading
import time
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

from servo_app import messages as msg
from servo_app.motion.diffik import holding_back

if TYPE_CHECKING:
    from servo_app.service.core import ServoService


# Link phases in which the controller sends status; in any other the last status bits are history.
LIVE_LINKS = frozenset({"fetching_tables", "connected", "waiting_ready", "streaming", "ending"})
# A status older than this is not live whatever the phase says (FANUC: every 2-8 ms; Janome: after
# each move and every ~0.05-0.1 s while it holds; both links fault on far shorter silences).
STATUS_STALE_S = 2.0
# Warnings whose wall clock is remembered: more than the servo process lists (its last 20).
WARNINGS_STAMPED = 100


def consistent(s: dict[str, Any], now: float) -> dict[str, Any]:
    """Make the view agree with itself (the console once showed READY beside "link fault"): status
    bits are reported only while status packets arrive (``status_live``; the last ones stay in
    ``status_bits_last``, ``status_age_s`` old), and with the link faulted, a state that rests on the
    controller's status (connected, ready) reads disconnected: the next start opens the link afresh."""
    t = s.get("status_unix") or 0.0
    age = max(0.0, now - t) if t > 0 else None
    live = s.get("link") in LIVE_LINKS and age is not None and age < STATUS_STALE_S
    s["status_age_s"] = age
    s["status_live"] = live
    s["status_bits_last"] = s.get("status_bits")
    if not live:
        s["status_bits"] = None
    if s.get("link") == "fault" and s.get("state") in ("connected", "ready"):
        s["state"] = "disconnected"
    return s


class StateViews:
    def __init__(self, service: ServoService) -> None:
        self.service = service
        self._warning_unix: dict[float, float] = {}  # a warning's servo clock ``t`` -> its wall clock
        self._warning_lock = threading.Lock()
        # The forwarder follows the servo process's safety view (resets, new streams, faults).
        service.alarm_forwarder.attach(lambda: service.safety, lambda: service.servo_fault, self._status_time_ms)

    def _published(self) -> dict[str, Any] | None:
        """The servo process's published state; None without one, or while a reset replaces a dead
        process (its handle's slot is closed before the new handle takes its place: reading it
        raised AttributeError, a 500 on /api/state)."""
        stream = self.service.stream
        if stream is None:
            return None
        try:
            return stream.state()
        except (AttributeError, BufferError, ValueError, OSError):
            return None

    def _status_time_ms(self) -> int | None:
        """The controller's time stamp of the last status (None: none, or it has no clock)."""
        t = (self._published() or {}).get("status_time_ms")
        return None if t is None else int(t)

    def _with_wall_clock(self, warnings: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """The servo process's warnings, each with ``time_unix``: its ``t`` is that process's monotonic
        clock, which this process shares (one host), so the console can order them among the
        controller's alarms (stamped ``time_unix``) and say when they happened. Worked out once per
        warning, so that every read gives the same; copies (the safety view is shared)."""
        offset = time.time() - time.monotonic()
        out: list[dict[str, Any]] = []
        with self._warning_lock:
            for w in warnings:
                t = w.get("t")
                if isinstance(t, (int, float)):
                    w = {**w, "time_unix": self._warning_unix.setdefault(t, t + offset)}
                out.append(w)
            while len(self._warning_unix) > WARNINGS_STAMPED:  # the oldest first (insertion order)
                del self._warning_unix[next(iter(self._warning_unix))]
        return out

    def _no_process(self) -> dict[str, Any]:
        svc = self.service
        if svc.stream is None:
            return {"state": "disconnected", "link": "idle"}
        # Being replaced: the old one's fault stands until the new one is up. Not being replaced: the new
        # one failed to start (its fault says how), and a reset tries again.
        fault = svc.servo_fault
        process = "starting" if svc.spawning or fault is None else fault["message"].removeprefix("servo process ")
        return {"state": "fault" if fault else "disconnected", "link": "fault" if fault else "idle",
                "servo_process": process, "fault": fault, "status_live": False, "status_bits": None,
                "alarms": svc.alarm_forwarder.alarms(), "alarm_history": svc.alarm_forwarder.history(),
                "mcap_error": svc.mcap_error}

    def state_vector(self) -> dict[str, Any]:
        """The servo process's published state alone (cheap: a shared-memory copy); a dead process's
        last state shows the fault. With the alarm and fault counts for /metrics."""
        svc = self.service
        s = self._published()
        if s is None:
            return {"state": "disconnected", "link": "idle"} if svc.stream is None else self._no_process()
        if svc.servo_fault is not None:
            s["state"], s["link"], s["settled"] = "fault", "fault", False
        s["alarm_counts"], s["fault_counts"] = svc.alarm_forwarder.counts()
        s["alarm_poll_failures"] = svc.alarm_forwarder.poll_failures
        return svc.tools.decorate(s)  # the pose is the active TCP's (servo_app.service.tools)

    def state(self) -> dict[str, Any]:
        svc = self.service
        s = self._published()
        if s is None:
            return self._no_process()
        safety = svc.safety_view(s["state"])
        s.update({k: v for k, v in safety.items() if k not in ("state", "link")})
        for key in ("warnings", "warning_history"):
            if s.get(key):
                s[key] = self._with_wall_clock(s[key])
        s["servo_process"] = "running"
        if svc.servo_fault is not None:  # the last published state is stale: the process is gone
            # The controller stopped the arm; no feedback says where it came to rest.
            s.update(state="fault", link="fault", fault=svc.servo_fault, resumable=False, at_rest=True,
                     settled=False)
            s["servo_process"] = svc.servo_fault["message"].removeprefix("servo process ")
        s["servo_starts"] = svc.servo_starts
        svc.tools.decorate(s)  # the active tool; the pose is its TCP's, the flange's beside it
        s["backend"] = svc.backend.name
        s["model"] = svc.profile.name
        # Why a Cartesian motion goes slower than asked, or stops short (None: no Cartesian motion).
        s["cartesian"] = {"scale": s["ik_scale"], "condition": s["ik_condition"],
                          "held_back_by": holding_back(s["ik_flags"])} if s.get("ik_active") else None
        s["robot"] = f"{svc.robot_address[0]}:{svc.robot_address[1]}" if svc.robot_address else None
        s["simulated"] = svc.sim is not None
        s["alarms"] = svc.alarm_forwarder.alarms()
        s["alarm_history"] = svc.alarm_forwarder.history()
        s["faults"] = svc.alarm_forwarder.faults[-10:]
        # The embedded controller's alarm list cannot be read now (frozen or starved): new alarms wait.
        s["alarm_poll_error"] = svc.alarm_forwarder.poll_error or None
        s["mcap_error"] = svc.mcap_error
        replay = s.get("trajectory")
        if replay is not None and replay["state"] == "ended":  # why it ended before its end
            left = svc.last_event(msg.ReplayLeft)
            replay["reason"] = left.reason if isinstance(left, msg.ReplayLeft) else None
        consistent(s, time.time())
        if svc.inputs is not None:
            s["inputs"] = svc.inputs.summary()
        return s

    def stops(self) -> dict[str, int]:
        """Stops by reason: the servo process's (hold-to-run, lease, signals, API) plus API-only counts."""
        out = Counter(self.service.stops_by_reason)
        out.update(self.service.safety.get("stops") or {})
        return dict(out)

    def limits(self) -> dict[str, Any]:
        svc = self.service
        out = svc.backend.limits(svc.stream.state() if svc.stream else {}, svc.options)
        tool = svc.tools.active  # its payload picks the tables' interpolation (Appendix B)
        out.update(tool=tool.name, payload_kg=tool.payload_kg)
        return self._with_flange_cap(out)

    def _with_flange_cap(self, out: dict[str, Any]) -> dict[str, Any]:
        """The flange-speed cap the servo, the feeds and the planner hold (the controller's $MAX_SPD
        where tighter than the configured cap), not the profile's: a client plans by it."""
        svc = self.service
        cap = svc.backend.flange_speed_cap(svc.options, svc.controller_tables)
        if cap is not None:
            out.update(max_flange_speed_mm_s=float(cap[0]), max_flange_speed_source=cap[1])
        return out

    def robot(self) -> dict[str, Any]:
        """Arm geometry for the console: the backend's axes, ranges and drawing of the current position."""
        svc = self.service
        st = svc.stream.state() if svc.stream is not None else {}
        q = st.get("q_servo") if st.get("status_received") else st.get("q_cmd")
        view = svc.backend.robot_view(q or [0.0] * 6)
        view["cartesian_jog"] = svc.backend.cartesian_jog
        return self._with_flange_cap(svc.tools.decorate_robot(view))  # the active tool's TCP, drawn from the flange

    def session_logs(self) -> list[dict[str, Any]]:
        d = self.service.cfg.log_dir
        if not d.is_dir():
            return []
        return [{"name": p.name, "bytes": p.stat().st_size, "modified_unix": p.stat().st_mtime}
                for p in sorted(d.glob("*.srvlog"), key=lambda p: p.stat().st_mtime, reverse=True)]

    def session_log_path(self, name: str) -> Path:
        d = self.service.cfg.log_dir
        try:
            p = (d / name).resolve()
            ok = p.parent == d.resolve() and p.suffix == ".srvlog" and p.is_file()
        except (OSError, ValueError):  # a NUL byte or an over-long name: no such log either
            ok = False
        if not ok:
            raise FileNotFoundError(f"no session log named {name!r}")
        return p
