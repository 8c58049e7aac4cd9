"""The servo process's published state: a fixed float64 layout with named fields.

The servo process writes one vector per cycle into a :class:`~servo_app.ipc.LatestValueSlot`; the API
process reads it and turns it into a dict. Adding a field means adding a line here, nothing else.
"""

from __future__ import annotations

from typing import Any

import numpy as np

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
    ("latency_last_us", 1),
    ("latency_p50_us", 1),
    ("latency_p99_us", 1),
    ("latency_max_us", 1),
    ("status_interval_last_ms", 1),
    ("io_read_value", 1),
    ("at_rest", 1),
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
]


def _build() -> tuple[dict[str, slice], int]:
    out, i = {}, 0
    for name, n in _FIELDS:
        out[name] = slice(i, i + n)
        i += n
    return out, i


FIELDS, STATE_SIZE = _build()
VECTOR_FIELDS = {name for name, n in _FIELDS if n > 1}


class StateVector:
    """A writable state vector with attribute-like access by field name."""

    def __init__(self) -> None:
        self.data = np.zeros(STATE_SIZE)

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
    for k in ("at_rest", "stopped", "tables_from_controller"):
        out[k] = bool(out[k])
    for k in ("status_seq", "status_bits", "commands_sent", "status_received", "status_lost", "status_duplicated",
              "malformed", "late_commands", "io_read_value"):
        out[k] = int(out[k])
    return out
