"""Small signal-shaping functions shared by adapters and the application building blocks."""

from __future__ import annotations

import math
from collections.abc import Sequence


def deadband(x: float, width: float) -> float:
    """Zero inside +-width, shifted outside so the output is continuous (no jump at the edge)."""
    if abs(x) <= width:
        return 0.0
    return math.copysign(abs(x) - width, x)


def deadband_normalized(u: float, width: float) -> float:
    """Deadband on a value in [-1, 1], rescaled so full deflection still gives 1."""
    if width >= 1.0:
        return 0.0
    return deadband(u, width) / (1.0 - width)


def cubic_blend(u: float, k: float) -> float:
    """(1-k) u + k u^3: fine control near zero, full speed at full deflection, for k in [0, 1]."""
    return (1.0 - k) * u + k * u * u * u


def clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def clamp_norm(v: Sequence[float], limit: float) -> tuple[float, ...]:
    """Scale the whole vector down to the limit so its direction is kept."""
    n = math.sqrt(sum(c * c for c in v))
    if n <= limit or n == 0.0:
        return tuple(v)
    f = limit / n
    return tuple(c * f for c in v)


class LowPass:
    """First-order low-pass per channel; the step size comes from the samples' own stamps."""

    def __init__(self, cutoff_hz: float | None) -> None:
        self.tau = None if not cutoff_hz else 1.0 / (2.0 * math.pi * cutoff_hz)
        self._y: list[float] | None = None

    def reset(self) -> None:
        self._y = None

    def step(self, x: Sequence[float], dt: float) -> tuple[float, ...]:
        if self.tau is None:
            return tuple(x)
        if self._y is None or len(self._y) != len(x):
            self._y = list(x)
        elif dt > 0.0:
            a = dt / (self.tau + dt)
            self._y = [y + a * (xi - y) for y, xi in zip(self._y, x, strict=True)]
        return tuple(self._y)
