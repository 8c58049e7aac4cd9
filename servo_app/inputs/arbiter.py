"""Which source commands the robot right now.

A source is live when it is enabled, allowed by the current owner (if any), and its newest sample
is younger than its staleness timeout. The highest-priority live source wins; on equal priority the
source already in control keeps it, so two equal sources never flap. A source marked
`yield_when_idle` (a SpaceMouse at rest) only takes or holds control while its sample is non-zero
(or holds a stop the operator asked for), but still counts as live so nothing is reported stale.

When the source that was in control stops being live because its samples aged out, the decision
says so once (`went_stale`); with nothing else live `active` is None and the caller decelerates.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from servo_app.inputs.adapter import Clock, SourceSpec


@dataclass(frozen=True)
class Decision:
    active: str | None
    sample: Any | None
    age_s: float | None
    previous: str | None  # the source in control before this call, if it changed
    went_stale: str | None  # the source in control before, now stale: decelerate from its command
    live: tuple[str, ...]
    changed: bool = False  # control moved this call (including from or to nobody)

    @property
    def decelerate(self) -> bool:
        return self.active is None


class Arbiter:
    def __init__(self, sources: Iterable[SourceSpec] = (), *, clock: Clock = time.monotonic) -> None:
        self._clock = clock
        self._sources: dict[str, SourceSpec] = {}
        self._disabled: set[str] = set()
        self._owner: str | None = None
        self._active: str | None = None
        self._lock = threading.Lock()
        for s in sources:
            self.add(s)

    def add(self, spec: SourceSpec) -> None:
        with self._lock:
            if spec.name in self._sources:
                raise ValueError(f"source {spec.name!r} already added")
            self._sources[spec.name] = spec

    def remove(self, name: str) -> None:
        with self._lock:
            self._sources.pop(name, None)
            self._disabled.discard(name)

    def enable(self, name: str, on: bool = True) -> None:
        with self._lock:
            self._require(name)
            (self._disabled.discard if on else self._disabled.add)(name)

    def set_owner(self, name: str | None) -> None:
        """Give one source exclusive control (e.g. the holder of the control lease); None = all."""
        with self._lock:
            if name is not None:
                self._require(name)
            self._owner = name

    @property
    def active(self) -> str | None:
        return self._active

    @property
    def owner(self) -> str | None:
        return self._owner

    def _require(self, name: str) -> None:
        if name not in self._sources:
            raise KeyError(f"unknown source {name!r}; known: {sorted(self._sources)}")

    def select(self, now: float | None = None) -> Decision:
        now = self._clock() if now is None else now
        with self._lock:
            live: list[tuple[SourceSpec, Any, float]] = []
            stale_names: set[str] = set()
            for spec in self._sources.values():
                if spec.name in self._disabled or (self._owner is not None and spec.name != self._owner):
                    continue
                cur = spec.slot.read()
                age = spec.slot.age(now)
                if cur is None or age > spec.stale_after_s:
                    stale_names.add(spec.name)
                    continue
                live.append((spec, cur.value, age))

            engaged = [x for x in live if not (x[0].yield_when_idle and _idle(x[1]))]
            pool = engaged or live
            winner = None
            if pool:
                top = max(x[0].priority for x in pool)
                best = [x for x in pool if x[0].priority == top]
                # The incumbent keeps control among equals; otherwise the first configured wins.
                winner = next((x for x in best if x[0].name == self._active), best[0])

            previous = self._active
            self._active = winner[0].name if winner else None
            changed = previous != self._active
            return Decision(
                active=self._active,
                sample=winner[1] if winner else None,
                age_s=winner[2] if winner else None,
                previous=previous if changed else None,
                went_stale=previous if changed and previous in stale_names else None,
                live=tuple(x[0].name for x in live),
                changed=changed,
            )


def _idle(sample: Any) -> bool:
    holds = getattr(sample, "holds_control", None)
    if callable(holds) and holds():  # a stop button: zero, and no one else takes the arm meanwhile
        return False
    is_zero = getattr(sample, "is_zero", None)
    return bool(is_zero()) if callable(is_zero) else False
