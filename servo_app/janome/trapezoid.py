"""Point-to-point move timing: the trapezoidal (or, for short moves, triangular) speed profile a
Janome move follows from rest to rest (manual 17.5: start-up, acceleration, constant speed,
deceleration). Used by the simulator to time moves and by servo_app to expect their end."""

from __future__ import annotations

import math


def _check(distance: float, vmax: float, amax: float) -> None:
    if not (math.isfinite(distance) and distance >= 0):
        raise ValueError(f"distance={distance!r} must be finite and >= 0")
    if not (math.isfinite(vmax) and vmax > 0):
        raise ValueError(f"vmax={vmax!r} must be finite and > 0")
    if not (math.isfinite(amax) and amax > 0):
        raise ValueError(f"amax={amax!r} must be finite and > 0")


def move_time(distance: float, vmax: float, amax: float) -> float:
    """Seconds to cover ``distance`` from rest to rest at most ``vmax`` with ``amax`` (= decel)."""
    _check(distance, vmax, amax)
    if distance * amax <= vmax * vmax:  # never reaches vmax: triangle
        return 2.0 * math.sqrt(distance / amax)
    return distance / vmax + vmax / amax


def covered(t: float, distance: float, vmax: float, amax: float) -> float:
    """Distance covered at time ``t`` after the start of that move (clamped to [0, distance])."""
    _check(distance, vmax, amax)
    total = move_time(distance, vmax, amax)
    if t <= 0 or distance == 0:
        return 0.0
    if t >= total:
        return distance
    v_peak = min(vmax, math.sqrt(distance * amax))
    t_acc = v_peak / amax
    if t < t_acc:
        return 0.5 * amax * t * t
    d_acc = 0.5 * v_peak * t_acc
    t_dec = total - t_acc
    if t < t_dec:
        return d_acc + v_peak * (t - t_acc)
    left = total - t
    return distance - 0.5 * amax * left * left
