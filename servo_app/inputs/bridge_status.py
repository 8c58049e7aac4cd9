"""What the inputs bridge reports: per-source rate, age, staleness and errors (JSON-ready rows)."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from servo_app.inputs.bridge import InputsBridge


def finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), 6)


class RateMeter:
    """Samples per second per source over a sliding window, from the slots' sequence counters."""

    def __init__(self, window_s: float = 2.0, every_s: float = 0.05) -> None:
        self.window_s = window_s
        self.every_s = every_s
        self._hist: deque[tuple[float, dict[str, int]]] = deque()

    def sample(self, now: float, counts: Mapping[str, int]) -> None:
        if self._hist and now - self._hist[-1][0] < self.every_s:
            return
        self._hist.append((now, dict(counts)))
        while len(self._hist) > 2 and now - self._hist[1][0] >= self.window_s:
            self._hist.popleft()

    def rate(self, name: str, now: float, count: int) -> float:
        if not self._hist:
            return 0.0
        t0, counts = self._hist[0]
        span = now - t0
        return (count - counts.get(name, 0)) / span if span > 1e-3 else 0.0


def _age(slot: Any, now: float) -> float | None:
    cur = slot.read()
    if cur is None:
        return None
    stamp = getattr(cur.value, "stamp", cur.stamp)  # the sample's own time (apps shift the slot stamp)
    return finite_or_none(max(0.0, now - stamp))


def source_rows(bridge: InputsBridge, now: float, rates: RateMeter) -> list[dict[str, Any]]:
    active = bridge.arbiter.active
    rows: list[dict[str, Any]] = []

    def row(name: str, role: str, type_: str, kind: str, slot: Any, stale_after: float, **extra: Any) -> None:
        rows.append({"name": name, "role": role, "type": type_, "kind": kind,
                     "rate_hz": round(rates.rate(name, now, slot.seq), 2), "age_s": _age(slot, now),
                     "stale": slot.age(now) > stale_after, "stale_after_s": stale_after, "active": name == active,
                     "commands": name in bridge.specs, "samples": slot.seq, **extra})

    for a in bridge.adapters:
        st = a.status(now)
        row(a.name, "adapter", a.config.type, bridge.kinds.get(a.name, "unknown"), a.output, a.stale_after_s,
            connected=st.connected, connects=st.connects, scheduling=a.scheduling, errors=dict(st.problems),
            last_error=st.last_problem.message if st.last_problem else None)
    for s in bridge.feeds.all_stats():
        cfg = bridge.feeds.config(s.source)
        row(s.source, "feed", cfg.kind, cfg.kind, bridge.feeds.slot(s.source), cfg.stale_after_s,
            errors={k: v for k, v in (("rejected", s.rejected), ("out_of_order", s.out_of_order)) if v},
            last_error=s.last_error, latency_ms={"last": finite_or_none(s.latency_ms_last),
                                                 "mean": finite_or_none(s.latency_ms_mean),
                                                 "max": finite_or_none(s.latency_ms_max)})
    for app in bridge.apps:
        counts, recent = app.problems.snapshot()
        row(app.name, "application", app.type_name, app.output_kind, app.output,
            app.stale_after_s, errors=dict(counts), last_error=recent[-1].message if recent else None)
    return rows
