"""Watchdogs that turn time into safety events; pure, evaluated with an explicit ``now`` (seconds).

Each watch is an immutable value: ``renew``/``seen``/``received`` return a new one. All three fire
when an age is *greater* than its timeout, and all fail safe: a non-finite ``now`` counts as expired,
and a non-finite or older timestamp never refreshes a watch. StalenessWatch and StatusWatch are
level-triggered (they keep reporting while the condition holds; the transition function treats
repeats as no-ops); HoldToRun.poll releases itself, so one held jog expires once.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType

from servo_app.safety.events import InputStale, JogExpired, StatusLost


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")


def _later(old: float | None, now: float) -> float | None:
    """The refreshed timestamp: never NaN/inf, never moving backwards."""
    if not math.isfinite(now):
        return old
    return now if old is None else max(old, now)


@dataclass(frozen=True)
class HoldToRun:
    """Jog only while the operator keeps asking: each jog renews a deadline ``timeout_s`` ahead."""

    timeout_s: float
    last_renewed: float | None = None  # None: no jog held

    def __post_init__(self) -> None:
        _positive("timeout_s", self.timeout_s)

    @property
    def held(self) -> bool:
        return self.last_renewed is not None

    @property
    def deadline(self) -> float | None:
        return None if self.last_renewed is None else self.last_renewed + self.timeout_s

    @classmethod
    def renewed(cls, timeout_s: float, now: float) -> HoldToRun:
        """``HoldToRun(timeout_s).renew(now)`` in one construction: a twist starts one at every renewal."""
        return cls(timeout_s, _later(None, now))

    def renew(self, now: float) -> HoldToRun:
        # (by the constructor, not dataclasses.replace: a twist renews it 20 times a second, and replace
        # reads the fields anew each time)
        return HoldToRun(self.timeout_s, _later(self.last_renewed, now))

    def active(self, now: float) -> bool:
        """A jog may drive motion now."""
        return self.held and not self.expired(now)

    def release(self) -> HoldToRun:
        return HoldToRun(self.timeout_s)

    def expired(self, now: float) -> bool:
        if self.last_renewed is None:
            return False
        return not math.isfinite(now) or now - self.last_renewed > self.timeout_s

    def poll(self, now: float) -> tuple[HoldToRun, JogExpired | None]:
        """Released watch and the event once the deadline has passed (edge: a jog ends once)."""
        if self.expired(now):
            return self.release(), JogExpired()
        return self, None


@dataclass(frozen=True)
class StalenessWatch:
    """Per-source timeouts on the latest-value input slots (spacemouse, serial, CAN, ...)."""

    timeouts: Mapping[str, float]
    last_seen: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for source, timeout in self.timeouts.items():
            _positive(f"timeout of {source!r}", timeout)
        unknown = set(self.last_seen) - set(self.timeouts)
        if unknown:
            raise ValueError(f"no timeout for sources {sorted(unknown)}")
        # read-only views: the watch is a value, shared freely between steps
        object.__setattr__(self, "timeouts", MappingProxyType(dict(self.timeouts)))
        object.__setattr__(self, "last_seen", MappingProxyType(dict(self.last_seen)))

    @classmethod
    def start(cls, timeouts: Mapping[str, float], now: float) -> StalenessWatch:
        """Every source counts as seen at ``now``: one that never reports goes stale after its timeout."""
        if not math.isfinite(now):
            raise ValueError(f"start time must be finite, got {now!r}")
        return cls(timeouts, {source: now for source in timeouts})

    def seen(self, source: str, now: float) -> StalenessWatch:
        if source not in self.timeouts:
            raise KeyError(f"unwatched input source {source!r}")
        refreshed = _later(self.last_seen.get(source), now)
        if refreshed is None or refreshed == self.last_seen.get(source):
            return self
        return replace(self, last_seen={**self.last_seen, source: refreshed})

    def stale(self, now: float) -> tuple[str, ...]:
        """Sources whose newest sample is older than their timeout (never-seen ones are not watched yet)."""
        if not math.isfinite(now):
            return tuple(self.timeouts)
        return tuple(s for s, t in self.last_seen.items() if now - t > self.timeouts[s])

    def events(self, now: float) -> tuple[InputStale, ...]:
        return tuple(InputStale(source) for source in self.stale(now))


@dataclass(frozen=True)
class StatusWatch:
    """Status packets arrive every interval (8 or 4 ms); none for ``missed`` intervals -> StatusLost.

    Three intervals by default: without status we send no commands, so the controller alarms within
    a few intervals anyway (MOTN-603); the watch only has to name the cause first.
    """

    interval_s: float
    missed: int = 3
    last: float | None = None  # None: not watching (status output not requested)

    def __post_init__(self) -> None:
        _positive("interval_s", self.interval_s)
        if self.missed < 1:
            raise ValueError(f"missed must be >= 1, got {self.missed!r}")

    @property
    def timeout_s(self) -> float:
        return self.interval_s * self.missed

    def arm(self, now: float) -> StatusWatch:
        """Start watching (status output requested): a controller that never answers is lost too."""
        if not math.isfinite(now):
            raise ValueError(f"arm time must be finite, got {now!r}")
        return replace(self, last=now)

    def received(self, now: float) -> StatusWatch:
        return replace(self, last=_later(self.last, now))

    def disarm(self) -> StatusWatch:
        """Status output stopped on purpose."""
        return replace(self, last=None)

    def lost(self, now: float) -> bool:
        if self.last is None:
            return False
        return not math.isfinite(now) or now - self.last > self.timeout_s

    def poll(self, now: float) -> StatusLost | None:
        if not self.lost(now):
            return None
        if self.last is not None and math.isfinite(now):
            return StatusLost(f"no status packet for {now - self.last:.3f} s")
        return StatusLost("no status packet (invalid clock)")
