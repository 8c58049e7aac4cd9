"""Target tracking: latency compensation of a pose stream, and a tracking-error report.

A camera or tracker pose arrives late; its stamp says when it was true. `PoseExtrapolator` fits a
constant velocity to the newest samples (least squares over a short window, angles unwrapped) and
moves the newest pose forward to "now", by at most `max_horizon_s`: beyond that a constant-velocity
guess is worse than admitting the target is old. After a gap in the stream the velocity is
unknown, and the newest pose is held.

W P R are extrapolated as angles, which is fine for the short horizons this is meant for.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from servo_app.inputs.samples import PoseSample


def wrap_deg(a: float) -> float:
    """Angle in (-180, 180]."""
    a = math.fmod(a + 180.0, 360.0)
    if a <= 0.0:
        a += 360.0
    return a - 180.0


class PoseExtrapolator:
    def __init__(self, max_horizon_s: float = 0.1, window: int = 3, max_gap_s: float = 0.25) -> None:
        if window < 2:
            raise ValueError("window needs at least 2 samples to estimate a velocity")
        self.max_horizon_s = max_horizon_s
        self.max_gap_s = max_gap_s
        self._hist: deque[PoseSample] = deque(maxlen=window)

    def add(self, sample: PoseSample) -> bool:
        """Keep the sample unless it is not newer than the last one (late or repeated packets)."""
        if self._hist and sample.stamp <= self._hist[-1].stamp:
            return False
        if self._hist and sample.stamp - self._hist[-1].stamp > self.max_gap_s:
            self._hist.clear()  # velocity across a gap would be invented
        self._hist.append(sample)
        return True

    @property
    def latest(self) -> PoseSample | None:
        return self._hist[-1] if self._hist else None

    def velocity(self) -> tuple[float, ...] | None:
        """mm/s and deg/s from a least-squares line through the window, or None with fewer than 2 samples."""
        if len(self._hist) < 2:
            return None
        t = np.array([s.stamp for s in self._hist])
        p = np.array([s.xyzwpr for s in self._hist])
        p[:, 3:] = np.degrees(np.unwrap(np.radians(p[:, 3:]), axis=0))
        t = t - t.mean()
        denom = float((t * t).sum())
        if denom <= 0.0:
            return None
        v = (t[:, None] * (p - p.mean(axis=0))).sum(axis=0) / denom
        return tuple(float(x) for x in v)

    def predict(self, now: float, source: str | None = None) -> PoseSample | None:
        """The target's pose at `now` (stamped with the time it actually refers to)."""
        last = self.latest
        if last is None:
            return None
        if now - last.stamp > self.max_gap_s + self.max_horizon_s:
            return None  # the stream has stopped; do not pretend to know where the target is
        v = self.velocity()
        h = min(max(now - last.stamp, 0.0), self.max_horizon_s)
        if v is None:
            v, h = (0.0,) * 6, 0.0
        xyzwpr = [last.xyzwpr[i] + v[i] * h for i in range(6)]
        xyzwpr[3:] = [wrap_deg(a) for a in xyzwpr[3:]]
        return PoseSample(tuple(xyzwpr), last.stamp + h, source or last.source, last.frame)  # type: ignore[arg-type]


def wpr_matrix(w: float, p: float, r: float) -> np.ndarray:
    """R = Rz(r) Ry(p) Rx(w), degrees (rotations about the fixed X, Y, Z axes)."""
    cw, sw = math.cos(math.radians(w)), math.sin(math.radians(w))
    cp, sp = math.cos(math.radians(p)), math.sin(math.radians(p))
    cr, sr = math.cos(math.radians(r)), math.sin(math.radians(r))
    rx = np.array([[1, 0, 0], [0, cw, -sw], [0, sw, cw]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return rz @ ry @ rx


def pose_error(target: Sequence[float], actual: Sequence[float]) -> tuple[float, float]:
    """(position error in mm, rotation angle between the orientations in deg)."""
    dp = math.dist(target[:3], actual[:3])
    rel = wpr_matrix(*target[3:6]).T @ wpr_matrix(*actual[3:6])
    c = max(-1.0, min(1.0, (float(np.trace(rel)) - 1.0) / 2.0))
    return dp, math.degrees(math.acos(c))


@dataclass(frozen=True)
class TrackingErrorReport:
    samples: int
    position_mm_last: float
    position_mm_rms: float
    position_mm_max: float
    angle_deg_last: float
    angle_deg_rms: float
    angle_deg_max: float
    target_age_s_mean: float | None  # how old the targets were when used (after compensation)
    target_age_s_max: float | None


class TrackingErrorMonitor:
    """Running tracking-error statistics over the last `window` updates."""

    def __init__(self, window: int = 1000) -> None:
        self._pos: deque[float] = deque(maxlen=window)
        self._ang: deque[float] = deque(maxlen=window)
        self._age: deque[float] = deque(maxlen=window)

    def reset(self) -> None:
        self._pos.clear()
        self._ang.clear()
        self._age.clear()

    def update(self, target: PoseSample | Sequence[float], actual: Sequence[float],
               now: float | None = None) -> tuple[float, float]:
        xyzwpr = target.xyzwpr if isinstance(target, PoseSample) else tuple(target)
        dp, da = pose_error(xyzwpr, actual)
        self._pos.append(dp)
        self._ang.append(da)
        if now is not None and isinstance(target, PoseSample):
            self._age.append(max(0.0, now - target.stamp))
        return dp, da

    def report(self) -> TrackingErrorReport | None:
        if not self._pos:
            return None
        n = len(self._pos)
        ages = list(self._age)
        return TrackingErrorReport(
            samples=n,
            position_mm_last=self._pos[-1],
            position_mm_rms=math.sqrt(sum(x * x for x in self._pos) / n),
            position_mm_max=max(self._pos),
            angle_deg_last=self._ang[-1],
            angle_deg_rms=math.sqrt(sum(x * x for x in self._ang) / n),
            angle_deg_max=max(self._ang),
            target_age_s_mean=sum(ages) / len(ages) if ages else None,
            target_age_s_max=max(ages) if ages else None,
        )
