"""The FANUC controller simulator on a real UDP socket: a thin shell around FanucControllerModel.

Two daemon threads share one socket: the receiver hands every datagram to the model (and sends
its replies, the limit-table responses, back to the sender); the ticker calls ``model.tick`` on a
fixed grid of absolute deadlines and sends the status packet to the address the start packet came
from. All model access holds ``lock``; use the delegating methods (or hold ``sim.lock`` yourself).

Fault injection (status packets only, seeded RNG so runs repeat): drop, duplicate, delay by a
uniform extra time, follow with a malformed datagram (the status cut short), and tick jitter (each
tick at its grid time + U(-jitter, +jitter), so intervals range period +- 2 * jitter:
``jitter_s=0.001`` gives the FAQ's 6-10 ms at 8 ms).
"""

from __future__ import annotations

import contextlib
import heapq
import random
import select
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from types import TracebackType

from servo_app.fanuc.alarms import AlarmEvent
from servo_app.fanuc.packets import ROBOT_PORT
from servo_app.motion.limit_tables import LimitTables
from servo_app.robots.profile import RobotProfile
from servo_app.sim.fanuc_model import ControllerConfig, FanucControllerModel, stderr_line
from servo_app.sim.ticker import IntervalRecorder, IntervalStats, sleep_until


@dataclass(frozen=True)
class FaultConfig:
    drop_prob: float = 0.0
    dup_prob: float = 0.0
    delay_prob: float = 0.0
    delay_range_s: tuple[float, float] = (0.002, 0.020)
    jitter_s: float = 0.0
    # After a status packet, also send a malformed datagram (the status cut short) from the
    # controller's own address with this probability: what a corrupting link delivers.
    malformed_prob: float = 0.0
    seed: int | None = 0

    def __post_init__(self) -> None:
        for name in ("drop_prob", "dup_prob", "delay_prob", "malformed_prob"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name}={p} must be in 0..1")
        if self.jitter_s < 0:
            raise ValueError(f"jitter_s={self.jitter_s} must be >= 0")


class EventList(list[AlarmEvent]):
    """A snapshot of alarm events that reads both as a list and as a call: ``sim.alarms == []``,
    ``sim.alarms[0].message`` and ``sim.alarms()`` all work (callers of both forms exist)."""

    def __call__(self) -> EventList:
        return self


@dataclass
class FaultCounts:
    dropped: int = 0
    duplicated: int = 0
    delayed: int = 0
    malformed: int = 0


MIN_SPACING = 0.75  # least spacing between two ticks, as a share of the interval


class FanucSimulator:
    """``with FanucSimulator(port=0) as sim: addr = sim.address`` ..."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = ROBOT_PORT,
        model: str | RobotProfile = "lrmate200id",
        interval_ms: int | None = None,
        *,
        config: ControllerConfig | None = None,
        faults: FaultConfig | None = None,
        tables: LimitTables | None = None,
        initial_joints: Sequence[float] | None = None,
        log: Callable[[str], None] | None = stderr_line,
        spin_s: float = 0.0005,
    ) -> None:
        config = config or ControllerConfig()
        if interval_ms is not None:
            config = replace(config, interval_ms=interval_ms)
        self.controller = FanucControllerModel(model, config, tables=tables, initial_joints=initial_joints,
                                               log=log)
        self.faults = faults or FaultConfig()
        if self.faults.jitter_s >= self.controller.interval_s / 2:
            raise ValueError(f"jitter_s={self.faults.jitter_s} must be below half the interval")
        self.fault_counts = FaultCounts()
        self.lock = threading.RLock()
        self._bind = (host, port)
        self._sock: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._rng = random.Random(self.faults.seed)
        self._delayed: list[tuple[float, int, bytes, object]] = []
        self._delayed_n = 0
        self._recorder = IntervalRecorder()
        self.spin_s = spin_s

    # ---- lifecycle ------------------------------------------------------------------------------

    def start(self) -> FanucSimulator:
        if self._sock is not None:
            return self
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(self._bind)
        sock.settimeout(0.1)
        self._sock = sock
        self._stop.clear()
        self._threads = [threading.Thread(target=self._rx_loop, name="fanuc-sim-rx", daemon=True),
                         threading.Thread(target=self._tick_loop, name="fanuc-sim-tick", daemon=True)]
        for t in self._threads:
            t.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads = []
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> FanucSimulator:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    @property
    def address(self) -> tuple[str, int]:
        if self._sock is None:
            raise RuntimeError("simulator not started")
        host, port = self._sock.getsockname()[:2]
        return host, port

    @property
    def interval_s(self) -> float:
        return self.controller.interval_s

    # ---- threads --------------------------------------------------------------------------------

    def _rx_loop(self) -> None:
        sock = self._sock
        assert sock is not None
        while not self._stop.is_set():
            try:
                data, addr = sock.recvfrom(2048)
            except TimeoutError:
                continue
            except OSError:  # ICMP port unreachable from an earlier send, or the socket closed
                if self._stop.is_set():
                    return
                continue
            self._receive(data, addr)

    def _receive(self, data: bytes, addr: object) -> None:
        now = time.perf_counter()
        with self.lock:
            replies = self.controller.on_datagram(data, now, addr)
        for r in replies:
            self._send(r, addr)

    def _drain(self) -> None:
        """Take in every datagram already queued on the socket.

        A controller's network stack receives independently of its control cycle; here the receive
        thread may be waiting for the GIL, so the tick takes what has arrived before it judges the
        command buffer (else a client that answered in time would get MOTN-603).
        """
        sock = self._sock
        if sock is None:
            return
        # select, not MSG_DONTWAIT: with a socket timeout set, Python waits before it calls recvfrom.
        while select.select([sock], [], [], 0)[0]:
            try:
                data, addr = sock.recvfrom(2048)
            except OSError:
                return
            self._receive(data, addr)

    def _tick_loop(self) -> None:
        period = self.controller.interval_s
        jitter = self.faults.jitter_s
        t0 = time.perf_counter() + period
        k = 0
        target = t0
        while not self._stop.is_set():
            wake = min(target, self._delayed[0][0]) if self._delayed else target
            sleep_until(wake, self.spin_s)
            now = time.perf_counter()
            self._flush_delayed(now)
            if now < target:
                continue
            self._drain()
            with self.lock:
                pkt = self.controller.tick(now)
                addr = self.controller.status_addr
            self._recorder.mark(now)
            if pkt is not None and addr is not None:
                self._emit(pkt, addr, now)
            k += 1
            late_slots = int((now - (t0 + k * period)) // period)
            if late_slots > 0:  # held up for more than a period: skip, do not burst
                k += late_slots
                self._recorder.overruns += late_slots
            target = t0 + k * period + (self._rng.uniform(-jitter, jitter) if jitter else 0.0)
            # A late tick shifts the grid rather than being followed at once: the FAQ's controller
            # varies between 6 and 10 ms at 8 ms, it never sends two status packets back to back.
            shortfall = now + MIN_SPACING * period - target
            if shortfall > 0:
                t0 += shortfall
                target += shortfall

    def _emit(self, pkt: bytes, addr: object, now: float) -> None:
        f = self.faults
        if f.drop_prob and self._rng.random() < f.drop_prob:
            self.fault_counts.dropped += 1
            return
        copies = 2 if f.dup_prob and self._rng.random() < f.dup_prob else 1
        if copies == 2:
            self.fault_counts.duplicated += 1
        if f.delay_prob and self._rng.random() < f.delay_prob:
            self.fault_counts.delayed += 1
            due = now + self._rng.uniform(*f.delay_range_s)
            for _ in range(copies):
                self._delayed_n += 1
                heapq.heappush(self._delayed, (due, self._delayed_n, pkt, addr))
            return
        for _ in range(copies):
            self._send(pkt, addr)
        if f.malformed_prob and self._rng.random() < f.malformed_prob:
            self.fault_counts.malformed += 1
            self._send(pkt[: self._rng.randrange(1, len(pkt))], addr)

    def _flush_delayed(self, now: float) -> None:
        while self._delayed and self._delayed[0][0] <= now:
            _, _, pkt, addr = heapq.heappop(self._delayed)
            self._send(pkt, addr)

    def _send(self, data: bytes, addr: object) -> None:
        sock = self._sock
        if sock is None:
            return
        with contextlib.suppress(OSError):  # the client went away; a controller keeps sending
            sock.sendto(data, addr)  # type: ignore[arg-type]

    # ---- stats and controls (delegated to the model under the lock) -----------------------------

    def interval_stats(self) -> IntervalStats:
        return self._recorder.stats()

    @property
    def events(self) -> EventList:
        """Every alarm and warning so far (snapshot; also callable)."""
        with self.lock:
            return EventList(self.controller.events)

    @property
    def alarms(self) -> EventList:
        """The alarms (not warnings) so far (snapshot; also callable)."""
        with self.lock:
            return EventList(self.controller.alarms())

    @property
    def warnings(self) -> EventList:
        with self.lock:
            return EventList(self.controller.warnings())

    def start_program(self) -> bool:
        with self.lock:
            return self.controller.start_program()

    def abort_program(self) -> None:
        with self.lock:
            self.controller.abort_program()

    def set_mode(self, mode: str) -> None:
        with self.lock:
            self.controller.set_mode(mode)

    def set_payload(self, payload_kg: float | None) -> None:
        with self.lock:
            self.controller.set_payload(payload_kg)

    def set_override(self, pct: int) -> None:
        with self.lock:
            self.controller.set_override(pct)

    def reset(self) -> None:
        with self.lock:
            self.controller.reset()

    def set_joints(self, q_deg: Sequence[float]) -> None:
        with self.lock:
            self.controller.set_joints(q_deg)

    def jog_to(self, q_deg: Sequence[float], duration_s: float | None = None) -> float:
        with self.lock:
            return self.controller.jog_to(q_deg, duration_s)

    def wait_until(self, predicate: Callable[[FanucControllerModel], bool], timeout_s: float = 2.0) -> bool:
        """Poll ``predicate(model)`` under the lock until true or timeout; for tests and scripts."""
        deadline = time.monotonic() + timeout_s
        while True:
            with self.lock:
                if predicate(self.controller):
                    return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.002)
