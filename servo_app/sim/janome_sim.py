"""The Janome robot simulator: plays the streaming point job as a TCP client of servo_app's server.

One daemon thread per simulator does what docs/janome_pointjob.txt does on the robot: ``connect``,
HELLO, then per loop wait (at most the ``setWTCOM`` time) for one target frame, check it, move (the
thread sleeps through the trapezoidal move, updating the position as it goes) or hold, and send the
next status. Faults to test with: :meth:`kill_link` (the socket is reset, mid-move if one is
running), :meth:`corrupt_next_status` / :meth:`corrupt_next_target` (one byte flipped on the wire),
:meth:`inject` (raw bytes to the server).

Standalone: ``servo-app sim janome --connect HOST:PORT --model jr3000|jc3|js3`` (see
:func:`add_janome_sim_parser` and :func:`run_janome_sim`).
"""

from __future__ import annotations

import argparse
import contextlib
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from servo_app.janome.profile import JanomeProfile, load_janome_profile
from servo_app.janome.protocol import Arm, ErrorCode, RobotKind
from servo_app.sim.janome_pointjob import Decision, PointJob, PointJobSettings
from servo_app.sim.janome_robot import JanomeRobot, MovePlan
from servo_app.stop_signals import stop_requested

_SLICE_S = 0.005  # how often a running move updates the position and checks for kill_link


@dataclass
class SimEvent:
    t: float
    kind: str  # connected, connect_failed, rejected, moved, bye, timeout, link_lost, killed, ended
    message: str = ""
    error: str = ""


class JanomeSimulator:
    """``sim = JanomeSimulator(("127.0.0.1", port), "js3").start()`` ... ``sim.stop()``."""

    def __init__(self, server: tuple[str, int], model: str | JanomeProfile = "jr3000", *,
                 start: tuple[float, ...] | None = None, elbow: int | None = None,
                 settings: PointJobSettings | None = None, connect_timeout_s: float = 5.0,
                 ptp_speed_fraction: float = 0.5, repeat: bool = False) -> None:
        self.server = server
        self.profile = model if isinstance(model, JanomeProfile) else load_janome_profile(model)
        self.robot = JanomeRobot(self.profile, start, elbow, ptp_speed_fraction)
        self.settings = settings or PointJobSettings()
        self.connect_timeout_s = connect_timeout_s
        self.repeat = repeat
        self.lock = threading.Lock()
        self.job = PointJob(self.robot, self.settings)
        self.moves = 0
        self._events: list[SimEvent] = []
        self._t0 = time.monotonic()
        self._stop = threading.Event()
        self._kill = threading.Event()
        self._corrupt_status = False
        self._corrupt_target = False
        self._sock: socket.socket | None = None
        self._thread = threading.Thread(target=self._run, name="janome-sim", daemon=True)
        self.done = threading.Event()  # the point job ended (BYE, timeout, link lost or killed)
        self.end_reason = ""
        self.plan: MovePlan | None = None

    # ------------------------------------------------------------------ control
    def start(self) -> JanomeSimulator:
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        self._thread.join(timeout)

    def __enter__(self) -> JanomeSimulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def kill_link(self) -> None:
        """Reset the TCP connection now (RST), as a pulled cable or a crashed controller would look."""
        self._kill.set()

    def corrupt_next_status(self) -> None:
        self._corrupt_status = True

    def corrupt_next_target(self) -> None:
        self._corrupt_target = True

    def inject(self, data: bytes) -> None:
        """Send raw bytes to the server (garbage, a forged frame)."""
        with self.lock:
            sock = self._sock
        if sock is not None:
            sock.sendall(data)

    def events(self, kind: str | None = None) -> list[SimEvent]:
        with self.lock:
            return [e for e in self._events if kind is None or e.kind == kind]

    @property
    def position(self) -> np.ndarray:
        with self.lock:
            return self.robot.position.copy()

    def wait_done(self, timeout: float) -> bool:
        return self.done.wait(timeout)

    # ------------------------------------------------------------------ thread
    def _event(self, kind: str, message: str = "", error: str = "") -> None:
        with self.lock:
            self._events.append(SimEvent(time.monotonic() - self._t0, kind, message, error))

    def _run(self) -> None:
        while not self._stop.is_set():
            reason = self._program()
            self.end_reason = reason
            self._event("ended", reason)
            if not self.repeat or self._kill.is_set():
                break
            self._stop.wait(0.5)  # the operator starts the program again
            self.job = PointJob(self.robot, self.settings)
        self.done.set()

    def _program(self) -> str:
        sock = self._connect()
        if sock is None:
            return "could not connect"
        try:
            return self._loop(sock)
        except OSError as exc:
            self._event("link_lost", f"{type(exc).__name__}: {exc}")
            return f"link lost: {exc}"
        finally:
            with self.lock:
                self._sock = None
            if self._kill.is_set():  # RST instead of FIN: the server sees a reset, not a clean close
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            with contextlib.suppress(OSError):
                sock.close()

    def _connect(self) -> socket.socket | None:
        deadline = time.monotonic() + self.connect_timeout_s
        while not self._stop.is_set():
            try:
                sock = socket.create_connection(self.server, timeout=1.0)
            except OSError as exc:
                if time.monotonic() > deadline:
                    self._event("connect_failed", str(exc))
                    return None
                self._stop.wait(0.05)
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(_SLICE_S)
            with self.lock:
                self._sock = sock
            self._event("connected", f"{self.server[0]}:{self.server[1]}")
            return sock
        return None

    def _send(self, sock: socket.socket, data: bytes) -> None:
        if self._corrupt_status:
            self._corrupt_status = False
            data = _flip(data)
        sock.sendall(data)

    def _loop(self, sock: socket.socket) -> str:
        job = self.job
        self._send(sock, job.hello())
        while True:
            d = self._wait_decision(sock, job)
            if isinstance(d, str):
                return d
            if d.kind == "end":
                self._send(sock, job.bye())
                self._event("bye", "END received")
                return "END received"
            if d.kind == "reject":
                self._event("rejected", d.message, d.error.name)
                self._send(sock, job.reject(d))
                if job.gave_up:
                    self._event("bye", f"{job.settings.max_errors} rejections in a row", d.error.name)
                    return f"gave up after {job.settings.max_errors} rejections"
                continue
            if d.kind == "hold":
                if self._sleep(self.settings.hold_delay_s):
                    return self._killed()
                self._send(sock, job.status())
                continue
            assert d.plan is not None
            t_move = self._move(d.plan)
            if t_move is None:
                return self._killed()
            self._send(sock, job.status(move_ms=round(t_move * 1000)))

    def _killed(self) -> str:
        self._event("killed", "link killed")
        return "link killed"

    def _wait_decision(self, sock: socket.socket, job: PointJob) -> Decision | str:
        """inCOM/cmpCOM with the setWTCOM timeout."""
        deadline = time.monotonic() + self.settings.receive_timeout_s
        while True:
            if self._kill.is_set() or self._stop.is_set():
                return self._killed() if self._kill.is_set() else "simulator stopped"
            with self.lock:
                d = job.decide()
            if d is not None:
                return d
            if time.monotonic() > deadline:
                self._send(sock, job.bye(ErrorCode.RX_TIMEOUT))
                self._event("timeout", f"no target within {self.settings.receive_timeout_s} s")
                return "receive timeout"
            try:
                data = sock.recv(8192)
            except TimeoutError:
                continue
            if not data:
                self._event("link_lost", "server closed the connection")
                return "server closed the connection"
            if self._corrupt_target:
                self._corrupt_target = False
                data = _flip(data)
            with self.lock:
                job.receive(data)

    def _move(self, plan: MovePlan) -> float | None:
        """Sleep through the move, updating the position; None if the link was killed meanwhile."""
        t0 = time.monotonic()
        self.plan = plan
        while True:
            t = time.monotonic() - t0
            with self.lock:
                self.robot.position = self.robot.at(plan, min(t, plan.duration))
            if t >= plan.duration:
                break
            if self._sleep(min(_SLICE_S, plan.duration - t)):
                return None
        with self.lock:
            self.robot.finish(plan)
            self.moves += 1
        self.plan = None
        return time.monotonic() - t0

    def _sleep(self, s: float) -> bool:
        """Sleep; True if the link was killed or the simulator stopped meanwhile."""
        end = time.monotonic() + s
        while True:
            if self._kill.is_set() or self._stop.is_set():
                return True
            left = end - time.monotonic()
            if left <= 0:
                return False
            time.sleep(min(left, _SLICE_S))


def _flip(data: bytes) -> bytes:
    """One byte changed inside the first frame's fields (the checksum then fails)."""
    b = bytearray(data)
    if len(b) > 20:
        b[20] ^= 0x5A
    return bytes(b)


# ---------------------------------------------------------------------------------- CLI


def add_janome_sim_parser(kinds: Any) -> argparse.ArgumentParser:
    """Register ``janome`` on the ``servo-app sim`` kinds subparsers (the lead's one-line hook)."""
    j = kinds.add_parser("janome", help="Janome JR3000 / JC-3 / JS3 point-job simulator (TCP client)")
    j.add_argument("--connect", required=True, metavar="HOST:PORT", help="servo_app's Janome link server")
    j.add_argument("--model", default="jr3000", help="Janome profile: jr3000, jc3, js3, or a TOML path")
    j.add_argument("--start", default=None, metavar="X,Y,Z,R", help="initial position (default: the profile's home)")
    j.add_argument("--elbow", choices=("righty", "lefty"), default=None, help="SCARA arm configuration")
    j.add_argument("--timeout-ms", type=int, default=2000, help="receive timeout, setWTCOM (default 2000)")
    j.add_argument("--hold-ms", type=int, default=50, help="delay after a HOLD before the next status (default 50)")
    j.add_argument("--max-errors", type=int, default=3, help="rejected frames in a row before BYE (default 3)")
    j.add_argument("--ptp-speed", type=float, default=0.5, help="PTP speed as a share of the axis maxima")
    j.add_argument("--repeat", action="store_true", help="start the point job again after it ends")
    j.set_defaults(handler=run_janome_sim)
    return j


def _host_port(spec: str) -> tuple[str, int]:
    host, sep, port = spec.rpartition(":")
    if not sep or not host:
        raise ValueError(f"--connect={spec!r}: expected HOST:PORT")
    try:
        return host, int(port)
    except ValueError:
        raise ValueError(f"--connect={spec!r}: port {port!r} is not a number") from None


def run_janome_sim(args: argparse.Namespace) -> int:
    """``servo-app sim janome``: run the point job against servo_app until it ends, Ctrl-C or SIGTERM."""
    from servo_app.robots.profile import ProfileError

    try:
        server = _host_port(args.connect)
        start = None if args.start is None else tuple(float(v) for v in args.start.split(","))
        elbow = None if args.elbow is None else int(Arm.RIGHTY if args.elbow == "righty" else Arm.LEFTY)
        settings = PointJobSettings(receive_timeout_s=args.timeout_ms / 1000.0, hold_delay_s=args.hold_ms / 1000.0,
                                    max_errors=args.max_errors)
        sim = JanomeSimulator(server, args.model, start=start, elbow=elbow, settings=settings,
                              ptp_speed_fraction=args.ptp_speed, repeat=args.repeat, connect_timeout_s=30.0)
    except (ValueError, ProfileError) as exc:
        print(f"servo-app sim janome: {exc}", file=sys.stderr)
        return 2
    p = sim.profile
    kind = "SCARA" if p.kind == RobotKind.SCARA else "cartesian"
    print(f"Janome point-job simulator ({p.display_name}, {kind}) connecting to {server[0]}:{server[1]}; "
          "Ctrl-C to stop", flush=True)
    seen = 0
    with stop_requested() as stop:
        sim.start()
        try:
            while not (sim.done.wait(0.2) or stop.is_set()):
                seen = _print_events(sim, seen)
        finally:
            sim.stop()
            _print_events(sim, seen)
            x, y, z, r = sim.position
            print(f"moves: {sim.moves}; position X {x:.3f} Y {y:.3f} Z {z:.3f} R {r:.3f}; ended: {sim.end_reason}",
                  flush=True)
    return 0


def _print_events(sim: JanomeSimulator, seen: int) -> int:
    events = sim.events()
    for e in events[seen:]:
        if e.kind != "moved":
            print(f"{e.t:9.3f} s  {e.kind:14s} {e.error} {e.message}".rstrip(), flush=True)
    return len(events)
