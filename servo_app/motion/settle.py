"""Has the robot's feedback stopped moving? (the ``settled`` flag beside ``at_rest``).

``at_rest`` says the commanded motion has stopped; the arm follows it with a lag (servo delay and
time constant on FANUC: 1.4-1.9 mm for 0.2 s after ``at_rest`` here; on Janome the status after the
last move, 4 mm further on). ``settled`` says the reported position itself has stopped: every sample
of the last ``window_s`` lies within ``tol`` of the others, per axis, and the window holds at least
``min_samples`` samples (a single status proves nothing).

Pure: the runner hands it each new status's time and position. The samples live in a preallocated
ring and each one costs one compiled call (:func:`settle_add`: it appends, drops what left the window
and judges the window in one pass), where the deque of arrays and ``np.stack`` it replaces cost
about 25 us per status here, a tenth of a 4 ms cycle's budget outside the IK.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from servo_app.jit import kernel

MAX_AXES = 9  # J1..J9 (FANUC) or X Y Z R (Janome): the ring's width
_FLOAT64 = np.dtype(np.float64)


@kernel("int64(float64[::1], float64[:, ::1], int64[::1], float64, float64[:], int64, float64, float64, int64)")
def settle_add(ts: np.ndarray, ps: np.ndarray, ring: np.ndarray, t: float, p: np.ndarray, n_axes: int,
                window_s: float, tol: float, min_samples: int) -> int:
    """Append sample (t, p[:n_axes]) to the ring (``ring`` = [head, count, axes]: the oldest slot, how many
    are kept and their axis count), drop the samples before the window's start but one, and judge the
    window. A clock that goes back or another axis count starts the watch afresh.

    Returns 1 settled, 0 not settled, -1 the ring is full (nothing changed: the caller grows it and
    calls again). The arithmetic is numpy's: the range per axis is max - min with NaN propagating, and
    ``range <= tol`` decides, so a NaN or an infinity anywhere in the window is never settled."""
    cap = ts.shape[0]
    head, count = ring[0], ring[1]
    if count and (n_axes != ring[2] or t < ts[(head + count - 1) % cap]):
        head, count = 0, 0  # a clock or an axis count that goes back: start watching afresh
    ring[0], ring[1], ring[2] = head, count, n_axes
    if count == cap:
        # Full: free the oldest slot only if it has left the window anyway (as the loop below would).
        if count >= 2 and ts[(head + 1) % cap] <= t - window_s:
            head = (head + 1) % cap
            count -= 1
        else:
            return -1
    slot = (head + count) % cap
    ts[slot] = t
    for j in range(n_axes):
        ps[slot, j] = p[j]
    count += 1
    # Keep one sample at or before the window's start: the window is then covered from its start.
    while count >= 2 and ts[(head + 1) % cap] <= t - window_s:
        head = (head + 1) % cap
        count -= 1
    ring[0], ring[1] = head, count
    covered = t - ts[head] >= window_s
    finite = True
    for j in range(n_axes):
        if not math.isfinite(p[j]):
            finite = False
    if not covered or count < min_samples or not finite:
        return 0
    for j in range(n_axes):
        hi = ps[head, j]
        lo = hi
        for k in range(1, count):
            v = ps[(head + k) % cap, j]
            if math.isnan(v) or math.isnan(hi):
                hi = math.nan
            elif v > hi:
                hi = v
            if math.isnan(v) or math.isnan(lo):
                lo = math.nan
            elif v < lo:
                lo = v
        if not hi - lo <= tol:
            return 0
    return 1


class SettleDetector:
    def __init__(self, tol: float, window_s: float, min_samples: int = 3, capacity: int = 64) -> None:
        if not (tol > 0 and window_s > 0 and min_samples >= 2):
            raise ValueError(f"tol={tol} and window_s={window_s} must be > 0, min_samples={min_samples} >= 2")
        self.tol = tol
        self.window_s = window_s
        self.min_samples = min_samples
        self._ts = np.zeros(capacity)
        self._ps = np.zeros((capacity, MAX_AXES))
        self._ring = np.zeros(3, dtype=np.int64)  # head, count, axes
        self.buffers = (self._ts, self._ps, self._ring)  # as settle_add takes them (for a kernel that calls it)
        self._p = np.zeros(MAX_AXES)  # the sample being added, as the kernel takes it
        self.settled = False

    def reset(self) -> None:
        """A new link: nothing is known about the feedback until it has been watched for a window."""
        self._ring[:] = 0
        self.settled = False

    def add(self, t: float, position: Sequence[float] | np.ndarray) -> bool:
        """One feedback sample at time ``t`` (s, monotonic); returns (and keeps) ``settled``."""
        n = len(position)
        if n > MAX_AXES:
            raise ValueError(f"{n} axes: at most {MAX_AXES}")
        p = position  # a float64 array is read where it is (numpy's copy: ~5 us a status, caches cold)
        if type(p) is not np.ndarray or p.dtype is not _FLOAT64:
            p = self._p
            p[:n] = position
        # The restart checks live in the kernel too: one call per sample, ~2 us here where the checks on
        # numpy scalars before it took 4 (once per status packet).
        r = settle_add(self._ts, self._ps, self._ring, float(t), p, n, self.window_s, self.tol, self.min_samples)
        if r < 0:  # more samples in the window than the ring holds (a fast link): twice the room
            self._grow()
            r = settle_add(self._ts, self._ps, self._ring, float(t), p, n, self.window_s, self.tol,
                            self.min_samples)
        self.settled = r == 1
        return self.settled

    def _grow(self) -> None:
        head, count = int(self._ring[0]), int(self._ring[1])
        order = (head + np.arange(count)) % self._ts.size
        cap = 2 * self._ts.size
        ts, ps = np.zeros(cap), np.zeros((cap, MAX_AXES))
        ts[:count], ps[:count] = self._ts[order], self._ps[order]
        self._ts, self._ps = ts, ps
        self.buffers = (ts, ps, self._ring)
        self._ring[0], self._ring[1] = 0, count
