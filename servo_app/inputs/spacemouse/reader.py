"""Drain a HID device to its newest state so a slow reader never lags behind the device.

The device queues a report every 8 ms while deflected; a reader that takes one report per loop
would fall further behind each time it is late. `drain` waits (bounded) for the first report, then
reads without waiting until the queue is empty. Axis reports overwrite (the newest wins); every
button report is kept in order, because each press and release matters.

`read(size, timeout_ms)` follows hidapi's `device.read` on a device set non-blocking: with
timeout_ms > 0 it waits up to that long for one report, with 0 it returns at once; no report is an
empty list; an unplugged device raises OSError.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

ReadFn = Callable[[int, int], Sequence[int] | bytes]

REPORT_SIZE = 64  # larger than any SpaceMouse report; hidapi truncates to this


def drain(read: ReadFn, wait_ms: int, *, size: int = REPORT_SIZE, max_reports: int = 256) -> list[bytes]:
    """All reports queued now (waiting up to wait_ms for the first), oldest first."""
    first = read(size, wait_ms)
    if not first:
        return []
    out = [bytes(first)]
    # Bounded so a device that floods faster than we read still lets the caller publish.
    while len(out) < max_reports:
        nxt = read(size, 0)
        if not nxt:
            break
        out.append(bytes(nxt))
    return out
