"""Has the robot's feedback stopped moving? (the ``settled`` flag beside ``at_rest``).

``at_rest`` says the commanded motion has stopped; the arm follows it with a lag (servo delay and
time constant on FANUC: 1.4-1.9 mm for 0.2 s after ``at_rest`` here; on Janome the status after the
last move, 4 mm further on). ``settled`` says the reported position itself has stopped: every sample
of the last ``window_s`` lies within ``tol`` of the others, per axis, and the window holds at least
``min_samples`` samples (a single status proves nothing).

Pure: the runner hands it each new status's time and position.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np


class SettleDetector:
    def __init__(self, tol: float, window_s: float, min_samples: int = 3) -> None:
        if not (tol > 0 and window_s > 0 and min_samples >= 2):
            raise ValueError(f"tol={tol} and window_s={window_s} must be > 0, min_samples={min_samples} >= 2")
        self.tol = tol
        self.window_s = window_s
        self.min_samples = min_samples
        self._samples: deque[tuple[float, np.ndarray]] = deque()
        self.settled = False

    def reset(self) -> None:
        """A new link: nothing is known about the feedback until it has been watched for a window."""
        self._samples.clear()
        self.settled = False

    def add(self, t: float, position: Sequence[float] | np.ndarray) -> bool:
        """One feedback sample at time ``t`` (s, monotonic); returns (and keeps) ``settled``."""
        p = np.asarray(position, dtype=float)
        s = self._samples
        if s and (t < s[-1][0] or s[-1][1].shape != p.shape):
            s.clear()  # a clock or an axis count that goes back: start watching afresh
        s.append((t, p))
        # Keep one sample at or before the window's start: the window is then covered from its start.
        while len(s) >= 2 and s[1][0] <= t - self.window_s:
            s.popleft()
        covered = t - s[0][0] >= self.window_s
        if not covered or len(s) < self.min_samples or not np.all(np.isfinite(p)):
            self.settled = False
            return False
        a = np.stack([q for _, q in s])
        self.settled = bool(np.all(a.max(axis=0) - a.min(axis=0) <= self.tol))
        return self.settled
