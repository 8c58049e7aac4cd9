"""Prometheus metrics, rendered from the servo process's published state at each scrape.

The servo process keeps the counts (commands, latency buckets, late commands, stops); the API only
formats them, so a scrape costs one shared-memory read and never touches the cycle.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily, Metric

from servo_app.service.views import consistent
from servo_app.state import LATENCY_BUCKETS_US, MODES, PHASES

_COUNTERS = (
    ("servo_commands_sent", "commands_sent", "command packets sent since the servo process started"),
    ("servo_status_received", "status_received", "status packets received since the servo process started"),
    ("servo_status_lost", "status_lost", "status packets lost (gaps in the status sequence)"),
    ("servo_status_duplicated", "status_duplicated", "duplicated or reordered status packets"),
    ("servo_malformed_packets", "malformed", "datagrams from the controller that did not decode"),
    ("servo_late_commands", "late_commands", "commands sent over half an interval after their status (this session)"),
    ("servo_late_inputs", "late_inputs",
     "IK solves repeated for an input that reached the servo process during the solve"),
)


class _StateCollector:
    def __init__(self, snapshot: Callable[[], tuple[dict[str, Any], dict[str, int]]],
                 api_counts: dict[str, int], lock: threading.Lock) -> None:
        self._snapshot = snapshot
        self._api = api_counts
        self._lock = lock

    def describe(self) -> list[Metric]:
        return []  # unchecked collector: metrics are built at each collect

    def collect(self) -> Iterator[Metric]:
        state, stops = self._snapshot()
        # As GET /api/state shows it: READY beside a faulted link reads disconnected there, and did not here.
        state = consistent(dict(state), time.time())
        g = GaugeMetricFamily("servo_state", "1 for the current safety state", labels=["state"])
        for m in MODES:
            g.add_metric([m], 1.0 if state.get("state") == m else 0.0)
        yield g
        g = GaugeMetricFamily("servo_link", "1 for the current stream (link) phase", labels=["phase"])
        for p in PHASES:
            g.add_metric([p], 1.0 if state.get("link") == p else 0.0)
        yield g
        for name, key, doc in _COUNTERS:
            yield CounterMetricFamily(name, doc, value=float(state.get(key, 0)))
        hist = state.get("latency_hist") or [0] * (len(LATENCY_BUCKETS_US) + 1)
        buckets, total = [], 0
        for bound, n in zip((*LATENCY_BUCKETS_US, float("inf")), hist, strict=True):
            total += int(n)
            buckets.append(("+Inf" if bound == float("inf") else f"{bound / 1e6:g}", float(total)))
        yield HistogramMetricFamily(
            "servo_cycle_latency_seconds", "status packet receipt to command send, per command sent",
            buckets=buckets, sum_value=float(state.get("latency_sum_us", 0.0)) / 1e6)
        g = GaugeMetricFamily("servo_latency_quantile_seconds",
                              "status-to-command latency over the last 4096 commands", labels=["quantile"])
        for q, key in (("0.5", "latency_p50_us"), ("0.99", "latency_p99_us"), ("1", "latency_max_us")):
            g.add_metric([q], float(state.get(key, 0.0)) / 1e6)
        yield g
        if state["status_live"]:
            # Only while status packets arrive. Kept after they stopped, the last interval read as a
            # healthy link; 0 would be an interval that never was, and NaN spoils avg_over_time. Absent,
            # Prometheus marks the series stale: graphs show the gap, alerts on it resolve.
            yield GaugeMetricFamily("servo_status_interval_seconds", "last interval between status packets; "
                                    "absent while none arrive (no stream, a link fault)",
                                    value=float(state.get("status_interval_last_ms", 0.0)) / 1e3)
        yield GaugeMetricFamily("servo_at_rest", "1 when the commanded motion is at rest",
                                value=1.0 if state.get("at_rest") else 0.0)
        yield GaugeMetricFamily("servo_settled", "1 when the robot's reported position has stopped moving",
                                value=1.0 if state.get("settled") else 0.0)
        c = CounterMetricFamily("servo_alarms", "controller alarms and warnings by code", labels=["code"])
        for code, n in sorted((state.get("alarm_counts") or {}).items()):
            c.add_metric([code], float(n))
        yield c
        c = CounterMetricFamily("servo_faults", "faults by cause: the controller's alarm code, or what we "
                                "detected (status_lost, servo_process, ...)", labels=["cause"])
        for cause, n in sorted((state.get("fault_counts") or {}).items()):
            c.add_metric([cause], float(n))
        yield c
        yield CounterMetricFamily("servo_alarm_poll_failures", "reads of the embedded controller's alarm list "
                                  "that failed (no answer in time, a bad answer)",
                                  value=float(state.get("alarm_poll_failures", 0)))
        c = CounterMetricFamily("servo_stops", "stops by reason, without its particulars (the holder of a lost "
                                "lease, a limit's numbers): GET /api/state's stop_reason has them", labels=["reason"])
        for reason, n in sorted(stops.items()):
            c.add_metric([reason], float(n))
        yield c
        with self._lock:
            api = dict(self._api)
        c = CounterMetricFamily("servo_api_refused", "API requests refused, by why", labels=["why"])
        for why, n in sorted(api.items()):
            c.add_metric([why], float(n))
        yield c


class Metrics:
    def __init__(self, snapshot: Callable[[], tuple[dict[str, Any], dict[str, int]]]) -> None:
        self.registry = CollectorRegistry()
        self._lock = threading.Lock()
        self._api: dict[str, int] = {"rate_limited": 0, "unauthorized": 0, "no_lease": 0}
        self.registry.register(_StateCollector(snapshot, self._api, self._lock))

    def count(self, why: str) -> None:
        with self._lock:
            self._api[why] = self._api.get(why, 0) + 1

    def render(self) -> bytes:
        return generate_latest(self.registry)
