"""Waiting helpers shared by the input adapter tests (threads publish; the test waits, bounded)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from servo_app.inputs import LatestValue


def wait_for(slot: LatestValue[Any], pred: Callable[[Any], bool], timeout: float = 15.0) -> Any:
    """The first value published into ``slot`` that satisfies ``pred``."""
    deadline = time.monotonic() + timeout
    seq = 0
    while time.monotonic() < deadline:
        cur = slot.wait_newer(seq, timeout=0.1)
        if cur is not None:
            seq = cur.seq
            if pred(cur.value):
                return cur.value
    raise AssertionError("condition not reached")


def wait_until(pred: Callable[[], bool], timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached")
        time.sleep(0.01)


def assert_refreshed_within(slot: LatestValue[Any], limit: float, n: int = 8) -> None:
    """The next ``n`` values published into ``slot`` each come less than ``limit`` s after the one before
    (by their stamps): a source held at rest never goes stale."""
    last = slot.read()
    assert last is not None
    for _ in range(n):
        cur = slot.wait_newer(last.seq, timeout=5 * limit)
        assert cur is not None and cur.stamp - last.stamp < limit, \
            f"refreshed {'never' if cur is None else f'{cur.stamp - last.stamp:.3f} s later'}, stale after {limit} s"
        last = cur
