"""The FANUC servo process: one UDP socket, one stream session, nothing CPU-bound beside it.

Measured here (DESIGN.md): a busy Python thread in the same process pushes a UDP echo's p99 from
0.18 ms to 8 ms through the GIL, so the cycle lives in a process of its own. The parent talks to it
through a pipe (requests in, replies and events out) and reads its state from a shared-memory
latest-value slot. Per status packet: decode, compute, send, and only then log, publish and read the
pipe, so nothing sits between receipt and send but the motion step itself.

SIGINT/SIGTERM end the stream cleanly: decelerate, last data, then status output off.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import socket
import time
import traceback
from collections import deque
from dataclasses import asdict, dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from servo_app.fanuc.packets import ROBOT_PORT, IoType, Status
from servo_app.fanuc.session import IoRequest, Phase, SessionConfig, StreamSession
from servo_app.fanuc.session_log import SessionLogWriter
from servo_app.ipc import LatestValueSlot
from servo_app.motion.servo import CommandRejected, ServoCycle, ServoSettings
from servo_app.robots.profile import load_profile
from servo_app.state import PHASES, STATE_SIZE, StateVector, decode_state

assert all(p.value in PHASES for p in Phase)


@dataclass
class StreamConfig:
    host: str = "127.0.0.1"
    port: int = ROBOT_PORT
    model: str = "lrmate200id"
    interval_ms: int | None = None  # None: the profile's
    lead: int = 0
    log_dir: str = "var/sessions"
    limit_fraction: float = 0.9
    flange_speed_cap: float | None = None
    payload_kg: float | None = None
    status_timeout_s: float = 0.1
    late_threshold_ms: float | None = None  # None: half an interval
    extra: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------- child side


class _Latency:
    """Status receipt to command send, last 4096 cycles."""

    def __init__(self) -> None:
        self.samples: deque[float] = deque(maxlen=4096)
        self.max_us = 0.0
        self.late = 0

    def add(self, us: float, late_us: float) -> None:
        self.samples.append(us)
        self.max_us = max(self.max_us, us)
        if us > late_us:
            self.late += 1

    def percentiles(self) -> tuple[float, float]:
        if not self.samples:
            return 0.0, 0.0
        a = np.fromiter(self.samples, float)
        p50, p99 = np.percentile(a, [50, 99])
        return float(p50), float(p99)


class _ServoProcess:
    def __init__(self, cfg: StreamConfig, conn: Connection, slot_name: str) -> None:
        self.cfg = cfg
        self.conn = conn
        self.slot = LatestValueSlot(STATE_SIZE, name=slot_name, create=False)
        self.profile = load_profile(cfg.model)
        self.dt = (cfg.interval_ms or self.profile.interval_ms) / 1000.0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect((cfg.host, cfg.port))
        self.sock.settimeout(0.02)
        self.cycle: ServoCycle | None = None
        self.session: StreamSession | None = None
        self.log: SessionLogWriter | None = None
        self.t0 = time.monotonic()
        self.state = StateVector()
        self.latency = _Latency()
        self.late_us = (cfg.late_threshold_ms or self.dt * 1000 / 2) * 1000
        self.hist: deque[np.ndarray] = deque(maxlen=4)  # last commanded positions, for finite differences
        self.signalled = False
        self.quit = False
        self.last_status_t = 0.0
        self.last_phase = Phase.IDLE

    # -- main loop
    def run(self) -> None:
        signal.signal(signal.SIGTERM, self._on_signal)
        signal.signal(signal.SIGINT, self._on_signal)
        self._event("ready", pid=os.getpid())
        try:
            while not self.quit:
                self._step()
        finally:
            self._finish_log()
            self.sock.close()
            self.slot.close()

    def _step(self) -> None:
        s = self.session
        try:
            data = self.sock.recv(1024)
        except (TimeoutError, ConnectionRefusedError):
            data = b""
        now = time.monotonic()
        if s is not None and data:
            out = s.on_datagram(data, now)
            for b in out:
                self.sock.send(b)
            t_sent = time.monotonic()
            self._after_datagram(s, now, t_sent)
        elif s is not None:
            s.on_idle(now)
        self._poll_requests()
        self._watch_phase()
        self._publish()

    def _after_datagram(self, s: StreamSession, t_recv: float, t_sent: float) -> None:
        st = s.last_status
        if st is None or self.log is None:
            return
        t = t_recv - self.t0
        if st.seq != getattr(self, "_logged_seq", None):
            self._logged_seq = st.seq
            self.log.status(t, st.seq, st.status, st.read_io_value, st.joints)
            if self.last_status_t:
                self.state.set("status_interval_last_ms", (t_recv - self.last_status_t) * 1000)
            self.last_status_t = t_recv
        lat_us = (t_sent - t_recv) * 1e6
        for sent in s.sent:
            c = sent.command
            self.log.command(t_sent - self.t0, c.seq, c.last_data, c.data_format, c.write_io_value, lat_us, c.values)
            self.latency.add(lat_us, self.late_us)
            self.hist.append(np.array(c.values[:6]))

    # -- requests from the parent
    def _poll_requests(self) -> None:
        while self.conn.poll():
            try:
                req = self.conn.recv()
            except EOFError:
                self._on_signal(signal.SIGTERM, None)
                return
            rid = req.get("id")
            try:
                result = self._handle(req)
                self.conn.send({"id": rid, "ok": True, "result": result})
            except (CommandRejected, ValueError, RuntimeError) as exc:
                self.conn.send({"id": rid, "ok": False, "error": str(exc)})

    def _handle(self, req: dict[str, Any]) -> Any:
        op = req["op"]
        if op == "start":
            return self._start()
        if op == "shutdown":
            self._on_signal(signal.SIGTERM, None)
            return None
        s, c = self.session, self.cycle
        if op == "end":
            if s is None or s.phase in (Phase.CLOSED, Phase.FAULT):
                raise RuntimeError("no open stream session to end")
            s.request_end()
            return None
        if op == "close":  # status output off without streaming (after a fault)
            if s is not None:
                for b in s.close_now():
                    self.sock.send(b)
            return None
        if op == "io_read":
            if s is None:
                raise RuntimeError("no session")
            s.io_read = IoRequest(_io_type(req["type"]), int(req["index"]), int(req.get("mask", 0xFFFF)))
            return None
        if op == "io_write":
            if s is None or s.phase != Phase.STREAMING:
                raise RuntimeError("I/O is written through command packets: only while streaming")
            s.write_io(IoRequest(_io_type(req["type"]), int(req["index"]), int(req.get("mask", 0xFFFF)),
                                 int(req["value"])))
            return None
        if c is None or s is None or s.phase != Phase.STREAMING:
            raise CommandRejected(f"'{op}' needs a streaming session (phase is {s.phase if s else 'idle'})")
        if op == "target":
            c.set_joint_target(np.asarray(req["joints"], float), float(req.get("speed_scale", 1.0)))
        elif op == "jog":
            c.jog_joints(np.asarray(req["joints"], float), float(req.get("hold_s", 0.2)))
        elif op == "stop":
            c.stop(fast=bool(req.get("fast", False)))
        elif op == "resume":
            c.resume()
        else:
            raise CommandRejected(f"op={op!r} is unknown")
        return None

    def _start(self) -> str:
        if self.session is not None and self.session.phase not in (Phase.CLOSED, Phase.FAULT):
            raise RuntimeError(f"a session is already open (phase {self.session.phase})")
        self._finish_log()
        settings = ServoSettings(limit_fraction=self.cfg.limit_fraction, flange_speed_cap=self.cfg.flange_speed_cap,
                                 payload_kg=self.cfg.payload_kg)
        self.cycle = ServoCycle(self.profile, self.dt, settings)
        self.session = StreamSession(self.cycle, SessionConfig(
            lead=self.cfg.lead, status_timeout_s=self.cfg.status_timeout_s,
            max_payload_kg=self.profile.max_payload_kg))
        self.t0 = time.monotonic()
        self.latency = _Latency()
        self.hist.clear()
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = Path(self.cfg.log_dir) / f"session-{stamp}-{os.getpid()}-{int(self.t0 * 1000) % 100000}.srvlog"
        self.log = SessionLogWriter(path, {"model": self.profile.name, "interval_ms": self.dt * 1000,
                                           "j23_factor": self.profile.j23_factor, "protocol": "fanuc-j519-v1",
                                           "robot": f"{self.cfg.host}:{self.cfg.port}",
                                           "flush_every": int(1 / self.dt)}, flush_every=max(1, int(1 / self.dt)))
        for b in self.session.open(time.monotonic()):
            self.sock.send(b)
        return str(path)

    def _watch_phase(self) -> None:
        s = self.session
        if s is None or s.phase == self.last_phase:
            return
        self.last_phase = s.phase
        self._event("phase", phase=s.phase.value, reason=s.fault_reason)
        if s.phase in (Phase.CLOSED, Phase.FAULT):
            self._finish_log()
            if self.signalled:
                self.quit = True

    def _finish_log(self) -> None:
        if self.log is not None:
            self.log.close()
            self._event("log_closed", path=str(self.log.path), records=self.log.records)
            self.log = None

    def _on_signal(self, signum: int, frame: object) -> None:
        self.signalled = True
        s = self.session
        if s is None or s.phase in (Phase.CLOSED, Phase.FAULT, Phase.IDLE):
            self.quit = True
        elif s.phase in (Phase.FETCHING_TABLES, Phase.WAITING_READY):
            for b in s.close_now():
                self.sock.send(b)
            self.quit = True
        else:
            s.request_end()

    def _event(self, kind: str, **kw: Any) -> None:
        with contextlib.suppress(BrokenPipeError, OSError):
            self.conn.send({"event": kind, **kw})

    # -- publishing
    def _publish(self) -> None:
        sv, s, c = self.state, self.session, self.cycle
        sv.set("published_unix", time.time())
        if s is not None:
            sv.set("phase", PHASES.index(s.phase.value))
            sv.set("session_time", time.monotonic() - self.t0)
            st = s.last_status
            if isinstance(st, Status):
                sv.set("status_seq", st.seq)
                sv.set("status_bits", st.status)
                sv.set("q_servo", np.array(st.joints[:6]))
                sv.set("cart_servo", np.array(st.cartesian[:6]))
                sv.set("io_read_value", st.read_io_value)
            for k in ("commands_sent", "status_received", "status_lost", "status_duplicated", "malformed"):
                sv.set(k, getattr(s.stats, k))
        lat = self.latency
        if lat.samples:
            p50, p99 = lat.percentiles() if len(lat.samples) % 16 == 0 else (None, None)
            sv.set("latency_last_us", lat.samples[-1])
            if p50 is not None:
                sv.set("latency_p50_us", p50)
                sv.set("latency_p99_us", p99)
            sv.set("latency_max_us", lat.max_us)
            sv.set("late_commands", lat.late)
        if c is not None and c.limits is not None:
            sv.set("at_rest", float(c.at_rest()))
            sv.set("stopped", float(c._stopped))
            sv.set("tables_from_controller", float(c.tables_source == "controller"))
            vel_l, acc_l, jerk_l = c.limits
            sv.set("vel_limit", vel_l)
            sv.set("acc_limit", acc_l)
            sv.set("jerk_limit", jerk_l)
        if len(self.hist) >= 1:
            h = list(self.hist)
            while len(h) < 4:
                h.insert(0, h[0])
            q = np.array(h)
            v = np.diff(q, axis=0) / self.dt
            a = np.diff(v, axis=0) / self.dt
            j = np.diff(a, axis=0) / self.dt
            sv.set("q_cmd", q[-1])
            sv.set("vel", v[-1])
            sv.set("acc", a[-1])
            sv.set("jerk", j[-1])
        self.slot.write(sv.data)


def _io_type(value: Any) -> int:
    if isinstance(value, str):
        try:
            return int(IoType[value.upper()])
        except KeyError:
            raise CommandRejected(f"io type={value!r} is unknown (DI, DO, RI, RO, ..., F, M)") from None
    return int(IoType(int(value)))


def _child_main(cfg_dict: dict[str, Any], conn: Connection, slot_name: str) -> None:
    try:
        _ServoProcess(StreamConfig(**cfg_dict), conn, slot_name).run()
    except Exception:  # report, then die: the parent turns this into a fault
        with contextlib.suppress(OSError):
            conn.send({"event": "crashed", "traceback": traceback.format_exc()})
        raise


# -------------------------------------------------------------------------- parent side


class StreamProcess:
    """Parent-side handle of the servo process."""

    def __init__(self, cfg: StreamConfig) -> None:
        self.cfg = cfg
        self.slot = LatestValueSlot(STATE_SIZE)
        ctx = mp.get_context("spawn")
        self._conn, child_conn = ctx.Pipe()
        self.process = ctx.Process(target=_child_main, args=(asdict(cfg), child_conn, self.slot.name),
                                   name="servo-cycle", daemon=True)
        self.events: list[dict[str, Any]] = []
        self._next_id = 0
        self._replies: dict[int, dict[str, Any]] = {}

    def start(self, timeout: float = 30.0) -> None:
        self.process.start()
        self.wait_event("ready", timeout)

    def request(self, op: str, timeout: float = 2.0, **kw: Any) -> Any:
        """Send a request to the servo process and wait for its reply; errors raise CommandRejected."""
        self._next_id += 1
        rid = self._next_id
        self._conn.send({"id": rid, "op": op, **kw})
        deadline = time.monotonic() + timeout
        while rid not in self._replies:
            if not self._pump(deadline - time.monotonic()):
                raise TimeoutError(f"servo process did not answer '{op}' within {timeout} s")
        reply = self._replies.pop(rid)
        if not reply["ok"]:
            raise CommandRejected(reply["error"])
        return reply.get("result")

    def _pump(self, timeout: float) -> bool:
        if timeout <= 0 or not self._conn.poll(timeout):
            return False
        try:
            msg = self._conn.recv()
        except EOFError:
            return False
        if "event" in msg:
            self.events.append(msg)
        else:
            self._replies[msg["id"]] = msg
        return True

    def poll_events(self) -> list[dict[str, Any]]:
        while self._pump(0.0001):
            pass
        return self.events

    def wait_event(self, kind: str, timeout: float, **match: Any) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        seen = 0
        while True:
            for ev in self.events[seen:]:
                if ev["event"] == kind and all(ev.get(k) == v for k, v in match.items()):
                    return ev
                if ev["event"] == "crashed":
                    raise RuntimeError(f"servo process crashed:\n{ev['traceback']}")
            seen = len(self.events)
            if not self._pump(deadline - time.monotonic()) and time.monotonic() >= deadline:
                raise TimeoutError(f"no '{kind}' event {match} within {timeout} s; events: {self.events[-5:]}")

    def state(self) -> dict[str, Any]:
        _, data = self.slot.read()
        return decode_state(data)

    def shutdown(self, timeout: float = 10.0) -> int | None:
        """Signal the process (it ends a running stream cleanly) and wait for it."""
        if self.process.is_alive():
            assert self.process.pid is not None
            os.kill(self.process.pid, signal.SIGTERM)
            self.process.join(timeout)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(2)
        self.poll_events()
        self.slot.close()
        return self.process.exitcode
