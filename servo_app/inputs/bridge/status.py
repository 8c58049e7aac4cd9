"""What the inputs bridge reports: per-source rate, age, staleness and errors (JSON-ready rows).

Pure: the rows are built from what they are given (`Sources`, `Reported`); nothing here imports the
bridge. The caller takes its lock around what the bridge's pass changes.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Protocol

from servo_app.input_slot import InputCommand
from servo_app.inputs.adapter import InputAdapter, SourceSpec
from servo_app.inputs.apps.base import Application
from servo_app.inputs.arbiter import Arbiter
from servo_app.inputs.feed import FeedRegistry
from servo_app.inputs.problems import ProblemLog

SUMMARY_KEYS = ("name", "kind", "rate_hz", "age_s", "stale", "active", "latency_ms", "failure")


class Sources(Protocol):
    """The sources a report lists (the bridge's wiring)."""

    adapters: Sequence[InputAdapter]
    feeds: FeedRegistry
    kinds: Mapping[str, str]
    apps: Sequence[Application]
    specs: Mapping[str, SourceSpec]  # the sources that command


class Reported(Protocol):
    """What the bridge's views show besides the rows."""

    enabled: bool
    arbiter: Arbiter
    slot_name: str
    source_names: Sequence[str]
    published: int
    stale_events: Counter[str]
    actions: Iterable[dict[str, Any]]
    problems: ProblemLog


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


def source_rows(src: Sources, active: str | None, now: float, rates: RateMeter) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []

    def row(name: str, role: str, type_: str, kind: str, slot: Any, stale_after: float, **extra: Any) -> None:
        rows.append({"name": name, "role": role, "type": type_, "kind": kind,
                     "rate_hz": round(rates.rate(name, now, slot.seq), 2), "age_s": _age(slot, now),
                     "stale": slot.age(now) > stale_after, "stale_after_s": stale_after, "active": name == active,
                     "commands": name in src.specs, "samples": slot.seq, **extra})

    for a in src.adapters:
        st = a.status(now)
        row(a.name, "adapter", a.config.type, src.kinds.get(a.name, "unknown"), a.output, a.stale_after_s,
            connected=st.connected, connects=st.connects, scheduling=a.scheduling, errors=dict(st.problems),
            last_error=st.last_problem.message if st.last_problem else None,
            failure=st.failure.view() if st.failure is not None else None)
    for s in src.feeds.all_stats():
        cfg = src.feeds.config(s.source)
        row(s.source, "feed", cfg.kind, cfg.kind, src.feeds.slot(s.source), cfg.stale_after_s,
            errors={k: v for k, v in (("rejected", s.rejected), ("out_of_order", s.out_of_order),
                                       ("resyncs", s.resyncs)) if v},
            last_error=s.last_error, latency_ms={"last": finite_or_none(s.latency_ms_last),
                                                 "mean": finite_or_none(s.latency_ms_mean),
                                                 "max": finite_or_none(s.latency_ms_max)})
    for app in src.apps:
        counts, recent = app.problems.snapshot()
        row(app.name, "application", app.type_name, app.output_kind, app.output,
            app.stale_after_s, errors=dict(counts), last_error=recent[-1].message if recent else None)
    return rows


def application_rows(apps: Iterable[Application]) -> list[dict[str, Any]]:
    return [{"name": a.name, "type": a.type_name, "priority": a.priority,
             "sources": {r: i.source for r, i in a.inputs.items()}, **a.describe()} for a in apps]


def summary_view(b: Reported, rows: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """Short, for GET /api/state (the console polls it): sources with rate, age and staleness."""
    return {"enabled": b.enabled, "active": b.arbiter.active, "owner": b.arbiter.owner,
            "sources": [{k: r[k] for k in SUMMARY_KEYS if k in r} for r in rows]}


def describe_view(b: Reported, now: float, rows: list[dict[str, Any]], apps: list[dict[str, Any]],
                  last: InputCommand | None) -> dict[str, Any]:
    """Everything, for GET /api/inputs: sources with errors, applications, the last command."""
    names = b.source_names
    return {
        "enabled": b.enabled, "active": b.arbiter.active, "owner": b.arbiter.owner,
        "slot": b.slot_name,
        "servo_sources": names, "sources": rows, "applications": apps,
        "published": b.published, "stale_events": dict(b.stale_events), "button_actions": list(b.actions),
        "bridge_problems": dict(b.problems.snapshot()[0]),
        "last_command": None if last is None else {
            "kind": ("none", "twist", "pose")[last.kind], "source": names[last.source]
            if 0 <= last.source < len(names) else None, "frame": last.frame,
            "values": list(last.values), "stale": last.stale, "age_s": finite_or_none(now - last.stamp)},
    }
