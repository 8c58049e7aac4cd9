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
import gc
import math
import os
import socket
import struct
import time
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from servo_app import messages as msg
from servo_app.errors import CommandRejected
from servo_app.fanuc.packets import (
    COMMAND_FORMAT_OFFSET,
    COMMAND_LAST_DATA_OFFSET,
    COMMAND_VALUES_OFFSET,
    COMMAND_WRITE_VALUE_OFFSET,
    ROBOT_PORT,
    SEQ_OFFSET,
    STATUS_BITS_OFFSET,
    STATUS_CARTESIAN_OFFSET,
    STATUS_IO_OFFSET,
    STATUS_JOINTS_OFFSET,
    STATUS_SIZE,
    STATUS_TIME_OFFSET,
    Status,
)
from servo_app.fanuc.session import MotionSource, Phase, SentCommand, SessionConfig
from servo_app.fanuc.supervisor import StreamSupervisor
from servo_app.input_slot import InputSlotReader
from servo_app.jit import kernel
from servo_app.messages import Ready
from servo_app.motion.mujoco_c import address_table, table_f1, table_f2, table_i1, table_u1
from servo_app.motion.servo import ServoCycle, ServoSettings
from servo_app.motion.settle import SettleDetector, settle_add
from servo_app.process_handle import ServoProcessHandle, ServoProcessHost, run_child
from servo_app.realtime import WakeLatencyHold, make_realtime
from servo_app.robots.conventions import matrix_to_xyzwpr
from servo_app.robots.profile import load_profile
from servo_app.safety import Mode
from servo_app.session_log import (
    KIND_COMMAND,
    KIND_STATUS,
    RECORD_DTYPE,
    RECORD_SIZE,
    command_record,
    end_note,
    note_records,
    payload_record,
    status_record,
    tables_note,
)
from servo_app.state import (
    FIELDS,
    LATENCY_BUCKETS_US,
    LINK_COUNTERS,
    LINK_COUNTERS_OF,
    MODES,
    OFFSET,
    PHASES,
    STATE_SIZE,
    StateVector,
    write_link_counters,
)

assert all(p.value in PHASES for p in Phase)
assert all(m.value in MODES for m in Mode)

# The modes in which a stream has run, looked at every loop iteration (an enum member looked up on its
# class costs ~0.1 us here, more with caches cold).
_STREAMED_MODES = (Mode.STREAMING, Mode.STOPPING, Mode.STOPPED, Mode.ENDING)
_STREAMING = Mode.STREAMING
# Disk space kept allocated past the session log's end, in seconds of statuses and their commands: when
# the disk fills up, the stream's stop and end (a few seconds at most) are still logged whole.
LOG_RESERVE_S = 10.0


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
    status_timeout_s: float = 0.1  # no status packet for this long while streaming: the link is lost
    link_timeout_s: float = 1.0  # no status packet for this long after status output start: no controller
    start_timeout_s: float = 5.0  # a start that is not streaming by then is given up, with the reason
    late_threshold_ms: float | None = None  # None: half an interval
    # An input that reaches the slot while the IK solves a status packet's command is solved into that
    # packet if the IK finished within this time of the packet's arrival (None: a quarter interval, so
    # that one more solve as long as the first still answers within half an interval; 0: never).
    late_input_ms: float | None = None
    realtime_priority: int | None = 20  # SCHED_FIFO priority for the servo process; None: leave as is
    wake_latency_us: int | None = 0  # CPU idle-state exit latency held while streaming; None: leave as is
    input_slot: str | None = None  # shared-memory name of the inputs bridge's live command
    data_format: str = "joint"  # "joint", or "cartesian": the flange pose of the shaped joints (format 0)
    # settled: every reported joint within settle_tol_deg over settle_window_s (servo lag after at_rest:
    # 0.2-0.3 deg, 1.4-1.9 mm at the flange, for 0.2 s with the simulator's servo model)
    settle_tol_deg: float = 0.005
    settle_window_s: float = 0.1
    extra: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------- child side


class _CommandHistory:
    """The last four commanded positions in a preallocated ring, and their finite differences as
    the controller computes them (``state.command_derivatives``, without allocating in the cycle)."""

    def __init__(self, dof: int, dt: float) -> None:
        self.dof, self.dt = dof, dt
        self.q = np.zeros((4, dof))
        # The row of q holding the newest command, and the commands since clear(): in an array, so that
        # one kernel per command (_command_into_state) adds to the ring too.
        self.at = np.zeros(2, dtype=np.int64)
        self.values = np.zeros(dof)  # a command's values as the kernels take them

    @property
    def newest(self) -> int:
        return int(self.at[0])

    @property
    def n(self) -> int:
        return int(self.at[1])

    def clear(self) -> None:
        self.at[1] = 0

    def add(self, values: tuple[float, ...] | list[float]) -> None:
        v = self.values
        v[:] = values[: self.dof]
        _history_add(self.q, self.at, v)

    def write(self, d: np.ndarray) -> None:
        """q_cmd, vel, acc and jerk into the state vector ``d`` (the same arithmetic as np.diff)."""
        _write_derivatives(self.q, self.at[0], self.dt, d, _Q_CMD, _VEL, _ACC, _JERK)


@kernel("void(float64[:, ::1], int64[::1], float64[:])")
def _history_add(q: np.ndarray, at: np.ndarray, values: np.ndarray) -> None:
    """``values[:dof]`` into the ring ``q`` as its newest row (``at``: that row, and the count since the
    clear); at the start, the first command stands in for the ones not sent yet (every row)."""
    n = q.shape[1]
    if values.size < n:
        raise ValueError("fewer command values than the history's axes")
    if at[1] == 0:
        for r in range(4):
            q[r, :] = values[:n]
    else:
        at[0] = (at[0] + 1) % 4
        q[at[0], :] = values[:n]
    at[1] += 1


@kernel("void(float64[:, ::1], int64, float64, float64[::1], int64, int64, int64, int64)")
def _write_derivatives(q: np.ndarray, newest: int, dt: float, d: np.ndarray, at_q: int, at_v: int, at_a: int,
                       at_j: int) -> None:
    """The newest of the four commands in ring ``q`` and its backward differences divided by ``dt``, in
    np.diff's order of operations (so the state shows exactly what command_derivatives computes)."""
    n = q.shape[1]
    r0, r1, r2, r3 = (newest + 1) % 4, (newest + 2) % 4, (newest + 3) % 4, newest  # oldest .. newest
    for i in range(n):
        v0 = (q[r1, i] - q[r0, i]) / dt
        v1 = (q[r2, i] - q[r1, i]) / dt
        v2 = (q[r3, i] - q[r2, i]) / dt
        a0 = (v1 - v0) / dt
        a1 = (v2 - v1) / dt
        d[at_q + i] = q[r3, i]
        d[at_v + i] = v2
        d[at_a + i] = a1
        d[at_j + i] = (a1 - a0) / dt


_Q_CMD, _VEL, _ACC, _JERK = (OFFSET[k] for k in ("q_cmd", "vel", "acc", "jerk"))


@kernel("void(float64[::1], int64, float64[::1], float64[::1], float64[::1])")
def _percentiles(ring: np.ndarray, n: int, quantiles: np.ndarray, scratch: np.ndarray, out: np.ndarray) -> None:
    """``out[k] = np.percentile(ring[:n], 100 * quantiles[k])`` (linear method, numpy's own arithmetic:
    index (n - 1) * q, its floor, and the lerp numpy uses on either side of one half), sorting a copy in
    ``scratch``; NaN if any sample is NaN."""
    a = scratch[:n]
    a[:] = ring[:n]
    a.sort()  # NaN last
    for k in range(quantiles.size):
        v = (n - 1) * quantiles[k]
        if math.isnan(a[n - 1]):
            out[k] = math.nan
        elif v >= n - 1:
            out[k] = a[n - 1]
        else:
            i = math.floor(v)
            g = v - i
            lo, hi = a[i], a[i + 1]
            diff = hi - lo
            out[k] = hi - diff * (1 - g) if g >= 0.5 else lo + diff * g


@kernel("void(float64[::1], int64, float64[::1], float64[::1])")
def _median_max(ring: np.ndarray, n: int, scratch: np.ndarray, out: np.ndarray) -> None:
    """``out[0] = np.median(ring[:n])`` (an even count: the mean of the middle two, as numpy takes it),
    ``out[1] = ring[:n].max()``; NaN if any sample is NaN."""
    a = scratch[:n]
    a[:] = ring[:n]
    a.sort()  # NaN last
    if math.isnan(a[n - 1]):
        out[0] = out[1] = math.nan
        return
    m = n // 2
    out[0] = a[m] if n % 2 else (a[m - 1] + a[m]) / 2.0
    out[1] = a[n - 1]


_P50_P99 = np.array([50.0, 99.0]) / 100  # as np.percentile divides them


class _Latency:
    """Status receipt to command send, last 4096 cycles, in a preallocated ring. Its percentiles by one
    compiled sort of a copy: over a full window 0.5-1 ms here with np.fromiter of a deque and
    np.percentile, every 16th command for the first 1024 (a 10 s run at 8 ms never left that regime).
    The count, maximum and late count live in ``stats`` so that one kernel per command updates them
    all (:func:`_command_into_state`)."""

    SIZE = 4096

    def __init__(self) -> None:
        self.ring = np.zeros(self.SIZE)
        self.scratch = np.empty(self.SIZE)  # the percentiles' sort
        self.out = np.zeros(2)  # (p50, p99)
        self.stats = np.zeros(3)  # samples ever added (those kept stop at 4096), maximum, late ones

    @property
    def count(self) -> int:
        return int(self.stats[_COUNT])

    @property
    def max_us(self) -> float:
        return float(self.stats[_MAX])

    @property
    def late(self) -> int:
        return int(self.stats[_LATE_COUNT])

    @property
    def samples(self) -> np.ndarray:
        """The samples kept (not in time order once the ring has wrapped)."""
        return self.ring[: min(self.count, self.SIZE)]

    def add(self, us: float, late_us: float) -> None:
        _latency_add(self.ring, self.stats, us, late_us)

    def percentiles(self) -> tuple[float, float]:
        """(p50, p99) of the samples kept, as np.percentile gives them."""
        n = min(self.count, self.SIZE)
        if n == 0:
            return 0.0, 0.0
        out = self.out
        _percentiles(self.ring, n, _P50_P99, self.scratch, out)
        return float(out[0]), float(out[1])


_COUNT, _MAX, _LATE_COUNT = 0, 1, 2  # _Latency.stats


@kernel("void(float64[::1], float64[::1], float64, float64)")
def _latency_add(ring: np.ndarray, stats: np.ndarray, us: float, late_us: float) -> None:
    """One latency sample into the ring and the count, maximum and late count of ``stats``."""
    n = int(stats[0])
    ring[n % ring.size] = us
    stats[0] = n + 1
    if us > stats[1]:
        stats[1] = us
    if us > late_us:
        stats[2] += 1


# The state vector's offsets _command_into_state writes, in this order. Passed to the kernel as an array,
# not read as globals: a compiled kernel keeps the globals it was compiled with in its on-disk cache,
# which is keyed on this file alone, so a layout change in state.py would go unseen.
_CMD_FIELDS = ("latency_hist", "latency_sum_us", "latency_p50_us", "latency_p99_us", "latency_last_us",
               "latency_max_us", "late_commands", "q_cmd", "vel", "acc", "jerk")


@kernel("void(float64[::1], int64[::1], float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], "
        "float64[::1], float64[:, ::1], int64[::1], float64[:], float64, float64, float64)")
def _command_into_state(d: np.ndarray, at: np.ndarray, buckets: np.ndarray, quantiles: np.ndarray,
                        ring: np.ndarray, stats: np.ndarray, scratch: np.ndarray, out: np.ndarray, q: np.ndarray,
                        q_at: np.ndarray, values: np.ndarray, lat_us: float, late_us: float, dt: float) -> None:
    """What a command that left changes in the state vector ``d`` (offsets ``at``: _CMD_FIELDS), in one
    call where a dozen Python operations took ~20 us a status here: its latency into the window
    (``ring``, ``stats``: _Latency), the histogram bucket (``bisect_left`` on ``buckets``: le semantics)
    and the sum, the percentiles when due, the figures, and its ``values`` into the command history
    (``q``, ``q_at``: _CommandHistory) with the derivatives. The same arithmetic, in the same order."""
    _latency_add(ring, stats, lat_us, late_us)
    k = 0
    while k < buckets.size and buckets[k] < lat_us:
        k += 1
    d[at[0] + k] += 1
    d[at[1]] += lat_us  # over the process's life: Prometheus wants counters that only grow
    # By count: the window's length stops at 4096, where "len % 16" held at every cycle. Over a
    # full window the percentiles cost 0.5-1 ms here (now ~0.1 ms compiled): every 256th command
    # (1-2 s) once it holds 1024, every 16th before, is as fresh as a display or a scrape needs.
    count = int(stats[0])
    if count % (16 if count < 1024 else 256) == 0:
        _percentiles(ring, min(count, ring.size), quantiles, scratch, out)
        d[at[2]] = out[0]
        d[at[3]] = out[1]
    d[at[4]] = lat_us
    d[at[5]] = stats[1]
    d[at[6]] = stats[2]
    _history_add(q, q_at, values)
    _write_derivatives(q, q_at[0], dt, d, at[7], at[8], at[9], at[10])


# What _exchange_into_state reads from the two datagrams (big-endian, packets.py), writes into the state
# vector and packs into the log (session_log.RECORD_DTYPE, little-endian), by offset in this order: an
# array, not globals baked into the cached kernel (see _CMD_FIELDS).
_EXCHANGE_FIELDS = (
    "status seq", "status bits", "status io", "status time", "status cartesian", "status joints", "command seq",
    "command last_data", "command format", "command write value", "command values", "record t", "record seq",
    "record flags", "record io", "record latency", "record values", "state q_servo", "state cart_servo",
    "state status_seq", "state status_bits", "state io_read_value", "state io_read_type", "state io_read_index",
    "state io_read_mask", "state status_unix", "state status_time_ms", "state status_interval_last_ms",
    "state link counters")
_BYTES = "Bytes(uint8, 1, 'C', readonly=True)"  # a bytes object as numba takes it: read where it lies
# The arrays _exchange_into_state reaches through its table of addresses (mujoco_c.address_table), in
# this order: one argument where they were 22, each of which numba's dispatch types and unboxes (the
# call cost ~46 us with caches cold here that way; see _ServoProcess._exchange_table). ``consts``: the
# late threshold (us), the interval (s), and the settle detector's window (s), tolerance and minimum count.
_EXCHANGE_ARRAYS: tuple[tuple[str, str, int], ...] = (
    ("d", "f", 1), ("at", "i", 1), ("log", "u", 1), ("bits", "f", 1), ("consts", "f", 1), ("settle_ts", "f", 1),
    ("settle_ps", "f", 2), ("settle_ring", "i", 1), ("cmd_at", "i", 1), ("buckets", "f", 1), ("quantiles", "f", 1),
    ("ring", "f", 1), ("stats", "f", 1), ("scratch", "f", 1), ("out", "f", 1), ("q", "f", 2), ("q_at", "i", 1))


@kernel(f"int64(int64[:, ::1], {_BYTES}, {_BYTES}, float64[:], UniTuple(int64, 5), float64, float64, float64, "
        "float64, float64)")
def _exchange_into_state(table: np.ndarray, status: bytes, command: bytes, values: np.ndarray,
                         link: tuple[int, ...], t0: float, t_status: float, t_command: float, last_status_t: float,
                         unix: float) -> int:
    """The usual exchange, a new status packet and the one command that answered it, in one call: the
    status's fields into the state vector ``d`` (offsets ``at``: _EXCHANGE_FIELDS) with its joints into
    the settle detector's ring (:func:`settle_add`, whose result it returns), the link counters, the
    two log records packed into ``log`` straight from the bytes that crossed the wire (``bits``: one
    float64 of scratch), and the command (its ``values`` as the history takes them) into the latency
    figures and history (:func:`_command_into_state`). The arrays through ``table`` (_EXCHANGE_ARRAYS).
    The same values, and the same log bytes, as the Python path (``_publish_status``, ``status_record``
    + ``command_record``, ``_command_sent``): tested.

    Why: those four steps as Python cost ~75 us a status here with caches cold, about a tenth of the
    servo process's CPU at 8 ms (issue 15)."""
    d, at, log, bits, consts = (table_f1(table, 0), table_i1(table, 1), table_u1(table, 2), table_f1(table, 3),
                                table_f1(table, 4))
    late_us, dt = consts[0], consts[1]
    b8 = bits.view(np.uint8)
    f32 = bits.view(np.float32)
    # The status: its fields, big-endian, into the state (as decode_from_robot gives them).
    o = at[0]
    seq = (status[o] << 24) | (status[o + 1] << 16) | (status[o + 2] << 8) | status[o + 3]
    o = at[2]
    io_type = status[o]
    io_index = (status[o + 1] << 8) | status[o + 2]
    io_mask = (status[o + 3] << 8) | status[o + 4]
    io_value = (status[o + 5] << 8) | status[o + 6]
    o = at[3]
    stamp = (status[o] << 24) | (status[o + 1] << 16) | (status[o + 2] << 8) | status[o + 3]
    for k in range(6):
        o = at[4] + 4 * k
        b8[0], b8[1], b8[2], b8[3] = status[o + 3], status[o + 2], status[o + 1], status[o]
        d[at[18] + k] = f32[0]
        o = at[5] + 4 * k
        b8[0], b8[1], b8[2], b8[3] = status[o + 3], status[o + 2], status[o + 1], status[o]
        d[at[17] + k] = f32[0]
    d[at[19]] = seq
    d[at[20]] = status[at[1]]
    d[at[21]] = io_value
    d[at[22]] = io_type
    d[at[23]] = io_index
    d[at[24]] = io_mask
    d[at[25]] = unix
    d[at[26]] = stamp
    if last_status_t:
        d[at[27]] = (t_status - last_status_t) * 1000
    for k in range(5):
        d[at[28] + k] = link[k]
    settled = settle_add(table_f1(table, 5), table_f2(table, 6), table_i1(table, 7), t_status, d[at[17]: at[17] + 6],
                         6, consts[2], consts[3], int(consts[4]))
    # The log: the status record, then the command record (session_log's layout, little-endian); the
    # big-endian u32, u16 and f32 of the datagrams byte-reversed, not decoded and encoded again.
    size = log.size // 2
    for r in range(2):
        src = status if r == 0 else command
        base = r * size
        log[base] = r  # KIND_STATUS, KIND_COMMAND
        bits[0] = (t_status if r == 0 else t_command) - t0
        for k in range(8):
            log[base + at[11] + k] = b8[k]
        o = at[0] if r == 0 else at[6]
        for k in range(4):
            log[base + at[12] + k] = src[o + 3 - k]
        if r == 0:
            log[base + at[13]] = status[at[1]]
            o = at[2] + 5  # the read I/O value
            f32[0] = 0.0
        else:
            log[base + at[13]] = command[at[7]] | (command[at[8]] << 1)
            o = at[9]
            f32[0] = np.float32((t_command - t_status) * 1e6)
        log[base + at[14]], log[base + at[14] + 1] = src[o + 1], src[o]
        for k in range(4):
            log[base + at[15] + k] = b8[k]
        o = at[5] if r == 0 else at[10]
        for k in range(9):
            for j in range(4):
                log[base + at[16] + 4 * k + j] = src[o + 4 * k + 3 - j]
    _command_into_state(d, table_i1(table, 8), table_f1(table, 9), table_f1(table, 10), table_f1(table, 11),
                        table_f1(table, 12), table_f1(table, 13), table_f1(table, 14), table_f2(table, 15),
                        table_i1(table, 16), values, (t_command - t_status) * 1e6, late_us, dt)
    return settled


class _TimeWindow:
    """The last ``size`` samples of a per-cycle time (us) in a preallocated ring; its median and maximum
    are refreshed every ``every`` samples, by one compiled call (np.median of 256 cost ~20 us: a few per
    second is plenty for a display, and nothing is computed in between). They are written into ``out``
    (2 floats: a view of the published state vector's p50 and max fields, so that the publish has
    nothing to copy from here per cycle)."""

    def __init__(self, size: int = 256, every: int = 64, out: np.ndarray | None = None) -> None:
        self.ring = np.zeros(size)
        self._scratch = np.empty(size)
        self.out = np.zeros(2) if out is None else out
        assert self.out.shape == (2,)
        self.size, self.every = size, every
        self.count = 0

    @property
    def p50_us(self) -> float:
        return float(self.out[0])

    @property
    def max_us(self) -> float:
        return float(self.out[1])

    def add(self, us: float) -> None:
        n = self.count
        self.ring[n % self.size] = us
        self.count = n = n + 1
        if n % self.every == 0:
            _median_max(self.ring, min(n, self.size), self._scratch, self.out)


class _TimedMotion:
    """The servo cycle as the stream session sees it, with the time of each ``next_command`` (the
    motion step: IK, shaper, guards) kept in ``window``. Two clock reads per command (~0.1 us)."""

    def __init__(self, cycle: MotionSource, window: _TimeWindow) -> None:
        self.cycle, self.window = cycle, window

    def begin(self, q_start: np.ndarray, tables: Any) -> None:
        self.cycle.begin(q_start, tables)

    def next_command(self, status: Status) -> np.ndarray:
        t = time.perf_counter()
        q = self.cycle.next_command(status)
        self.window.add((time.perf_counter() - t) * 1e6)
        return q

    def request_rest(self) -> None:
        self.cycle.request_rest()

    def at_rest(self) -> bool:
        return self.cycle.at_rest()


class _ServoProcess(ServoProcessHost):
    def __init__(self, cfg: StreamConfig, conn: Connection, slot_name: str) -> None:
        super().__init__(conn, slot_name)
        self.cfg = cfg
        self.profile = load_profile(cfg.model)
        self.dt = (cfg.interval_ms or self.profile.interval_ms) / 1000.0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect((cfg.host, cfg.port))
        # A blocking socket whose waits time out in the kernel (SO_RCVTIMEO, SO_SNDTIMEO: 20 ms): recv is
        # one recvfrom and send one sendto, where with settimeout Python polls before each (four system
        # calls a status packet instead of two). A signal interrupts the wait; Python runs its handler
        # and waits again (PEP 475), so a SIGTERM while no status comes is handled within 20 ms more.
        timeout = struct.pack("ll", 0, _SOCKET_TIMEOUT_US)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, timeout)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, timeout)
        settings = ServoSettings(limit_fraction=cfg.limit_fraction, flange_speed_cap=cfg.flange_speed_cap,
                                 payload_kg=cfg.payload_kg)
        self.cycle = ServoCycle(self.profile, self.dt, settings)
        self.sup = StreamSupervisor(self.cycle, SessionConfig(
            lead=cfg.lead, status_timeout_s=cfg.status_timeout_s, link_timeout_s=cfg.link_timeout_s,
            max_payload_kg=self.profile.max_payload_kg), start_timeout_s=cfg.start_timeout_s)
        # Per-cycle compute times, published (solve_*_us, cycle_*_us): the motion step per command, and
        # a status's whole handling here, from its receipt to the end of the loop's housekeeping. Each
        # window writes its median and maximum straight into the state vector when it refreshes them.
        d = self.state.data
        self.solve_time = _TimeWindow(out=d[_SOLVE_P50: _SOLVE_P50 + 2])
        self.cycle_time = _TimeWindow(out=d[_CYCLE_P50: _CYCLE_P50 + 2])
        self._tables_reported: object = None  # the controller's tables last sent to the parent
        self._replay_left_reported: object = None  # the replay whose leaving was last sent to the parent
        # The IK solved ahead, per solve (ServoCycle.solve_ahead)
        self.ahead_time = _TimeWindow(out=d[_AHEAD_P50: _AHEAD_P50 + 2])
        self._traj_published = False  # a replay's progress is in the state (traj_state not 0)
        self.session = self.sup.session
        self.session.motion = _TimedMotion(self.cycle, self.solve_time)
        self._handled_status = False  # this loop iteration handled a datagram (its cycle time is due)
        self.inputs = InputSlotReader(cfg.input_slot) if cfg.input_slot else None
        self._t_recv = 0.0  # when the status packet being answered arrived
        late_ms = self.dt * 1000 / 4 if cfg.late_input_ms is None else cfg.late_input_ms
        self.late_input_s = late_ms / 1000
        if self.inputs is not None and self.late_input_s > 0:
            self.cycle.late_command = self._late_input
        if cfg.data_format == "cartesian":
            kin = self.cycle.kin
            self.sup.session.to_cartesian = lambda q: matrix_to_xyzwpr(kin.fk_fanuc_deg(q))
        elif cfg.data_format != "joint":
            raise ValueError(f"data_format={cfg.data_format!r} must be 'joint' or 'cartesian'")
        self.latency = _Latency()
        # The latency histogram and sum (both kept in the state vector) are over the process's life:
        # Prometheus wants counters that only grow.
        self.late_us = (cfg.late_threshold_ms or self.dt * 1000 / 2) * 1000
        self.hist = _CommandHistory(6, self.dt)  # J1..J6 (the state's 6 slots): commanded velocity, acc., jerk
        self._limits_published: object = None  # the limits last written to the state (they change per stream)
        self._status_published: Status | None = None
        self.last_status_t = 0.0
        self._logged_seq: int | None = None
        self._log_streamed = False
        self._tool_name: str | None = None  # the active tool (SetTool's name), for the log's header
        self._tool_asked: str | None = None
        self._logged_payload: float | None = cfg.payload_kg  # the payload the open log has last said
        self.settle = SettleDetector(cfg.settle_tol_deg, cfg.settle_window_s)
        self._log_pair = np.zeros(2 * RECORD_SIZE, dtype=np.uint8)  # a status and its command, packed in place
        self._bits = np.zeros(1)  # _exchange_into_state's scratch
        self._exchange: np.ndarray | None = None  # its table (_exchange_table), made when first needed
        self._settle_seq: int | None = None

    # -- main loop
    def run(self) -> None:
        self._install_signals()
        # Warm up first: it is CPU-bound for most of a second, and at SCHED_FIFO it would starve every
        # normal process on its core (a simulator there went silent for 100 ms: MOTN-603).
        self._warm_up()
        realtime = make_realtime(self.cfg.realtime_priority)
        self.wake = WakeLatencyHold(self.cfg.wake_latency_us)
        # Objects made at start-up never become garbage: keep them out of the collector's scans.
        gc.collect()
        gc.freeze()
        self.serve(Ready(pid=os.getpid(), realtime=f"{realtime}; {self.wake.status}"))

    def _shutdown(self) -> None:
        if self.sup.session.output_on:
            # Leaving with the status output on (the parent died, or the link failed mid-shutdown):
            # switch it off, so the controller does not stream status to a socket nobody reads.
            with contextlib.suppress(OSError):
                self._send(self.sup.session.close_now())
        self.wake.close()
        if self.log is not None and not self._log_streamed:  # a start under way at the shutdown
            self._close_unstreamed_log("the servo process shut down before the stream started")
        self._close_log()
        self.sock.close()
        # Break runner <-> cycle (late_command is a bound method of this runner): gc.freeze() in run()
        # keeps that cycle from ever being collected, and its ruckig objects alive at exit printed
        # nanobind's "leaked instances" dump.
        self.cycle.late_command = None

    def _warm_up(self) -> None:
        """Run every per-cycle code path once before streaming: first calls pay for lazy set-up
        (numpy's percentile machinery alone took 6.6 ms here, enough to miss a 4 ms packet)."""
        window = _TimeWindow()
        for _ in range(window.every):  # np.median's first call
            window.add(1.0)
        cycle = ServoCycle(self.profile, self.dt, self.cycle.settings)
        q0 = np.zeros(self.profile.dof)
        q0[4] = -90.0  # wrist bent: a regular pose, away from every configuration boundary
        cycle.begin(q0, None)
        cycle.set_joint_target(q0 + 1.0)
        cycle.jog_joints(np.ones(self.profile.dof))
        for _ in range(3):
            cycle.next_command(Status(seq=1))
        cycle.stop(fast=False)
        cycle.next_command(Status(seq=1))
        self.hist.add(tuple(q0))
        self.hist.write(self.state.data)
        self._publish_backend(self.state)
        self.hist.clear()
        # The command's kernel (the latency window and the history within it), on figures thrown away.
        lat, hist = _Latency(), _CommandHistory(6, self.dt)
        _command_into_state(np.zeros(STATE_SIZE), _CMD_AT, _BUCKETS, _P50_P99, lat.ring, lat.stats, lat.scratch,
                            lat.out, hist.q, hist.at, hist.values, 100.0, self.late_us, self.dt)

    def _send(self, out: list[bytes]) -> None:
        for b in out:
            self.sock.send(b)

    def _io_step(self) -> None:
        sock = self.sock
        try:
            data = sock.recv(1024)
        except (BlockingIOError, ConnectionRefusedError):  # SO_RCVTIMEO passed (EAGAIN), or no controller
            data = b""
        now = time.monotonic()
        if data:
            self._t_recv = now
            # A stream's first command (the hold position) leaves before anything else happens on its
            # ready status: the packet was made while waiting (prepare_first_command), only the status's
            # sequence number and joints go in now.
            session = self.session
            first = None if session.first_command is None else session.first_command_early(data)
            t_first = 0.0
            if first is not None:
                sock.send(first)
                t_first = time.monotonic()
            if self.inputs is not None:  # the newest input before this status packet's command
                cmd = self.inputs.poll()
                if cmd is not None:
                    self.sup.on_input(cmd, now)
            for b in self.sup.on_datagram(data, now):
                sock.send(b)
            t_sent = time.monotonic()
            session.begin_motion()  # a stream's first commands (the hold) left first
            self._after_datagram(data, now, t_sent, t_first)
            self._handled_status = True
        else:
            self._send(self.sup.on_idle(now))

    def _housekeeping(self) -> None:
        super()._housekeeping()
        # Last, once requests and signals are in: the next status finds the first command ready if it
        # starts the stream.
        self.sup.prepare_first_command()
        if self._handled_status:
            self._handled_status = False
            self.cycle_time.add((time.monotonic() - self._t_recv) * 1e6)
        # Last of all, once this loop has read every request, signal and input it will read before the
        # next status packet: the next command's IK, so that the status finds it solved. The command
        # itself (shaper, guards) is still made on the status, from what holds then; a command changed
        # on the status (input slot, safety, hold-to-run) is solved afresh there, as without this.
        if self.session.streaming_motion:
            t = time.perf_counter()
            if self.cycle.solve_ahead():
                self.ahead_time.add((time.perf_counter() - t) * 1e6)

    def _deliver_signal(self, sig: int, now: float) -> None:
        self._send(self.sup.signal(sig, now))

    def _before_request(self, req: msg.Request) -> None:
        # The tool asked for becomes the active one once the request is taken (_after_request); a
        # refused one (no _after_request) is forgotten at the next request.
        self._tool_asked = req.name if isinstance(req, msg.SetTool) else None
        if isinstance(req, msg.Start):
            self._open_stream_log()

    def _after_request(self) -> None:
        self._send(self.sup._take())
        if self._tool_asked is not None:
            self._tool_name, self._tool_asked = self._tool_asked, None
        payload = self.cycle.settings.payload_kg
        if self.log is not None and payload != self._logged_payload:  # a tool change: into the log
            self._logged_payload = payload
            self.log.write_records([payload_record(time.monotonic() - self.t0, self._logged_seq or 0, payload)])

    def _late_input(self) -> None:
        """``ServoCycle.late_command``: the slot read again after each of the IK's solves.

        The solve takes most of the time between a status packet and its answer (about 1 ms here,
        with caches cold after the wait for the packet); a sensor frame that reached the slot meanwhile
        would otherwise wait a whole interval for the next packet. Taken only while the answer is still
        early (``late_input_ms`` after the packet arrived), and only when the motion asked for changed:
        a renewal of the same command is not worth another solve and waits for the next packet."""
        assert self.inputs is not None
        now = time.monotonic()
        if now - self._t_recv > self.late_input_s:
            return
        cmd = self.inputs.peek()
        if cmd is None or cmd.same_motion(self.inputs.current):
            return
        if self.sup.on_late_input(cmd, now):
            self.inputs.consume()

    def _after_datagram(self, data: bytes, t_recv: float, t_sent: float, t_first: float = 0.0) -> None:
        """Log what really crossed the wire: the status just received (once per sequence number) and
        the commands just sent for it (``t_first``: when the one sent ahead left). A malformed datagram
        leaves ``session.sent`` empty.

        What the commands change in the state goes into the vector here, once per status, not at every
        publish (the publish after a reply rewrote them unchanged): the latency figures, the histogram
        bucket by offset, and the commanded position's derivatives; and what the status changes (its
        fields, the link counters, the settle detector's window)."""
        s = self.session
        st = s.last_status
        sent = s.sent
        if (len(sent) == 1 and self.log is not None and st is not None and st is not self._status_published
                and st.seq != self._logged_seq and st.seq != self._settle_seq and len(data) == STATUS_SIZE):
            self._log_exchange(data, st, sent[0], t_recv, t_sent, t_first)  # the usual status and its command
        else:
            self._log_datagram(t_recv, t_sent, t_first)

    def _log_datagram(self, t_recv: float, t_sent: float, t_first: float) -> None:
        """``_after_datagram`` for any datagram: a status seen before, several commands or none, no log."""
        s = self.session
        st = s.last_status
        d = self.state.data
        write_link_counters(d, s.stats)  # (only a datagram changes them)
        if st is None:
            return
        if st is not self._status_published:  # a status became the session's last
            self._publish_status(d, st)
        if self.log is None:
            return
        records = []
        if st.seq != self._logged_seq:
            self._logged_seq = st.seq
            records.append(status_record(t_recv - self.t0, st.seq, st.status, st.read_io_value, st.joints))
            if self.last_status_t:
                d[_STATUS_INTERVAL] = (t_recv - self.last_status_t) * 1000
            self.last_status_t = t_recv
        sent = s.sent
        if not sent:
            if records:
                self.log.write_records(records)
            return
        for c in sent:
            t = t_first if c.early else t_sent
            lat_us = (t - t_recv) * 1e6
            records.append(command_record(t - self.t0, c.seq, c.last_data, c.data_format, c.write_io[3], lat_us,
                                          c.values))
            self._command_sent(d, c, lat_us)
        self.log.write_records(records)  # the status and its answers in one write, after they left
        s.sent = []

    def _log_exchange(self, data: bytes, st: Status, c: SentCommand, t_recv: float, t_sent: float,
                      t_first: float) -> None:
        """``_after_datagram`` for the usual exchange (a new status packet ``data``, decoded as ``st``, and
        the one command ``c`` that answered it): the log pair, the status's fields and the command's
        figures in one compiled call (:func:`_exchange_into_state`), then the one write."""
        self._status_published = st
        self._logged_seq = self._settle_seq = st.seq
        t = t_first if c.early else t_sent
        hist, settle = self.hist, self.settle
        values = c.array  # (as _command_sent takes them)
        if values is None or values.dtype is not _FLOAT64:
            values = hist.values
            values[:] = c.values[: hist.dof]
        table = self._exchange
        if table is None:
            table = self._exchange = self._exchange_table()
        r = _exchange_into_state(table, data, c.data, values, LINK_COUNTERS_OF(self.session.stats), self.t0, t_recv,
                                 t, self.last_status_t, time.time() - (time.monotonic() - t_recv))
        self.last_status_t = t_recv
        self.log.write_pair(self._log_pair)  # type: ignore[union-attr]
        if r < 0:  # the settle ring was full and nothing added: SettleDetector.add grows it and adds
            settle.add(t_recv, self.state.data[_Q_SERVO: _Q_SERVO + 6])
            self._exchange = None  # (its arrays are new)
        else:
            settle.settled = r == 1
        self.session.sent = []

    def _exchange_table(self) -> np.ndarray:
        """_exchange_into_state's table of the arrays it reaches, kept alive with it (made again when
        one of them is replaced: a new latency window, a grown settle ring)."""
        lat, hist, settle = self.latency, self.hist, self.settle
        ts, ps, ring = settle.buffers
        self._exchange_arrays = dict(
            d=self.state.data, at=_EXCHANGE_AT, log=self._log_pair, bits=self._bits,
            consts=np.array([self.late_us, self.dt, settle.window_s, settle.tol, settle.min_samples]),
            settle_ts=ts, settle_ps=ps, settle_ring=ring, cmd_at=_CMD_AT, buckets=_BUCKETS, quantiles=_P50_P99,
            ring=lat.ring, stats=lat.stats, scratch=lat.scratch, out=lat.out, q=hist.q, q_at=hist.at)
        return address_table(_EXCHANGE_ARRAYS, self._exchange_arrays)

    def _publish_status(self, d: np.ndarray, st: Status) -> None:
        """The fields of status ``st`` into the state vector, and for a new sequence number its joints
        into the settle detector (the feedback moved on, or did not)."""
        self._status_published = st
        # q_servo, then cart_servo, item by item: numpy's conversion of a tuple into a slice cost ~15 us
        # with caches cold here, twelve stores ~5 (/tmp microbenchmark, 64 MB touched between calls).
        q, c = st.joints, st.cartesian
        d[_Q_SERVO], d[_Q_SERVO + 1], d[_Q_SERVO + 2], d[_Q_SERVO + 3], d[_Q_SERVO + 4], d[_Q_SERVO + 5] = q[:6]
        d[_CART_SERVO], d[_CART_SERVO + 1], d[_CART_SERVO + 2], d[_CART_SERVO + 3], d[_CART_SERVO + 4], \
            d[_CART_SERVO + 5] = c[:6]
        if st.seq != self._settle_seq:
            self._settle_seq = st.seq
            self.settle.add(self._t_recv, d[_Q_SERVO: _Q_SERVO + 6])  # J1..J6 as just written, array to array
            d[_STATUS_UNIX] = time.time() - (time.monotonic() - self._t_recv)
            d[_STATUS_TIME] = st.timestamp_ms
        d[_STATUS_SEQ] = st.seq
        d[_STATUS_BITS] = st.status
        d[_IO_VALUE] = st.read_io_value
        d[_IO_TYPE] = st.read_io_type
        d[_IO_INDEX] = st.read_io_index
        d[_IO_MASK] = st.read_io_mask

    def _command_sent(self, d: np.ndarray, c: SentCommand, lat_us: float) -> None:
        """A command that left, into the latency figures and the command history, and both into the
        state vector (of several for one status, the last one's stand): one compiled call."""
        lat, hist = self.latency, self.hist
        values = c.array  # the kernel copies the history's row from it (numpy's copy: ~5-15 us, caches cold)
        if values is None or values.dtype is not _FLOAT64:  # (another float type: by numpy's conversion)
            values = hist.values
            values[:] = c.values[: hist.dof]
        _command_into_state(d, _CMD_AT, _BUCKETS, _P50_P99, lat.ring, lat.stats, lat.scratch, lat.out, hist.q,
                            hist.at, values, lat_us, self.late_us, self.dt)

    def _open_stream_log(self) -> None:
        """A new session log for the stream a start asks for; CommandRejected (the start refused, nothing
        changed) when it cannot be opened with LOG_RESERVE_S of records' disk space kept for it."""
        if self.log is not None:
            if self.log.trouble is None:
                return
            self._close_log()  # (a log in trouble takes no new stream: a new one, or the start refused)
        t0 = time.monotonic()
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = Path(self.cfg.log_dir) / f"session-{stamp}-{os.getpid()}-{int(t0 * 1000) % 100000}.srvlog"
        try:
            # The payload and tool: `servo-app check` judges at the tables the stream used (a light tool's
            # limits are above the maximum payload's); a tool change later is a payload record.
            payload = self.cycle.settings.payload_kg
            self._open_log(path, {"model": self.profile.name, "interval_ms": self.dt * 1000,
                                  "j23_factor": self.profile.j23_factor, "protocol": "fanuc-j519-v1",
                                  "robot": f"{self.cfg.host}:{self.cfg.port}", "commands": "joint_format",
                                  "fixed_interval": True, "payload_kg": payload,
                                  "max_payload_kg": self.profile.max_payload_kg, "tool": self._tool_name},
                           reserve_bytes=round(LOG_RESERVE_S / self.dt) * 2 * RECORD_SIZE)
        except OSError as exc:
            raise CommandRejected(
                f"start refused: the session log cannot be opened in {self.cfg.log_dir} with "
                f"{LOG_RESERVE_S:g} s of records' disk space kept for it ({exc}); free disk space there, "
                "then start again") from exc
        self._log_streamed = False
        self._logged_payload = payload
        self.t0 = t0
        self._log_tables()  # (tables read at an earlier start of this session)
        self.latency = _Latency()
        self._exchange = None  # (a new latency window)
        self.hist.clear()
        self._logged_seq = None

    def _on_link_phase(self, phase: str) -> None:
        tables = self.sup.session.tables
        if tables is not None and tables is not self._tables_reported:  # read at this start
            self._tables_reported = tables
            self._event(msg.LimitTablesReceived(tables=tables))
            self._log_tables()
        # A start from ended or disconnected reconnects (link -> connected) before the mode moves on:
        # only a stream that has run since the log opened may close it.
        if phase in (Phase.CLOSED, Phase.FAULT, Phase.CONNECTED) and self.sup.state.mode in (
                Mode.ENDED, Mode.FAULT, Mode.DISCONNECTED) and self._log_streamed:
            self._close_log()

    def _log_tables(self) -> None:
        """The controller's limit tables into the open log (a note): `servo-app check` and the MCAP
        export judge against the tables the stream moved within, not the profile's."""
        tables = self.sup.session.tables
        if self.log is not None and tables is not None:
            self.log.write_records(note_records(time.monotonic() - self.t0, tables_note(tables)))

    def _watch_link(self) -> None:
        if self.sup.state.mode in _STREAMED_MODES:
            self._log_streamed = True
        if self.sup.session.phase != self._last_phase:  # (the base's own test, without its call per cycle)
            super()._watch_link()
        # A start that was given up closes its log: the next start opens a new one.
        if (self.log is not None and not self._log_streamed and not self.sup.start_pending
                and self.sup.state.mode != _STREAMING):
            self._close_unstreamed_log()

    def _close_unstreamed_log(self, why: str = "") -> None:
        """Close the log of a start that never streamed. What came before the start was given up (status
        packets, the controller's tables) stays, ended by a note saying why; a log that holds nothing
        (a controller that never answered, a start refused at once) is deleted: its header alone
        recorded nothing, and GET /api/sessions listed it as a session."""
        log = self.log
        if log is not None and log.records and not log.failed:
            fault = self.sup.state.fault
            why = why or self.sup.start_error or (fault.message if fault else
                                                  f"the start was given up in {self.sup.state.mode.value}")
            log.write_records(note_records(time.monotonic() - self.t0, end_note(why, streamed=False)))
        self._close_log(remove_empty=True)

    # -- publishing
    def _publish_backend(self, sv: StateVector) -> None:
        # Straight into the vector by offset, nothing allocated: this runs once per cycle. What a status
        # and its commands change was written as they came and left (_after_datagram).
        d, c = sv.data, self.cycle
        d[_LATE_INPUTS] = c.late_inputs
        ik = c.last_ik if c.ik_active else None
        if ik is not None:
            d[_IK_ACTIVE], d[_IK_FLAGS], d[_IK_SCALE], d[_IK_CONDITION] = True, ik.flags, ik.scale, ik.condition
        else:
            d[_IK_ACTIVE], d[_IK_FLAGS], d[_IK_SCALE], d[_IK_CONDITION] = False, 0.0, 1.0, 0.0
        if c.limits is not None:
            at_rest = c.at_rest()
            d[_AT_REST] = at_rest
            d[_SETTLED] = at_rest and self.settle.settled
            d[_STOPPED] = c.stopped
            d[_TABLES_FROM_CONTROLLER] = c.tables_source == "controller"
            if c.limits is not self._limits_published:  # set once per stream (ServoCycle.begin)
                self._limits_published = c.limits
                vel_l, acc_l, jerk_l = c.limits
                sv.set("vel_limit", vel_l)
                sv.set("acc_limit", acc_l)
                sv.set("jerk_limit", jerk_l)
        replay = c.replay_player
        if c.replay_error and self._replay_left_reported is not replay:  # once per replay left
            self._replay_left_reported = replay
            self._event(msg.ReplayLeft(reason=c.replay_error, index=replay.index if replay is not None else 0))
        if replay is not None:  # a trajectory replay's progress (servo_app.motion.trajectory)
            d[_TRAJ] = replay.state
            d[_TRAJ + 1] = replay.tau
            d[_TRAJ + 2] = replay.total
            d[_TRAJ + 3] = replay.tau * self.dt
            d[_TRAJ + 4] = (replay.total - 1) * self.dt
            self._traj_published = True
        elif self._traj_published:  # none (any more): written once, not every cycle
            d[_TRAJ] = 0.0
            self._traj_published = False


_Q_SERVO, _CART_SERVO, _LAT_HIST = (OFFSET[k] for k in ("q_servo", "cart_servo", "latency_hist"))
_STATUS_INTERVAL = OFFSET["status_interval_last_ms"]
_TRAJ = OFFSET["traj_state"]  # traj_state, traj_index, traj_total, traj_time_s, traj_total_s in a row
(_STATUS_UNIX, _STATUS_TIME, _STATUS_SEQ, _STATUS_BITS, _IO_VALUE, _IO_TYPE, _IO_INDEX, _IO_MASK, _LATE_INPUTS,
 _SOLVE_P50, _SOLVE_MAX, _CYCLE_P50, _CYCLE_MAX, _AHEAD_P50, _AHEAD_MAX, _IK_ACTIVE, _IK_FLAGS, _IK_SCALE,
 _IK_CONDITION, _AT_REST, _SETTLED, _STOPPED, _TABLES_FROM_CONTROLLER, _LAT_P50, _LAT_P99, _LAT_SUM, _LAT_LAST,
 _LAT_MAX, _LATE) = (OFFSET[k] for k in (
    "status_unix", "status_time_ms", "status_seq", "status_bits", "io_read_value", "io_read_type", "io_read_index",
    "io_read_mask", "late_inputs", "solve_p50_us", "solve_max_us", "cycle_p50_us", "cycle_max_us",
    "solve_ahead_p50_us", "solve_ahead_max_us", "ik_active", "ik_flags", "ik_scale", "ik_condition", "at_rest",
    "settled", "stopped", "tables_from_controller", "latency_p50_us", "latency_p99_us", "latency_sum_us",
    "latency_last_us", "latency_max_us", "late_commands"))
assert FIELDS["latency_hist"].stop - _LAT_HIST == len(LATENCY_BUCKETS_US) + 1
assert _CART_SERVO == _Q_SERVO + 6  # written as one
_CMD_AT = np.array([OFFSET[k] for k in _CMD_FIELDS], dtype=np.int64)  # _command_into_state's offsets
_EXCHANGE_AT = np.array(
    [SEQ_OFFSET, STATUS_BITS_OFFSET, STATUS_IO_OFFSET, STATUS_TIME_OFFSET, STATUS_CARTESIAN_OFFSET,
     STATUS_JOINTS_OFFSET, SEQ_OFFSET, COMMAND_LAST_DATA_OFFSET, COMMAND_FORMAT_OFFSET, COMMAND_WRITE_VALUE_OFFSET,
     COMMAND_VALUES_OFFSET, *(RECORD_DTYPE.fields[k][1] for k in ("t", "seq", "flags", "io", "latency_us", "values")),
     _Q_SERVO, _CART_SERVO, _STATUS_SEQ, _STATUS_BITS, _IO_VALUE, _IO_TYPE, _IO_INDEX, _IO_MASK, _STATUS_UNIX,
     _STATUS_TIME, _STATUS_INTERVAL, OFFSET[LINK_COUNTERS[0]]], dtype=np.int64)
assert len(_EXCHANGE_AT) == len(_EXCHANGE_FIELDS)
assert RECORD_DTYPE.fields["kind"][1] == KIND_STATUS == 0 and KIND_COMMAND == 1  # (the kernel writes them so)
assert [OFFSET[k] for k in LINK_COUNTERS] == list(range(_EXCHANGE_AT[-1], _EXCHANGE_AT[-1] + 5))
_FLOAT64 = np.dtype(np.float64)
_BUCKETS = np.array(LATENCY_BUCKETS_US)  # the latency histogram's upper bounds, for the kernel
_SOCKET_TIMEOUT_US = 20_000  # a wait for a datagram: at most this long between housekeeping rounds
assert _SOLVE_MAX == _SOLVE_P50 + 1 and _CYCLE_MAX == _CYCLE_P50 + 1 and _AHEAD_MAX == _AHEAD_P50 + 1  # _TimeWindow.out


def _child_main(cfg_dict: dict[str, Any], conn: Connection, slot_name: str) -> None:
    run_child(conn, lambda: _ServoProcess(StreamConfig(**cfg_dict), conn, slot_name).run())


# -------------------------------------------------------------------------- parent side


class StreamProcess(ServoProcessHandle):
    """Parent-side handle of the FANUC servo process."""

    def __init__(self, cfg: StreamConfig, **watch: Any) -> None:
        super().__init__(cfg, _child_main, "servo process", **watch)
