"""Keeping a period in a Python thread: absolute deadlines, sleep until close, then a short spin.

Deadlines sit on a fixed grid (``t0 + k * period``), so errors never accumulate. When the thread
was held up for more than a whole period (GIL, a loaded machine) the missed slots are skipped,
not replayed in a burst, and counted as overruns: a controller's cycle does not run twice.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class IntervalStats:
    """Achieved intervals between consecutive ticks, in ms."""

    count: int
    mean_ms: float
    std_ms: float
    min_ms: float
    max_ms: float
    p99_ms: float
    overruns: int  # grid slots skipped because a tick came more than one period late


def sleep_until(deadline: float, spin_s: float = 0.0005) -> None:
    """Sleep until ``deadline`` (perf_counter seconds): OS sleep, then spin the last ``spin_s``."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0.0:
            return
        if remaining > spin_s:
            time.sleep(remaining - spin_s)
        else:
            time.sleep(0)  # yield the GIL while spinning


class IntervalRecorder:
    """The last ``maxlen`` tick-to-tick intervals."""

    def __init__(self, maxlen: int = 20000) -> None:
        self._intervals: deque[float] = deque(maxlen=maxlen)
        self._last: float | None = None
        self._lock = threading.Lock()  # stats() runs in another thread than mark()
        self.overruns = 0

    def mark(self, t: float) -> None:
        if self._last is not None:
            with self._lock:
                self._intervals.append(t - self._last)
        self._last = t

    def stats(self) -> IntervalStats:
        with self._lock:
            values = list(self._intervals)
        if not values:
            nan = math.nan
            return IntervalStats(0, nan, nan, nan, nan, nan, self.overruns)
        a = np.array(values) * 1000.0
        return IntervalStats(len(a), float(a.mean()), float(a.std()), float(a.min()), float(a.max()),
                             float(np.percentile(a, 99)), self.overruns)
