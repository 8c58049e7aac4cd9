"""The Janome servo process: a TCP server for the robot's point job, the session, nothing else.

Mirrors ``servo_app.fanuc.runner``: the cycle lives in a process of its own (spawned), the parent talks
to it through a pipe (requests in, replies and events out) and reads its state from the same
shared-memory latest-value slot layout (``servo_app.state``; q_cmd = X Y Z R padded with zeros).

The robot is the TCP client (manual 21.1): the process listens on ``host:port`` and serves one
connection at a time; a second one is refused (closed at once) so two robots can never share a
stream. Per status frame: decode, compute, send, and only then publish and read the pipe.

SIGINT/SIGTERM end cleanly: no further step, END at rest, the robot's BYE, then exit.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import time
from collections import deque
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from servo_app import messages as msg
from servo_app.errors import CommandRejected
from servo_app.input_slot import InputSlotReader
from servo_app.janome.motion import JanomeMotion, MotionSettings
from servo_app.janome.profile import load_janome_profile
from servo_app.janome.protocol import Cmd, FrameError, Target
from servo_app.janome.session import Phase, SessionConfig
from servo_app.janome.supervisor import JanomeSupervisor
from servo_app.messages import PeerConnected, PeerDisconnected, PeerRefused, Ready
from servo_app.motion.settle import SettleDetector
from servo_app.process_handle import ServoProcessHandle, ServoProcessHost, run_child
from servo_app.safety import Mode, safe_to_exit
from servo_app.session_log import end_note, note_records
from servo_app.state import FIELDS, MODES, OFFSET, PHASES, StateVector, command_derivatives, write_link_counters

assert all(p.value in PHASES for p in Phase)
assert all(m.value in MODES for m in Mode)

# Disk space kept allocated past the connection log's end (a few frames a second: minutes of them), so
# that when the disk fills up the stream's end is still logged whole (see SessionLogWriter).
LOG_RESERVE_BYTES = 256 * 1024
DEFAULT_PORT = 10050  # any free port: the same number goes into the robot's client port settings


@dataclass
class JanomeConfig:
    host: str = "127.0.0.1"  # address to listen on (the robot connects here)
    port: int = DEFAULT_PORT  # 0: any free port (see JanomeProcess.address)
    model: str = "jr3000"  # Janome profile name or TOML path
    step_s: float | None = None  # None: the profile's link.step_s
    speed_fraction: float = 0.9
    move: str = "line"  # "line" (lineMove at the frame's speed) or "ptp" (moveAPTP, the robot's PTP condition)
    ptp_cond: int = 0
    status_timeout_s: float = 1.0  # beyond the expected move time
    handshake_timeout_s: float = 2.0
    hold_s: float = 0.5  # default hold-to-run for jogs (several link steps)
    publish_interval_s: float = 0.05
    log_dir: str = "var/sessions"  # every connection's exchange, per frame (servo_app/session_log.py)
    input_slot: str | None = None  # shared-memory name of the inputs bridge's live command
    # settled: X Y Z (mm) and R (deg) each within settle_tol over settle_window_s of statuses. The
    # status reports the position after the robot's last move, so at_rest (the last target sent)
    # comes one move early: 4 mm at jog speed here. A holding robot reports every ~0.05-0.1 s.
    settle_tol: float = 0.01
    settle_window_s: float = 0.25


# --------------------------------------------------------------------------- child side


class _JanomeServoProcess(ServoProcessHost):
    start_waits_for_stream = False  # the robot's point job connects when the operator runs it

    def __init__(self, cfg: JanomeConfig, conn: Connection, slot_name: str) -> None:
        super().__init__(conn, slot_name)
        self.cfg = cfg
        self.profile = load_janome_profile(cfg.model)
        if cfg.move not in ("line", "ptp"):
            raise ValueError(f"move={cfg.move!r} must be 'line' or 'ptp'")
        settings = MotionSettings(speed_fraction=cfg.speed_fraction,
                                  move=Cmd.LINE if cfg.move == "line" else Cmd.PTP, ptp_cond=cfg.ptp_cond)
        self.motion = JanomeMotion(self.profile, cfg.step_s, settings)
        self.sup = JanomeSupervisor(self.motion, SessionConfig(
            kind=self.profile.kind, status_timeout_s=cfg.status_timeout_s,
            handshake_timeout_s=cfg.handshake_timeout_s, cp_accel=self.profile.cp_accel,
            r_accel=self.profile.accel[3]), hold_s=cfg.hold_s)
        self.listener = socket.create_server((cfg.host, cfg.port), reuse_port=False)
        self.listener.setblocking(False)
        self.sock: socket.socket | None = None
        self.peer = ""
        self.lat_us: deque[float] = deque(maxlen=1024)
        self.lat_max = 0.0
        self.hist: deque[np.ndarray] = deque(maxlen=4)
        self.last_status_t = 0.0
        self._last_pub = 0.0
        self._logged_seq: int | None = None
        self._logged_targets = False  # a target frame was logged on this connection
        self.inputs = InputSlotReader(cfg.input_slot) if cfg.input_slot else None
        self.settle = SettleDetector(cfg.settle_tol, cfg.settle_window_s)
        self._settle_seq: int | None = None

    # -- main loop
    def run(self) -> None:
        self._install_signals()
        self.serve(Ready(pid=os.getpid(), address=tuple(self.listener.getsockname()[:2])))  # type: ignore[arg-type]

    def _shutdown(self) -> None:
        self._close_conn("servo process exiting", notify=False)
        self.listener.close()

    def _io_step(self) -> None:
        rlist: list[Any] = [] if self.parent_gone else [self.conn]
        if self.sup.session.accepting and not self.sup.state.shutdown:  # shutting down: no new robot
            rlist.append(self.listener)
        if self.sock is not None:
            rlist.append(self.sock)
        try:
            ready, _, _ = select.select(rlist, [], [], 0.02)
        except InterruptedError:
            ready = []
        if self.sock is not None and self.sock in ready:
            self._read()
        if self.listener in ready:
            self._accept()
        self.sup.on_idle(time.monotonic())

    def _deliver_signal(self, sig: int, now: float) -> None:
        self.sup.signal(sig, now)

    def _before_request(self, req: msg.Request) -> None:
        # The connection's log takes its streams: none starts once it is in trouble (a full disk).
        if isinstance(req, msg.Start) and self.log is not None and self.log.trouble is not None:
            raise CommandRejected(f"start refused: the session log {self.log.path.name} cannot take a stream "
                                  f"({self.log.trouble}); free disk space in {self.cfg.log_dir}, then let the "
                                  "robot reconnect")

    def _after_request(self) -> None:
        self._maybe_close()

    def _housekeeping(self) -> None:
        super()._housekeeping()
        self._maybe_close()
        if self.sup.state.shutdown and safe_to_exit(self.sup.state) and self.sock is not None:
            # Nothing left to stream: hang up, so the robot's point job sees the end (its inCOM times out
            # or its socket closes) and this process can exit.
            self._close_conn("servo_app is shutting down", notify=True)

    def _publish(self) -> None:
        # Frames come a few times a second: publish on each (in _read) and otherwise at a fixed rate.
        if self.sup.changed or time.monotonic() - self._last_pub >= self.cfg.publish_interval_s:
            super()._publish()

    def _accept(self) -> None:
        try:
            sock, addr = self.listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        peer = f"{addr[0]}:{addr[1]}"
        if self.sock is not None:  # one robot per stream
            sock.close()
            self._event(PeerRefused(peer=peer, reason=f"already serving {self.peer}"))
            return
        try:  # every frame of a connection is logged: no connection without its log
            self._open_connection_log(peer)
        except OSError as exc:
            sock.close()
            self._event(PeerRefused(peer=peer, reason=(
                f"the session log cannot be opened in {self.cfg.log_dir} with {LOG_RESERVE_BYTES // 1024} KiB "
                f"of disk space kept for it ({exc}); free disk space there, then let the robot reconnect")))
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.sock, self.peer = sock, peer
        self.settle.reset()  # another connection: its feedback is watched afresh
        self._settle_seq = None
        self.sup.on_connect(time.monotonic())
        self._event(PeerConnected(peer=peer))

    def _read(self) -> None:
        assert self.sock is not None
        try:
            data = self.sock.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # reset by the peer, or the cable
            self._lost(f"{type(exc).__name__}: {exc}")
            return
        if not data:
            self._lost("the robot closed the connection")
            return
        t_recv = time.monotonic()
        if self.inputs is not None:  # the newest input before this status frame's answer
            cmd = self.inputs.poll()
            if cmd is not None:
                self.sup.on_input(cmd, t_recv)
        out = self.sup.on_bytes(data, t_recv)
        us = 0.0
        if out:
            try:
                self.sock.sendall(b"".join(out))
            except OSError as exc:
                self._lost(f"send failed: {exc}")
                return
            us = (time.monotonic() - t_recv) * 1e6
            self.lat_us.append(us)
            self.lat_max = max(self.lat_max, us)
        self._log_exchange(t_recv, out, us)
        st = self.sup.session.last_status
        if st is not None and st.seq != self._settle_seq:  # a new status: where the last move ended
            self._settle_seq = st.seq
            self.settle.add(t_recv, st.xyzr)
            self.state.data[OFFSET["status_unix"]] = time.time() - (time.monotonic() - t_recv)
        if st is not None:
            if self.last_status_t:
                self.state.data[OFFSET["status_interval_last_ms"]] = (t_recv - self.last_status_t) * 1000
            self.last_status_t = t_recv
        if self.motion.last is not None:
            self.hist.append(self.motion.last.copy())
        ServoProcessHost._publish(self)

    def _log_exchange(self, t_recv: float, out: list[bytes], latency_us: float) -> None:
        """One record per new robot status and per target frame sent (the shared .srvlog format: flags
        hold the robot state for a status, and stop | cmd << 1 for a target)."""
        log = self.log
        if log is None:
            return
        st = self.sup.session.last_status or self.sup.session.refused_hello
        t = t_recv - self.t0
        if st is not None and st.seq != self._logged_seq:
            self._logged_seq = st.seq
            log.status(t, st.seq, int(st.state) & 0xFF, int(st.error) & 0xFFFF, st.xyzr)
        for frame in out:
            try:
                tg = Target.decode(frame)
            except FrameError:
                continue
            log.command(t, tg.seq, int(tg.stop), int(tg.cmd), 0, latency_us, (tg.x, tg.y, tg.z, tg.r))
            self._logged_targets = True

    def _open_connection_log(self, peer: str) -> None:
        path = Path(self.cfg.log_dir) / f"janome-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.srvlog"
        self._open_log(path, {"model": self.profile.name, "protocol": "janome-pointjob-v1",
                              "axes": ["X", "Y", "Z", "R"], "peer": peer, "commands": "all",
                              "fixed_interval": False}, reserve_bytes=LOG_RESERVE_BYTES)
        self._logged_seq = None
        self._logged_targets = False

    def _lost(self, reason: str) -> None:
        self._close_conn(reason, notify=True)

    def _close_conn(self, reason: str, notify: bool) -> None:
        if self.sock is None:
            return
        with contextlib.suppress(OSError):
            self.sock.close()
        self.sock = None
        # The log ends saying why (its records are what was exchanged); a connection that brought no
        # frame leaves none: a header alone records nothing, and the log list showed it as a session.
        log = self.log
        if log is not None and log.records and not log.failed:
            log.write_records(note_records(time.monotonic() - self.t0, end_note(reason, self._logged_targets)))
        self._close_log(remove_empty=True)
        if notify:
            self.sup.on_disconnect(reason, time.monotonic())
            self._event(PeerDisconnected(peer=self.peer, reason=reason))

    def _maybe_close(self) -> None:
        s = self.sup.session
        if s.want_close and self.sock is not None:
            self._close_conn(s.fault_reason or s.stats.last_error or "closed by servo_app", notify=True)

    # -- publishing
    def _publish_backend(self, sv: StateVector) -> None:
        # Straight into the vector by offset, as FANUC's: the slot then takes it in its one write.
        self._last_pub = time.monotonic()
        d, s, m, F = sv.data, self.sup.session, self.motion, OFFSET
        st = s.last_status
        if st is not None:
            d[F["status_seq"]] = st.seq
            d[F["status_bits"]] = int(st.state) | int(st.error) << 8
            q = d[_Q_SERVO: _Q_SERVO + 6]
            q[:4] = st.xyzr
            q[4:] = 0.0
            d[_CART_SERVO: _CART_SERVO + 6] = (st.x, st.y, st.z, 0.0, 0.0, st.r)
        write_link_counters(d, s.stats)
        if self.lat_us:
            a = np.fromiter(self.lat_us, float)
            d[F["latency_last_us"]] = a[-1]
            d[F["latency_p50_us"]], d[F["latency_p99_us"]] = np.percentile(a, [50, 99])
            d[F["latency_max_us"]] = self.lat_max
        at_rest = m.at_rest()
        d[F["at_rest"]] = at_rest
        d[F["settled"]] = at_rest and self.settle.settled
        d[F["stopped"]] = m.stopped
        _put(d, "vel_limit", m.vel)
        _put(d, "acc_limit", m.acc)
        _put(d, "jerk_limit", m.jerk)
        if self.hist:
            for key, value in command_derivatives(self.hist, m.step_s).items():
                _put(d, key, value)


_Q_SERVO, _CART_SERVO = OFFSET["q_servo"], OFFSET["cart_servo"]


def _put(d: np.ndarray, name: str, v: Any) -> None:
    """A vector field of up to 6 values (X Y Z R here), the rest zero."""
    sl = FIELDS[name]
    a = np.asarray(v, dtype=float).reshape(-1)[: sl.stop - sl.start]
    d[sl.start: sl.start + a.size] = a
    d[sl.start + a.size: sl.stop] = 0.0


def _child_main(cfg_dict: dict[str, Any], conn: Connection, slot_name: str) -> None:
    run_child(conn, lambda: _JanomeServoProcess(JanomeConfig(**cfg_dict), conn, slot_name).run())


# -------------------------------------------------------------------------- parent side


class JanomeProcess(ServoProcessHandle):
    """Parent-side handle of the Janome servo process; ``address`` is where it listens for the robot."""

    def __init__(self, cfg: JanomeConfig, **watch: Any) -> None:
        super().__init__(cfg, _child_main, "janome servo process", **watch)
        self.address: tuple[str, int] = (cfg.host, cfg.port)

    def start(self, timeout: float = 30.0) -> Ready:
        ev = super().start(timeout)
        assert ev.address is not None
        self.address = (str(ev.address[0]), int(ev.address[1]))
        return ev
