"""Thread-safe latest-value slots and bounded event queues inside the inputs process.

A slot keeps only the newest value: a slow reader never sees a backlog, it sees the present. The
sequence counter tells a reader whether anything new arrived since it last looked. Events (button
presses) are different: each one matters, so they go through a bounded queue that counts drops.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Stamped(Generic[T]):
    value: T
    stamp: float
    seq: int


class LatestValue(Generic[T]):
    def __init__(self, name: str = "") -> None:
        self.name = name
        self._cond = threading.Condition()
        self._current: Stamped[T] | None = None
        self._seq = 0

    def publish(self, value: T, stamp: float | None = None) -> int:
        """Replace the value; `stamp` defaults to the value's own `.stamp`. Returns the new sequence."""
        if stamp is None:
            stamp = float(value.stamp)  # type: ignore[attr-defined]
        with self._cond:
            self._seq += 1
            self._current = Stamped(value, stamp, self._seq)
            self._cond.notify_all()
            return self._seq

    def read(self) -> Stamped[T] | None:
        with self._cond:
            return self._current

    @property
    def seq(self) -> int:
        return self._seq

    def age(self, now: float) -> float:
        cur = self._current
        return math.inf if cur is None else max(0.0, now - cur.stamp)

    def wait_newer(self, seq: int, timeout: float) -> Stamped[T] | None:
        """Block until the sequence exceeds `seq` (or timeout); returns the current value or None."""
        with self._cond:
            self._cond.wait_for(lambda: self._seq > seq, timeout)
            return self._current if self._seq > seq else None


class EventQueue(Generic[T]):
    def __init__(self, maxlen: int = 256) -> None:
        self._items: deque[T] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition()
        self.dropped = 0

    def put(self, item: T) -> None:
        with self._cond:
            if len(self._items) >= self._maxlen:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify_all()

    def get(self, timeout: float | None = None) -> T | None:
        with self._cond:
            self._cond.wait_for(lambda: bool(self._items), timeout)
            return self._items.popleft() if self._items else None

    def drain(self) -> list[T]:
        with self._cond:
            out = list(self._items)
            self._items.clear()
            return out

    def __len__(self) -> int:
        return len(self._items)
