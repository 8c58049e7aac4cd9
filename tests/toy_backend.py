"""A third robot backend, test-only: proof (and a worked example) that a backend plugs in without
touching servo_app. Registered by name like the real ones::

    register_backend("toy", "toy_backend:ToyBackend")

The "toy" robot is a two-axis linear table (X, Y in mm) behind a trivial UDP protocol of its own.
What a backend supplies, from the bottom up:

- the wire protocol (``encode``/``decode``) and a pure link session (:class:`ToySession`);
- a motion stage (:class:`ToyMotion`): velocity jog / position target with a linear ramp;
- a supervisor (:class:`ToySupervisor`): the link hooks of :class:`SupervisorBase` and status handling;
- a servo-process host (:class:`ToyHost`) and its parent-side handle (:class:`ToyProcess`);
- an embedded simulator (:class:`ToyController`), and the :class:`ToyBackend` that ties them together.

Protocol (little-endian), one datagram each:

- ``START`` (servo -> controller): start sending status to me; the controller restarts its
  program (waiting for a first command) and its status sequence at 1;
- ``STOP``: stop sending status;
- ``STATUS`` (every interval): u32 seq, u8 flags (bit 0 waiting for commands, bit 1 a command was
  received in this program run, bit 2 ready), 2 x f64 position;
- ``COMMAND`` (one per status): u32 seq (1, 2, ... per stream), u8 last, 2 x f64 position. After
  ``last`` the program ends: bit 0 falls.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import select
import socket
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import StrEnum
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from servo_app.backends import ProcessOptions, RobotBackend, Target
from servo_app.errors import CommandRejected, InvalidRequest
from servo_app.messages import Event, Ready
from servo_app.process_handle import ServoProcessHandle, ServoProcessHost, run_child
from servo_app.safety import FaultInfo, Mode, ShaperAtRest, Signal, StatusLost, StatusReceived, stream_alive
from servo_app.state import PHASES, StateVector
from servo_app.supervision import SupervisorBase

N_AXES = 2
DEFAULT_PORT = 10090
INTERVAL_MS = 8

# ------------------------------------------------------------------------------------- profiles


@dataclass(frozen=True)
class ToyProfile:
    name: str
    display_name: str
    axis_names: tuple[str, ...] = ("X", "Y")
    axis_min: tuple[float, ...] = (0.0, 0.0)
    axis_max: tuple[float, ...] = (400.0, 300.0)
    speed: tuple[float, ...] = (250.0, 250.0)  # mm/s
    accel: tuple[float, ...] = (1000.0, 1000.0)  # mm/s^2 (a fast stop brakes at twice this)
    home: tuple[float, ...] = (100.0, 100.0)  # where the simulated table starts


PROFILES = {"toy1": ToyProfile("toy1", "Toy XY table")}


def load_toy_profile(model: str) -> ToyProfile:
    try:
        return PROFILES[model]
    except KeyError:
        raise ValueError(f"toy model {model!r} is unknown (known: {', '.join(PROFILES)})") from None


# ------------------------------------------------------------------------------------- protocol

START, STOP, STATUS, COMMAND = 1, 2, 3, 4
_PACKET = struct.Struct(f"<BIB{N_AXES}d")  # kind, seq, flags (status) or last (command), positions
WAITING, RECEIVED, READY = 0x01, 0x02, 0x04


@dataclass(frozen=True)
class Packet:
    kind: int
    seq: int = 0
    flags: int = 0  # STATUS: WAITING | RECEIVED | READY; COMMAND: 1 = last
    q: tuple[float, ...] = (0.0,) * N_AXES

    def encode(self) -> bytes:
        if self.kind in (START, STOP):
            return bytes([self.kind])
        return _PACKET.pack(self.kind, self.seq, self.flags, *self.q)


def decode(data: bytes) -> Packet:
    if len(data) == 1 and data[0] in (START, STOP):
        return Packet(data[0])
    if len(data) != _PACKET.size or data[0] not in (STATUS, COMMAND):
        raise ValueError(f"not a toy packet: {len(data)} bytes, kind {data[:1].hex() or 'none'}")
    kind, seq, flags, *q = _PACKET.unpack(data)
    return Packet(kind, seq, flags, tuple(q))


# --------------------------------------------------------------------------------- motion stage


@dataclass
class Ramp:
    """The commanded motion: position and velocity, advanced one interval per command."""

    q: np.ndarray
    v: np.ndarray


class ToyMotion:
    """Velocity jog or position target, ramped at the profile's acceleration and braking in time for
    the axis ends. ``shaper`` is None until streaming (the supervisor only decelerates a live one)."""

    def __init__(self, profile: ToyProfile, dt: float) -> None:
        self.dt = dt
        self.lo, self.hi = np.array(profile.axis_min), np.array(profile.axis_max)
        self.vmax, self.acc = np.array(profile.speed), np.array(profile.accel)
        self.shaper: Ramp | None = None
        self.stopped = False
        self._fast = False
        self._jog = np.zeros(N_AXES)
        self._target: tuple[np.ndarray, float] | None = None

    def begin(self, q0: tuple[float, ...]) -> None:
        """Streaming starts where the controller says the table is."""
        self.shaper = Ramp(np.array(q0, dtype=float), np.zeros(N_AXES))
        self.stopped, self._jog, self._target = False, np.zeros(N_AXES), None

    def next_command(self) -> np.ndarray:
        r = self._require()
        acc = self.acc * (2.0 if self.stopped and self._fast else 1.0)
        r.v = r.v + np.clip(self._wanted(r) - r.v, -acc * self.dt, acc * self.dt)
        r.q = np.clip(r.q + r.v * self.dt, self.lo, self.hi)
        return r.q.copy()

    def _wanted(self, r: Ramp) -> np.ndarray:
        if self.stopped:
            return np.zeros(N_AXES)
        if self._target is not None:  # towards the target, slow enough to stop on it
            d = self._target[0] - r.q
            cap = np.minimum(self.vmax * self._target[1], np.sqrt(2 * self.acc * np.abs(d)))
            return np.where(np.abs(d) < 1e-6, 0.0, np.clip(d / self.dt, -cap, cap))  # arrived: rest
        # A jog brakes in time for the axis ends.
        return np.clip(self._jog, -np.sqrt(2 * self.acc * (r.q - self.lo)), np.sqrt(2 * self.acc * (self.hi - r.q)))

    def at_rest(self) -> bool:
        return self.shaper is None or not self.shaper.v.any()

    # -- what the supervisor asks (SupervisorBase: jog, set_target, stop, resume)
    def jog(self, v: np.ndarray) -> None:
        self._require()
        self._jog, self._target = np.clip(self._checked(v, "joints"), -self.vmax, self.vmax), None

    def set_target(self, q: np.ndarray, speed_scale: float = 1.0) -> None:
        self._require()
        if not (np.isfinite(speed_scale) and 0.0 < speed_scale <= 1.0):
            raise InvalidRequest(f"speed_scale={speed_scale} must be in (0, 1]")
        q = self._checked(q, "joints")
        if np.any(q < self.lo) or np.any(q > self.hi):
            raise InvalidRequest(f"target {q.tolist()} mm is outside the axes {self.lo.tolist()}..{self.hi.tolist()}")
        self._target, self._jog = (q, float(speed_scale)), np.zeros(N_AXES)

    def stop(self, fast: bool = False) -> None:
        self.stopped, self._fast, self._jog = True, fast, np.zeros(N_AXES)

    def resume(self) -> None:
        self.stopped = False  # a jog was dropped by the stop; a target carries on

    def _require(self) -> Ramp:
        if self.shaper is None:
            raise CommandRejected("not streaming: no motion command is accepted yet")
        return self.shaper

    @staticmethod
    def _checked(values: np.ndarray, name: str) -> np.ndarray:
        v = np.asarray(values, dtype=float).reshape(-1)
        if v.shape != (N_AXES,) or not np.all(np.isfinite(v)):
            raise InvalidRequest(f"{name} must be {N_AXES} finite numbers (X, Y), got {v.tolist()}")
        return v


# -------------------------------------------------------------------------------- link session


class Phase(StrEnum):  # a subset of servo_app.state.PHASES: what the host publishes
    IDLE = "idle"
    CONNECTED = "connected"  # status flowing (or asked for), not streaming
    STREAMING = "streaming"
    ENDING = "ending"  # last data sent, waiting for bit 0 to fall
    CLOSED = "closed"  # status output stopped
    FAULT = "fault"


assert all(p.value in PHASES for p in Phase)


@dataclass
class LinkStats:
    status_received: int = 0
    status_lost: int = 0
    status_duplicated: int = 0
    commands_sent: int = 0
    malformed: int = 0
    last_error: str = ""


class ToySession:
    """The protocol rules, pure (no socket, no clock): one command per new status, consecutive
    command numbers, last data at rest, status timeouts. Returns the datagrams to send."""

    def __init__(self, motion: ToyMotion, status_timeout_s: float = 0.25, link_timeout_s: float = 1.0) -> None:
        self.motion = motion
        self.status_timeout_s = status_timeout_s  # silence while streaming: the link is lost
        self.link_timeout_s = link_timeout_s  # silence after START: no controller
        self.phase = Phase.IDLE
        self.fault_reason = ""
        self.last_status: Packet | None = None
        self.stats = LinkStats()
        self.sent: list[Packet] = []  # this call's commands, for the host's log
        self._armed = self._end = False
        self._seq = 0
        self._last_q: np.ndarray | None = None
        self._heard = 0.0  # when the last status (or START) was

    @property
    def output_on(self) -> bool:
        return self.phase not in (Phase.IDLE, Phase.CLOSED)

    def open(self, now: float) -> list[bytes]:
        self.last_status, self.fault_reason, self._heard = None, "", now  # the controller restarts at seq 1
        self.phase = Phase.CONNECTED
        return [Packet(START).encode()]

    def close(self) -> list[bytes]:
        self._armed, self.phase = False, Phase.CLOSED
        return [Packet(STOP).encode()]

    def arm(self) -> None:
        self._armed, self._end = True, False

    def request_end(self) -> None:
        self._end = True  # the supervisor has already brought the motion to rest

    def abandon(self, reason: str) -> None:
        self._armed, self.fault_reason, self.phase = False, reason, Phase.FAULT

    def recover(self, now: float) -> bool:
        """After a reset: usable again; connected if status still flows (True), else idle."""
        flowing = self.last_status is not None and now - self._heard < 0.05
        if self.phase == Phase.FAULT:
            self.fault_reason, self._armed = "", False
            self.phase = Phase.CONNECTED if flowing else Phase.IDLE
        return flowing

    def decode_status(self, data: bytes) -> Packet | None:
        try:
            p = decode(data)
            if p.kind != STATUS:
                raise ValueError(f"packet kind {p.kind} from the controller")
            return p
        except ValueError as exc:
            self.stats.malformed += 1
            self.stats.last_error = str(exc)
            return None

    def is_new(self, st: Packet) -> bool:
        return self.last_status is None or st.seq == 1 or st.seq > self.last_status.seq

    def on_status(self, st: Packet, now: float) -> list[bytes]:
        self.sent = []
        if not self.is_new(st):
            self.stats.status_duplicated += 1
            return []
        if self.last_status is not None and st.seq > self.last_status.seq + 1:
            self.stats.status_lost += st.seq - self.last_status.seq - 1
        self.stats.status_received += 1
        self.last_status, self._heard = st, now
        waiting = bool(st.flags & WAITING) and bool(st.flags & READY)
        if self.phase == Phase.CONNECTED and self._armed and waiting and not st.flags & RECEIVED:
            self._armed, self._seq, self._last_q, self.phase = False, 0, None, Phase.STREAMING
            self.motion.begin(st.q)
        if self.phase == Phase.STREAMING:
            if not waiting:
                self.abandon("the controller stopped the stream (bit 0 or ready fell)")
                return []
            return [self._command()]
        if self.phase == Phase.ENDING and not st.flags & WAITING:
            return self.close()  # the program ended: status output off
        return []

    def _command(self) -> bytes:
        last = self._end and self.motion.at_rest()
        q = self._last_q if last and self._last_q is not None else self.motion.next_command()
        self._seq += 1
        self._last_q = q
        cmd = Packet(COMMAND, self._seq, int(last), tuple(float(v) for v in q))
        self.sent.append(cmd)
        self.stats.commands_sent += 1
        if last:
            self.phase = Phase.ENDING
        return cmd.encode()

    def on_idle(self, now: float) -> None:
        silent = now - self._heard
        if self.phase in (Phase.STREAMING, Phase.ENDING) and silent > self.status_timeout_s:
            self.abandon(f"no status for {silent:.3f} s")
        elif self.phase == Phase.CONNECTED and silent > self.link_timeout_s:
            self.abandon(f"no status for {silent:.3f} s: is the controller running?")


# ----------------------------------------------------------------------------------- supervisor


class ToySupervisor(SupervisorBase):
    """Only what is the toy's: the link hooks, and status packets as safety events."""

    def __init__(self, motion: ToyMotion, session: ToySession, start_timeout_s: float = 5.0) -> None:
        super().__init__(min_input_hold_s=0.02, hold_s=0.2, start_timeout_s=start_timeout_s)
        self.motion, self.session = motion, session
        self._out: list[bytes] = []

    # -- the link (SupervisorBase's hooks, called for the state machine's actions)
    def _link_open(self, now: float) -> None:
        if not self.session.output_on or self.session.phase == Phase.FAULT:
            self._out += self.session.open(now)

    def _link_close(self) -> None:
        if self.session.output_on:
            self._out += self.session.close()

    def _link_arm(self) -> None:
        self.session.arm()

    def _link_end(self) -> None:
        self.session.request_end()

    def _link_abandon(self, reason: str, now: float) -> None:
        self.session.abandon(reason)

    def _link_recover(self, now: float) -> None:
        if not self.session.recover(now) and self.state.status is not None:
            self._feed(StatusLost(detail="no status since the fault"), now)

    def _link_failure(self) -> str:
        return self.session.fault_reason if self.session.phase == Phase.FAULT else ""

    def _link_closed(self) -> bool:
        return not self.session.output_on or self.session.phase == Phase.FAULT

    def _word_fault(self, fault: FaultInfo, context: dict[str, Any]) -> FaultInfo:
        # The state machine words its own detections for FANUC (MOTN-603, IBGN start): say it for the toy.
        if fault.code is not None:
            return fault
        return replace(fault, cause="The toy controller stopped sending status, or stopped its program.",
                       remedy="Check that the toy controller runs, then reset and start a new stream.")

    # -- traffic
    def on_datagram(self, data: bytes, now: float) -> list[bytes]:
        self.session.sent = []
        st = self.session.decode_status(data)
        if st is None:
            return []
        # Before the command for it, so a start or a stop acts on this very status; once we stopped the
        # status output, stragglers are no news.
        if self.session.output_on and self.session.is_new(st):
            self._feed(StatusReceived(bit0=bool(st.flags & WAITING), bit1=bool(st.flags & RECEIVED),
                                      sysrdy=bool(st.flags & READY)), now)
            self._start_when_ready(now)
            self._poll_hold(now)
        self._out += self.session.on_status(st, now)
        if self.state.mode == Mode.STOPPING and self.motion.at_rest():
            self._feed(ShaperAtRest(), now)
        self._after_link(now)
        return self.take()

    def on_idle(self, now: float) -> list[bytes]:
        self.session.sent = []
        self.session.on_idle(now)
        self._after_link(now)
        return self.take()

    def _after_link(self, now: float) -> None:
        s = self.session
        if s.phase == Phase.FAULT and (stream_alive(self.state) or self.state.mode in (Mode.CONNECTED, Mode.READY)):
            self._feed(StatusLost(detail=s.fault_reason), now)
        elif s.phase == Phase.CLOSED and self.state.status is not None:
            # We stopped the status output: what the last one said is no longer true. (Left set, a start
            # right after an end would find "status flowing, not waiting" and never open the link.)
            self._feed(StatusLost(detail="status output stopped"), now)

    def signal(self, sig: int, now: float) -> list[bytes]:
        self._feed(Signal(sig=sig), now)
        return self.take()

    def take(self) -> list[bytes]:
        out, self._out = self._out, []
        return out

    def describe(self) -> dict[str, Any]:
        s = self.session
        return {**self._safety_view(), "link": s.phase.value, "link_error": s.fault_reason or s.stats.last_error}


# ---------------------------------------------------------------------------------- servo process


@dataclass
class ToyConfig:  # what crosses to the spawned child (ServoProcessHandle passes it as a dict)
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    model: str = "toy1"
    log_dir: str = "var/sessions"
    interval_ms: int = INTERVAL_MS
    start_timeout_s: float = 5.0


class ToyHost(ServoProcessHost):
    def __init__(self, cfg: ToyConfig, conn: Connection, slot_name: str) -> None:
        super().__init__(conn, slot_name)
        self.cfg = cfg
        self.profile = load_toy_profile(cfg.model)
        self.motion = ToyMotion(self.profile, cfg.interval_ms / 1000)
        self.sup = ToySupervisor(self.motion, ToySession(self.motion), cfg.start_timeout_s)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect((cfg.host, cfg.port))
        self.sock.settimeout(0.02)  # _io_step waits at most ~20 ms, so requests are read in time
        self._logged_seq: int | None = None
        self._latency_us = 0.0

    def run(self) -> None:
        self._install_signals()
        self.serve(Ready(pid=os.getpid()))

    def _send(self, out: list[bytes]) -> None:
        for b in out:
            with contextlib.suppress(OSError):  # the controller is gone: its silence is the fault
                self.sock.send(b)

    # -- ServoProcessHost's hooks
    def _io_step(self) -> None:
        try:
            data = self.sock.recv(256)
        except (TimeoutError, ConnectionRefusedError):
            data = b""
        now = time.monotonic()
        if not data:
            self._send(self.sup.on_idle(now))
            return
        self._send(self.sup.on_datagram(data, now))  # answer first, then log
        self._latency_us = (time.monotonic() - now) * 1e6
        self._log(now)

    def _deliver_signal(self, sig: int, now: float) -> None:
        self._send(self.sup.signal(sig, now))

    def _after_request(self) -> None:
        self._send(self.sup.take())  # e.g. START for a start request

    def _on_link_phase(self, phase: str) -> None:
        if phase in (Phase.CLOSED, Phase.FAULT, Phase.IDLE):
            self._close_log()

    def _shutdown(self) -> None:
        if self.sup.session.output_on:
            self._send(self.sup.session.close())
        self.sock.close()

    def _publish_backend(self, sv: StateVector) -> None:
        s, r = self.sup.session, self.motion.shaper
        if s.last_status is not None:
            sv.set("status_seq", s.last_status.seq)
            sv.set("status_bits", s.last_status.flags)
            sv.set("q_servo", _pad(s.last_status.q))
        for k in ("commands_sent", "status_received", "status_lost", "status_duplicated", "malformed"):
            sv.set(k, getattr(s.stats, k))
        sv.set("latency_last_us", self._latency_us)
        sv.set("at_rest", float(self.motion.at_rest()))
        sv.set("stopped", float(self.motion.stopped))
        sv.set("vel_limit", _pad(self.motion.vmax))
        sv.set("acc_limit", _pad(self.motion.acc))
        if r is not None:
            sv.set("q_cmd", _pad(r.q))
            sv.set("vel", _pad(r.v))

    # -- the session log: every status received and command sent
    def _log(self, t_recv: float) -> None:
        s = self.sup.session
        if self.log is None and s.phase in (Phase.CONNECTED, Phase.STREAMING):
            self._open_toy_log()  # the host's log (ServoProcessHost._open_log): it closes it on every way out
        if self.log is None:
            return
        st = s.last_status
        if st is not None and st.seq != self._logged_seq:
            self._logged_seq = st.seq
            self.log.status(t_recv - self.t0, st.seq, st.flags, 0, st.q)
        for c in s.sent:
            self.log.command(t_recv - self.t0, c.seq, c.flags, 0, 0, self._latency_us, c.q)
        s.sent = []

    def _open_toy_log(self) -> None:
        stamp = f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}-{time.monotonic_ns() % 10**9}"
        self._open_log(Path(self.cfg.log_dir) / f"toy-{stamp}.srvlog", {
            "model": self.profile.name, "protocol": "toy-udp-v1", "interval_ms": self.cfg.interval_ms,
            "axes": list(self.profile.axis_names), "robot": f"{self.cfg.host}:{self.cfg.port}",
            "commands": "all", "fixed_interval": True})
        self._logged_seq = None


def _pad(v: Any) -> np.ndarray:
    out = np.zeros(6)
    a = np.asarray(v, dtype=float)[:6]
    out[: a.size] = a
    return out


def _child_main(cfg_dict: dict[str, Any], conn: Connection, slot_name: str) -> None:
    # Module level, so the spawned child finds it by name: toy_backend must be importable there (spawn
    # hands the child the parent's sys.path, where pytest put tests/).
    run_child(conn, lambda: ToyHost(ToyConfig(**cfg_dict), conn, slot_name).run())


class ToyProcess(ServoProcessHandle):
    def __init__(self, cfg: ToyConfig, **watch: Any) -> None:
        super().__init__(cfg, _child_main, "toy servo process", **watch)


# ------------------------------------------------------------------------- embedded simulator

COMMAND_TIMEOUT_S = 0.5  # a stream whose commands stop: the controller stops the program


def _controller_main(host: str, port: int, model: str, interval_s: float, conn: Connection) -> None:
    """The toy controller: status every interval to whoever sent START, following its commands."""
    profile = load_toy_profile(model)
    vmax = np.array(profile.speed)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((host, port))
    conn.send(sock.getsockname()[:2])
    q = np.array(profile.home)
    peer: Any = None
    seq = flags = expect = 0
    next_t = last_cmd = 0.0

    def halt(why: str) -> None:  # the program stops: bit 0 falls (a real one would post an alarm)
        nonlocal flags
        flags &= ~WAITING
        print(f"toy controller: {why}", file=sys.stderr, flush=True)

    while True:
        now = time.monotonic()
        wait = max(0.0, next_t - now) if peer else 0.05
        ready, _, _ = select.select([sock, conn], [], [], wait)
        if conn in ready:
            with contextlib.suppress(EOFError, OSError):
                conn.recv()
            return  # "quit", or the parent is gone
        if sock in ready:
            data, addr = sock.recvfrom(256)
            now = time.monotonic()
            try:
                p = decode(data)
            except ValueError:
                continue
            if p.kind == START:  # whoever asks gets the status (a restarted servo process takes over)
                peer, seq, flags, expect, next_t = addr, 0, WAITING | READY, 1, now
            elif addr != peer:
                continue
            elif p.kind == STOP:
                peer = None
            elif p.kind == COMMAND and flags & WAITING:
                step = np.abs(np.array(p.q) - q)
                if p.seq != expect:
                    halt(f"command seq {p.seq}, expected {expect}")
                elif np.any(step > vmax * interval_s * 1.01 + 1e-9):
                    halt(f"command jumps {step.tolist()} mm in one interval")
                else:
                    q, expect, last_cmd = np.array(p.q), expect + 1, now
                    flags |= RECEIVED
                    if p.flags:  # last data: the program ends
                        flags &= ~WAITING
        if peer and flags & RECEIVED and flags & WAITING and now - last_cmd > COMMAND_TIMEOUT_S:
            halt(f"no command for {now - last_cmd:.3f} s")
            peer = None  # and the status output with it: the client is gone
        if peer and now >= next_t:
            seq += 1
            sock.sendto(Packet(STATUS, seq, flags, tuple(q)).encode(), peer)
            next_t = max(next_t + interval_s, now - interval_s)  # keep the rate, no burst after a stall


class ToyController:
    """The embedded simulator in a spawned process; ``address`` is where it serves."""

    def __init__(self, host: str, port: int, model: str, interval_ms: int = INTERVAL_MS) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_controller_main, args=(host, port, model, interval_ms / 1000, child),
                                   name="toy-controller", daemon=True)
        self._child = child
        self.address: tuple[str, int] = (host, port)

    def start(self, timeout: float = 30.0) -> ToyController:
        self.process.start()
        self._child.close()
        if not self._conn.poll(timeout):
            raise TimeoutError("the toy controller did not start")
        host, port = self._conn.recv()
        self.address = (str(host), int(port))
        return self

    def call(self, name: str, *args: Any, timeout: float = 5.0) -> Any:
        """The service's controls of an embedded simulator: the toy posts no alarms and has none to reset."""
        if name == "events":
            return []
        if name == "reset":
            return None
        raise RuntimeError(f"the toy controller has no control {name!r}")

    def stop(self, timeout: float = 5.0) -> None:
        with contextlib.suppress(OSError):
            self._conn.send("quit")
        self.process.join(timeout)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(2.0)
        self._conn.close()


# -------------------------------------------------------------------------------------- backend


class ToyBackend(RobotBackend):
    name = "toy"
    default_port = DEFAULT_PORT
    default_model = "toy1"

    @classmethod
    def models(cls) -> list[str]:
        return list(PROFILES)

    def load_profile(self, model: str) -> ToyProfile:
        return load_toy_profile(model)

    def make_process(self, target: Target, options: ProcessOptions, on_event: Callable[[Event], None],
                     on_exit: Callable[[str], None]) -> ToyProcess:
        # options.lead does not apply: the toy controller keeps no command buffer.
        return ToyProcess(ToyConfig(host=target.host, port=target.port, model=self.model, log_dir=options.log_dir,
                                    interval_ms=options.interval_ms or INTERVAL_MS,
                                    start_timeout_s=options.start_timeout_s), on_event=on_event, on_exit=on_exit)

    def start_simulator(self, target: Target, sim_options: dict[str, Any], realtime_priority: int | None) -> Any:
        return ToyController(target.host, target.port, self.model,
                             sim_options.get("interval_ms") or INTERVAL_MS).start()

    def axes(self) -> list[dict[str, Any]]:
        p = self.profile
        return [{"name": n, "unit": "mm", "min": lo, "max": hi, "speed": v}
                for n, lo, hi, v in zip(p.axis_names, p.axis_min, p.axis_max, p.speed, strict=True)]

    def robot_view(self, q: list[float]) -> dict[str, Any]:
        p = self.profile
        x, y = (float(v) for v in q[:N_AXES])
        return {
            "backend": self.name, "kind": "cartesian", "model": p.name, "display_name": p.display_name,
            "dof": N_AXES, "joint_names": list(p.axis_names), "axis_label": "Axis",
            "pose_names": list(p.axis_names), "pose_caption": "carriage X Y (mm): controller feedback",
            "axes": self.axes(), "j23_factor": 0.0,  # RobotView requires it (FANUC's); meaningless here
            "q": [x, y],
            "points": [{"name": "base", "xyz_mm": [0.0, 0.0, 0.0]}, {"name": "carriage", "xyz_mm": [x, y, 0.0]}],
            "view_box_mm": {"min": [*p.axis_min, 0.0], "max": [*p.axis_max, 0.0]},
        }

    def limits(self, state: dict[str, Any], options: ProcessOptions) -> dict[str, Any]:
        p = self.profile
        return {"model": p.name, "backend": self.name, "source": "profile (configured)",
                "axes": list(p.axis_names), "axis_min": list(p.axis_min), "axis_max": list(p.axis_max),
                "speed": list(p.speed), "accel": list(p.accel), "interval_ms": options.interval_ms or INTERVAL_MS}
