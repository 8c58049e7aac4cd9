"""The service object behind the API: the servo process, the embedded simulator, leases, logs.

It lives in the API process and stays thin: every motion decision is taken in the servo process
(the cycle owns stops, hold-to-run and watchdogs, so a frozen API cannot leave the arm moving). This
object forwards requests, reads the published state and keeps the lists the API shows.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from servo_app.fanuc.alarms import ALARMS
from servo_app.fanuc.packets import ROBOT_PORT
from servo_app.fanuc.runner import StreamConfig, StreamProcess
from servo_app.motion.limit_tables import default_tables
from servo_app.motion.servo import CommandRejected
from servo_app.robots.profile import RobotProfile, load_profile


def parse_robot(spec: str | None) -> tuple[str, str, int] | None:
    """``fanuc:HOST[:PORT]`` -> ("fanuc", host, port); None means the embedded simulator."""
    if not spec:
        return None
    kind, _, rest = spec.partition(":")
    if kind != "fanuc" or not rest:
        raise ValueError(f"--robot={spec!r}: expected fanuc:HOST[:PORT]")
    host, _, port = rest.partition(":")
    try:
        return kind, host, int(port) if port else ROBOT_PORT
    except ValueError:
        raise ValueError(f"--robot={spec!r}: port {port!r} is not a number") from None


@dataclass
class ServiceConfig:
    robot: str | None = None  # None: embedded simulator
    model: str = "lrmate200id"
    interval_ms: int | None = None
    lead: int = 0
    var_dir: Path = Path("var")
    sim_port: int = 0  # embedded simulator UDP port (0: any free port)
    limit_fraction: float = 0.9
    flange_speed_cap: float | None = None
    payload_kg: float | None = None
    sim_options: dict[str, Any] = field(default_factory=dict)

    @property
    def log_dir(self) -> Path:
        return self.var_dir / "sessions"


class ServoService:
    def __init__(self, cfg: ServiceConfig) -> None:
        self.cfg = cfg
        self.profile: RobotProfile = load_profile(cfg.model)
        self.sim: Any = None
        self.stream: StreamProcess | None = None
        self.stops_by_reason: Counter[str] = Counter()
        self.faults: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self.robot_address: tuple[str, int] | None = None
        self._alarms_seen = 0
        self._sim_events: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ life
    def open(self) -> None:
        robot = parse_robot(self.cfg.robot)
        if robot is None:
            from servo_app.sim.process import SimulatorProcess

            self.sim = SimulatorProcess(model=self.cfg.model, port=self.cfg.sim_port,
                                        interval_ms=self.cfg.interval_ms, **self.cfg.sim_options)
            self.sim.start()
            host, port = self.sim.address
        else:
            _, host, port = robot
        self.robot_address = (host, port)
        self.stream = StreamProcess(StreamConfig(
            host=host, port=port, model=self.cfg.model, interval_ms=self.cfg.interval_ms, lead=self.cfg.lead,
            log_dir=str(self.cfg.log_dir), limit_fraction=self.cfg.limit_fraction,
            flange_speed_cap=self.cfg.flange_speed_cap, payload_kg=self.cfg.payload_kg))
        self.stream.start()

    def close(self) -> None:
        if self.stream is not None:
            self.stream.shutdown()
            self.stream = None
        if self.sim is not None:
            self.sim.stop()
            self.sim = None

    # -------------------------------------------------------------- requests
    def request(self, op: str, **kw: Any) -> Any:
        if self.stream is None:
            raise RuntimeError("the service is not open")
        with self._lock:
            return self.stream.request(op, **kw)

    def send(self, op: str, **kw: Any) -> None:
        """Fire-and-forget (jog renewals): the servo process validates again and drops bad ones."""
        if self.stream is None:
            raise RuntimeError("the service is not open")
        with self._lock:
            self.stream.request(op, **kw)

    def stop(self, reason: str, fast: bool = False) -> None:
        self.stops_by_reason[reason] += 1
        self.request("stop", fast=fast, reason=reason)

    def reset(self) -> None:
        """Clear a fault: the simulator's alarm (as an operator at the pendant would), then the supervisor."""
        if self.sim is not None:
            self.sim.reset()
        self.request("reset")

    def _forward_alarms(self) -> None:
        """The J519 status carries no alarm code: the embedded simulator's alarm list supplies it."""
        if self.sim is None or self.stream is None:
            return
        events = self.sim.events()
        for ev in events[self._alarms_seen:]:
            spec = ALARMS.get(ev["code"])
            if spec is not None and not spec.warning:
                self.faults.append(ev)
                with contextlib.suppress(CommandRejected):
                    self.request("controller_alarm", code=ev["code"], message=ev["message"])
        self._alarms_seen = len(events)
        self._sim_events = events

    # ----------------------------------------------------------------- views
    def state(self) -> dict[str, Any]:
        if self.stream is None:
            return {"phase": "disconnected"}
        s = self.stream.state()
        self._forward_alarms()
        safety = self.stream.last_event("safety") or {}
        s.update({k: v for k, v in safety.items() if k != "event"})
        s["model"] = self.profile.name
        s["robot"] = f"{self.robot_address[0]}:{self.robot_address[1]}" if self.robot_address else None
        s["simulated"] = self.sim is not None
        s["alarms"] = self.alarms()
        s["faults"] = self.faults[-10:]
        return s

    def alarms(self) -> list[dict[str, Any]]:
        if self.sim is None:
            return []
        out = []
        for ev in self._sim_events[-20:]:
            spec = ALARMS.get(ev["code"])
            out.append({**ev, "cause": spec.cause if spec else "", "remedy": spec.remedy if spec else "",
                        "warning": bool(spec and spec.warning)})
        return out

    def limits(self) -> dict[str, Any]:
        tables = default_tables(self.profile)
        vel, acc, jerk = tables.for_cap(self.cfg.flange_speed_cap or tables.vmax, self.cfg.payload_kg)
        st = self.stream.state() if self.stream else {}
        from_ctrl = bool(st.get("tables_from_controller"))
        if from_ctrl:
            vel, acc, jerk = st["vel_limit"], st["acc_limit"], st["jerk_limit"]
        return {
            "model": self.profile.name,
            "source": "controller limit tables" if from_ctrl else "profile defaults (configured, not published)",
            "interval_ms": self.cfg.interval_ms or self.profile.interval_ms,
            "limit_fraction": self.cfg.limit_fraction,
            "joint_min_deg": list(self.profile.joint_min_deg),
            "joint_max_deg": list(self.profile.joint_max_deg),
            "vel_deg_s": [float(v) for v in vel],
            "acc_deg_s2": [float(v) for v in acc],
            "jerk_deg_s3": [float(v) for v in jerk],
            "max_flange_speed_mm_s": tables.vmax,
        }

    def session_logs(self) -> list[dict[str, Any]]:
        d = self.cfg.log_dir
        if not d.is_dir():
            return []
        return [{"name": p.name, "bytes": p.stat().st_size, "modified_unix": p.stat().st_mtime}
                for p in sorted(d.glob("*.srvlog"), key=lambda p: p.stat().st_mtime, reverse=True)]

    def session_log_path(self, name: str) -> Path:
        p = (self.cfg.log_dir / name).resolve()
        if p.parent != self.cfg.log_dir.resolve() or p.suffix != ".srvlog" or not p.is_file():
            raise FileNotFoundError(f"no session log named {name!r}")
        return p

    def wait_state(self, state: str, timeout: float = 10.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            s = self.state()
            if s["state"] == state:
                return s
            time.sleep(0.01)
        raise TimeoutError(f"state {state!r} not reached within {timeout} s (now {self.state()['state']})")
