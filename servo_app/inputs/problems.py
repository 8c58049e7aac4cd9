"""Counting and logging of bad input without flooding the log.

Every problem is counted by kind and kept in a short history (with the offending bytes in hex); the
log gets at most one line per kind per interval, with the number suppressed since the last one. A kind
that does not recur still gets its count reported: with the next line of any kind once its interval
has passed (:meth:`ProblemLog.report_due`, which a polling thread may also call), and at close
(:meth:`ProblemLog.flush`).
"""

from __future__ import annotations

import logging
import threading
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass

# The offending bytes kept per problem: enough to see what came, never a flood's whole read (kept whole,
# 32 problems per adapter of up to ~12 KB of hex each made GET /api/inputs hundreds of KB).
MAX_DATA = 64


def _hex(data: bytes) -> str:
    if len(data) <= MAX_DATA:
        return data.hex(" ")
    return f"{data[:MAX_DATA].hex(' ')} ... ({len(data)} bytes)"


@dataclass(frozen=True, slots=True)
class Problem:
    stamp: float
    kind: str
    message: str
    data_hex: str | None


class ProblemLog:
    def __init__(self, logger: logging.Logger, clock: Callable[[], float], *,
                 min_interval_s: float = 1.0, keep: int = 32) -> None:
        self._logger = logger
        self._clock = clock
        self._min_interval = min_interval_s
        self.counts: Counter[str] = Counter()
        self.recent: deque[Problem] = deque(maxlen=keep)
        self._last_logged: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()
        # The last suppressed problem of each kind and its level, for the count's own line.
        self._last_suppressed: dict[str, tuple[Problem, int]] = {}
        self._lock = threading.Lock()

    def record(self, kind: str, message: str, data: bytes | None = None,
               level: int = logging.WARNING, exc_info: bool = False) -> Problem:
        now = self._clock()
        p = Problem(now, kind, message, None if data is None else _hex(data))
        with self._lock:
            self.counts[kind] += 1
            self.recent.append(p)
            last = self._last_logged.get(kind)
            if last is not None and now - last < self._min_interval:
                self._suppressed[kind] += 1
                self._last_suppressed[kind] = (p, level)
                return p
            self._last_logged[kind] = now
            suppressed = self._suppressed.pop(kind, 0)
            self._last_suppressed.pop(kind, None)
            others = self._take(now, force=False)
        more = f" (+{suppressed} more since last report)" if suppressed else ""
        raw = f" bytes: {p.data_hex}" if p.data_hex is not None else ""
        self._logger.log(level, "%s: %s%s%s", kind, message, raw, more, exc_info=exc_info)
        self._log_counts(others)
        return p

    def report_due(self) -> None:
        """Log the suppressed counts whose kind's interval has passed (each kind at most once per
        interval, as its own lines): a kind that never recurs is not left unreported."""
        if not self._suppressed:  # the common case, without the lock (a polling thread calls this)
            return
        with self._lock:
            due = self._take(self._clock(), force=False)
        self._log_counts(due)

    def flush(self) -> None:
        """Log every suppressed count now (at close: nothing else will)."""
        with self._lock:
            due = self._take(self._clock(), force=True)
        self._log_counts(due)

    def _take(self, now: float, force: bool) -> list[tuple[int, Problem, int]]:  # under the lock
        due = [k for k in self._suppressed if force or now - self._last_logged.get(k, now) >= self._min_interval]
        out = []
        for k in due:
            p, level = self._last_suppressed.pop(k)
            out.append((self._suppressed.pop(k), p, level))
            self._last_logged[k] = now
        return out

    def _log_counts(self, counts: list[tuple[int, Problem, int]]) -> None:
        for n, p, level in counts:
            self._logger.log(level, "%s: %d more since last report, the last: %s", p.kind, n, p.message)

    def snapshot(self) -> tuple[Counter[str], list[Problem]]:
        """Counts and recent problems, copied under the lock (the adapter thread keeps adding)."""
        with self._lock:
            return Counter(self.counts), list(self.recent)
