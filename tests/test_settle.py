"""The settle detector's compiled ring against the plain reading of its rule (a deque of samples)."""

from __future__ import annotations

from collections import deque

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from servo_app.motion.settle import SettleDetector


class PlainSettle:
    """The rule as first written: every sample of the window (plus one at or before its start) within
    ``tol`` of the others per axis, the window covered and holding ``min_samples``."""

    def __init__(self, tol: float, window_s: float, min_samples: int = 3) -> None:
        self.tol, self.window_s, self.min_samples = tol, window_s, min_samples
        self.s: deque[tuple[float, np.ndarray]] = deque()

    def add(self, t: float, position: list[float]) -> bool:
        p = np.asarray(position, dtype=float)
        s = self.s
        if s and (t < s[-1][0] or s[-1][1].shape != p.shape):
            s.clear()
        s.append((t, p))
        while len(s) >= 2 and s[1][0] <= t - self.window_s:
            s.popleft()
        if t - s[0][0] < self.window_s or len(s) < self.min_samples or not np.all(np.isfinite(p)):
            return False
        a = np.stack([q for _, q in s])
        return bool(np.all(a.max(axis=0) - a.min(axis=0) <= self.tol))


VALUES = st.one_of(st.floats(-1.0, 1.0), st.sampled_from([0.0, 0.004, 0.006, float("nan"), float("inf")]))


@settings(max_examples=300, deadline=None)
@given(steps=st.lists(st.tuples(st.floats(-0.02, 0.05), st.integers(4, 6), st.lists(VALUES, min_size=6, max_size=6),
                                st.booleans()), min_size=1, max_size=120),
       tol=st.sampled_from([0.005, 0.5, 2.0]), window_s=st.sampled_from([0.01, 0.1, 0.3]),
       min_samples=st.integers(2, 5))
def test_the_compiled_ring_judges_as_the_plain_rule(steps: list[tuple[float, int, list[float], bool]], tol: float,
                                                     window_s: float, min_samples: int) -> None:
    # A small ring, so that it has to grow; steps mostly forward (some back: the clock's reset), and
    # positions that mostly hold still (a small step), to reach settled often.
    fast, plain = SettleDetector(tol, window_s, min_samples, capacity=2), PlainSettle(tol, window_s, min_samples)
    t, q = 0.0, np.zeros(6)
    for dt, n, jump, still in steps:
        t += dt
        step = np.nan_to_num(np.asarray(jump), nan=0.0, posinf=0.0)
        q = q + (0.001 if still else 1.0) * step
        pos = list(q[:n])
        if not np.isfinite(jump[0]):  # a non-finite sample: never settled while it is in the window
            pos[0] = jump[0]
        assert fast.add(t, pos) == plain.add(t, pos), (t, pos)


def test_a_still_arm_settles_after_a_window_and_a_move_unsettles_it() -> None:
    d = SettleDetector(0.005, 0.1)
    q = [0.0, 10.0, 20.0, 0.0, -90.0, 0.0]
    assert not d.add(0.0, q) and not d.add(0.05, q)  # not yet a whole window
    assert d.add(0.1, q) and d.settled
    assert not d.add(0.108, [0.01, *q[1:]])  # 0.01 deg on J1: beyond the tolerance
    d.reset()
    assert not d.settled and not d.add(0.2, q)


def test_a_non_finite_sample_keeps_the_window_unsettled_until_it_leaves() -> None:
    for bad in (float("nan"), float("inf")):
        fast, plain = SettleDetector(0.5, 0.1), PlainSettle(0.5, 0.1)
        for k in range(40):
            pos = [bad if k == 5 else 0.0, 1.0, 2.0, 3.0]
            assert fast.add(0.01 * k, pos) == plain.add(0.01 * k, pos), (bad, k)
        assert fast.settled


def test_a_range_of_exactly_tol_is_settled() -> None:
    fast, plain = SettleDetector(0.25, 0.1), PlainSettle(0.25, 0.1)
    for k in range(20):
        pos = [0.25 * (k % 2), 0.0]
        assert fast.add(0.01 * k, pos) == plain.add(0.01 * k, pos)
    assert fast.settled


@settings(max_examples=100, deadline=None)
@given(steps=st.lists(st.tuples(st.floats(0.0, 0.05), st.lists(VALUES, min_size=6, max_size=6)), min_size=1,
                      max_size=60))
def test_an_array_sample_is_judged_as_the_same_values_in_a_list(steps: list[tuple[float, list[float]]]) -> None:
    """A float64 array is read where it is (a slice of the state vector, or a strided view): the same
    answers as the values handed over as a list."""
    from_list, from_slice, from_strided = (SettleDetector(0.5, 0.1, capacity=2) for _ in range(3))
    store = np.zeros(20)
    t = 0.0
    for dt, values in steps:
        t += dt
        store[0:6] = values
        store[8:20:2] = values
        want = from_list.add(t, list(values))
        assert from_slice.add(t, store[0:6]) == want
        assert from_strided.add(t, store[8:20:2]) == want
