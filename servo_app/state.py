"""The servo process's published state: a fixed float64 layout with named fields.

The servo process writes one vector per cycle into a :class:`~servo_app.ipc.LatestValueSlot`; the API
process reads it and turns it into a dict. Adding a field means adding a line here, nothing else.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any

import numpy as np

# Upper bounds (us) of the status-to-command latency histogram; one more bucket counts the rest.
# Dense around the usual 0.2-1 ms, then out to the 8 ms interval where a command is surely late.
LATENCY_BUCKETS_US = (100.0, 200.0, 300.0, 400.0, 500.0, 750.0, 1000.0, 1500.0, 2000.0, 3000.0, 4000.0,
                      6000.0, 8000.0)

# The link (stream session) phases and the safety modes, by index.
PHASES = ("idle", "fetching_tables", "connected", "waiting_ready", "streaming", "ending", "closed", "fault")
MODES = ("disconnected", "connected", "ready", "streaming", "stopping", "stopped", "ending", "ended", "fault")

_FIELDS: list[tuple[str, int]] = [
    ("published_unix", 1),
    ("phase", 1),
    ("mode", 1),
    ("session_time", 1),
    ("status_seq", 1),
    ("status_bits", 1),
    ("commands_sent", 1),
    ("status_received", 1),
    ("status_lost", 1),
    ("status_duplicated", 1),
    ("malformed", 1),
    ("late_commands", 1),
    ("late_inputs", 1),  # solves again for an input that reached the slot during the solve
    # Per-cycle compute times over the last 256 (median, maximum; 0 until there are 64): the motion step
    # per command (IK, shaper, guards), and a status packet's whole handling in the servo process, from
    # its receipt to the end of that loop's housekeeping (decode, safety, send, log, publish, requests).
    ("solve_p50_us", 1),
    ("solve_max_us", 1),
    ("cycle_p50_us", 1),
    ("cycle_max_us", 1),
    # The IK solved ahead between status packets (ServoCycle.solve_ahead), per solve: not in solve_*.
    ("solve_ahead_p50_us", 1),
    ("solve_ahead_max_us", 1),
    ("ik_active", 1),  # the last cycle was a Cartesian one (twist, pose target, braking on its path)
    ("ik_flags", 1),  # its IkFlag bits
    ("ik_scale", 1),  # the share of the commanded motion it delivered
    ("ik_condition", 1),  # condition number of the normalised flange Jacobian
    ("latency_last_us", 1),
    ("latency_p50_us", 1),
    ("latency_p99_us", 1),
    ("latency_max_us", 1),
    ("status_interval_last_ms", 1),
    ("io_read_value", 1),
    ("io_read_type", 1),  # the read I/O the status echoes, so a reader knows what the value is of
    ("io_read_index", 1),
    ("io_read_mask", 1),
    ("latency_sum_us", 1),  # over the servo process's life, never reset (Prometheus counters)
    ("latency_hist", len(LATENCY_BUCKETS_US) + 1),  # commands per latency bucket, not cumulative in le
    ("at_rest", 1),
    ("settled", 1),  # the robot's feedback has stopped moving too (servo_app.motion.settle)
    ("status_unix", 1),  # wall clock when the last status arrived (0: none from this process)
    ("status_time_ms", 1),  # the controller's own time stamp in that status (-1: it has none)
    ("stopped", 1),
    ("tables_from_controller", 1),
    ("q_cmd", 6),
    ("q_servo", 6),
    ("cart_servo", 6),
    ("vel", 6),
    ("acc", 6),
    ("jerk", 6),
    ("vel_limit", 6),
    ("acc_limit", 6),
    ("jerk_limit", 6),
    # A trajectory replay (servo_app.motion.trajectory.ReplayPlayer): its state (PLAYER_STATES index,
    # 0 none), the sample played and their count, and the same in seconds.
    ("traj_state", 1),
    ("traj_index", 1),
    ("traj_total", 1),
    ("traj_time_s", 1),
    ("traj_total_s", 1),
]


def _build() -> tuple[dict[str, slice], int]:
    out, i = {}, 0
    for name, n in _FIELDS:
        out[name] = slice(i, i + n)
        i += n
    return out, i


FIELDS, STATE_SIZE = _build()
VECTOR_FIELDS = {name for name, n in _FIELDS if n > 1}
# Each field's first index, for publishers that write ``data[OFFSET[name]]`` straight (once per cycle:
# StateVector.set's lookup and type test per field were half of the FANUC servo process's publish).
OFFSET: dict[str, int] = {name: sl.start for name, sl in FIELDS.items()}


# The link counters every backend's session keeps under these names (its ``stats``).
LINK_COUNTERS = ("commands_sent", "status_received", "status_lost", "status_duplicated", "malformed")


LINK_COUNTERS_OF = operator.attrgetter(*LINK_COUNTERS)  # a session's stats -> the counters' tuple
_AT_LINK = OFFSET[LINK_COUNTERS[0]]
assert [OFFSET[name] for name in LINK_COUNTERS] == list(range(_AT_LINK, _AT_LINK + 5))


def write_link_counters(data: np.ndarray, stats: object) -> None:
    """A session's link counters, straight into a state vector's data (a servo process's publish, once
    per cycle: one attrgetter call where a loop of getattr and offset look-ups took six)."""
    data[_AT_LINK], data[_AT_LINK + 1], data[_AT_LINK + 2], data[_AT_LINK + 3], data[_AT_LINK + 4] = (
        LINK_COUNTERS_OF(stats))


class StateVector:
    """A writable state vector with attribute-like access by field name."""

    def __init__(self) -> None:
        self.data = np.zeros(STATE_SIZE)
        self.set("status_time_ms", -1.0)

    def set(self, name: str, value: float | np.ndarray) -> None:
        sl = FIELDS[name]
        if isinstance(value, np.ndarray):
            self.data[sl.start: sl.start + value.size] = value
        else:
            self.data[sl.start] = value


def decode_state(data: np.ndarray) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, sl in FIELDS.items():
        if name in VECTOR_FIELDS:
            out[name] = [float(v) for v in data[sl]]
        else:
            out[name] = float(data[sl.start])
    out["link"] = PHASES[int(out.pop("phase"))]
    out["state"] = MODES[int(out.pop("mode"))]
    for k in ("at_rest", "settled", "stopped", "tables_from_controller", "ik_active"):
        out[k] = bool(out[k])
    out["status_time_ms"] = int(out["status_time_ms"]) if out["status_time_ms"] >= 0 else None
    for k in ("status_seq", "status_bits", "commands_sent", "status_received", "status_lost", "status_duplicated",
              "malformed", "late_commands", "late_inputs", "io_read_value", "io_read_type", "io_read_index",
              "io_read_mask", "ik_flags"):
        out[k] = int(out[k])
    out["latency_hist"] = [int(v) for v in out["latency_hist"]]
    out["trajectory"] = trajectory_progress(out)
    return out


def trajectory_progress(s: dict[str, Any]) -> dict[str, Any] | None:
    """A replay's progress from the decoded fields (None: no replay in this stream)."""
    from servo_app.motion.trajectory import PAUSED, PLAYER_STATES

    code = int(s.get("traj_state", 0))
    if code <= 0 or code >= len(PLAYER_STATES):
        return None
    return {"state": PLAYER_STATES[code], "index": int(s["traj_index"]), "total": int(s["traj_total"]),
            "time_s": round(float(s["traj_time_s"]), 4), "total_s": round(float(s["traj_total_s"]), 4),
            "paused": code == PAUSED}


def command_derivatives(history: Sequence[np.ndarray], dt: float) -> dict[str, np.ndarray]:
    """The newest commanded position and its velocity, acceleration and jerk as the controller
    computes them: finite differences over the last four commands at the fixed interval ``dt``
    (at the start, the first command stands in for the ones not sent yet)."""
    h = list(history)[-4:]
    q = np.array([h[0]] * (4 - len(h)) + h)
    v = np.diff(q, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    return {"q_cmd": q[-1], "vel": v[-1], "acc": a[-1], "jerk": j[-1]}
