"""Value checks shared by every adapter: a rejected value names its field and the value itself."""

from __future__ import annotations

import math


class ValueRejected(ValueError):
    """A decoded value that must not be published (not finite, out of range, malformed)."""

    def __init__(self, field: str, value: object, reason: str) -> None:
        super().__init__(f"field {field!r} value {value!r} rejected: {reason}")
        self.field = field
        self.value = value
        self.reason = reason


def check_finite(field: str, value: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueRejected(field, value, "not a number") from None
    if not math.isfinite(v):
        raise ValueRejected(field, value, "not finite")
    return v


def check_range(field: str, value: float, lo: float | None = None, hi: float | None = None) -> float:
    v = check_finite(field, value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ValueRejected(field, value, f"out of range [{lo}, {hi}]")
    return v
