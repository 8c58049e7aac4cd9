"""Prometheus metrics: gauges from the servo state, counters kept by the API."""

from __future__ import annotations

from collections import Counter
from typing import Any

from prometheus_client import CollectorRegistry, Gauge, generate_latest
from prometheus_client import Counter as PCounter

from servo_app.state import PHASES


class Metrics:
    def __init__(self) -> None:
        r = self.registry = CollectorRegistry()
        self.phase = Gauge("servo_phase", "1 for the current stream phase", ["phase"], registry=r)
        self.latency = Gauge("servo_latency_us", "status receipt to command send, microseconds", ["quantile"],
                             registry=r)
        self.late = Gauge("servo_late_commands", "commands sent later than half an interval", registry=r)
        self.lost = Gauge("servo_status_lost", "status packets lost (sequence gaps)", registry=r)
        self.dup = Gauge("servo_status_duplicated", "duplicated or reordered status packets", registry=r)
        self.sent = Gauge("servo_commands_sent", "command packets sent this session", registry=r)
        self.stops = Gauge("servo_stops", "stops by reason", ["reason"], registry=r)
        self.jog_rejected = PCounter("servo_jog_rate_limited", "jog requests refused by the rate limit",
                                     registry=r)
        self.interval = Gauge("servo_status_interval_ms", "last status packet interval", registry=r)

    def render(self, state: dict[str, Any], stops: Counter[str]) -> bytes:
        for p in PHASES:
            self.phase.labels(p).set(1.0 if state.get("phase") == p else 0.0)
        for q, key in (("0.5", "latency_p50_us"), ("0.99", "latency_p99_us"), ("1", "latency_max_us")):
            self.latency.labels(q).set(state.get(key, 0.0))
        self.late.set(state.get("late_commands", 0))
        self.lost.set(state.get("status_lost", 0))
        self.dup.set(state.get("status_duplicated", 0))
        self.sent.set(state.get("commands_sent", 0))
        self.interval.set(state.get("status_interval_last_ms", 0.0))
        for reason, n in stops.items():
            self.stops.labels(reason).set(n)
        return generate_latest(self.registry)
