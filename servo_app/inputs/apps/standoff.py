"""Stand-off control: keep a distance sensor's reading at a target by moving along the tool axis.

The sensor looks along +tool z, so a reading above the target means "too far": move +z. The
controller is PI with a speed limit and anti-windup (the integral only grows while the output is
not saturated in the same direction, and is bounded). Without a fresh reading it commands zero and
forgets the integral, so a reading that comes back does not start with a stale push. Its output
replaces the z component of the operator's tool-frame twist; the operator keeps the other axes.
"""

from __future__ import annotations

from dataclasses import dataclass

from servo_app.inputs.samples import TwistSample
from servo_app.inputs.shaping import clamp, deadband


@dataclass(frozen=True)
class StandoffParams:
    target_mm: float
    kp: float = 2.0  # (mm/s) per mm of error
    ki: float = 0.0  # (mm/s) per (mm s)
    max_speed_mm_s: float = 20.0
    deadband_mm: float = 0.0
    integral_limit_mm_s: float = 10.0  # bound of the integral term's contribution
    max_age_s: float = 0.2  # readings older than this are ignored
    direction: int = 1  # -1 if the sensor looks along -tool z


class StandoffController:
    def __init__(self, params: StandoffParams) -> None:
        self.p = params
        self.integral = 0.0  # in mm/s (already multiplied by ki)
        self._last: float | None = None
        self.error_mm: float | None = None

    def reset(self) -> None:
        self.integral = 0.0
        self._last = None
        self.error_mm = None

    def hold(self) -> None:
        """Not in control: the integral starts again from zero when it is (bumpless take-over)."""
        self.integral = 0.0
        self._last = None

    def step(self, distance_mm: float | None, stamp: float | None, now: float) -> float:
        """Tool-z speed in mm/s for this cycle."""
        p = self.p
        if distance_mm is None or stamp is None or now - stamp > p.max_age_s:
            self.reset()
            return 0.0
        if self._last is not None and now - self._last > p.max_age_s:
            # No reading for longer than its timeout (the sensor went stale, the arm stopped): the
            # integral is from before the gap, and the gap is no time to integrate the error over.
            self.reset()
        dt = 0.0 if self._last is None else max(0.0, now - self._last)
        self._last = now
        e = deadband(distance_mm - p.target_mm, p.deadband_mm)
        self.error_mm = distance_mm - p.target_mm
        unsat = p.kp * e + self.integral
        if p.ki and dt and (abs(unsat) < p.max_speed_mm_s or unsat * e < 0):
            self.integral = clamp(self.integral + p.ki * e * dt, -p.integral_limit_mm_s, p.integral_limit_mm_s)
        return p.direction * clamp(p.kp * e + self.integral, -p.max_speed_mm_s, p.max_speed_mm_s)

    def combine(self, operator: TwistSample | None, vz: float, now: float, source: str = "standoff") -> TwistSample:
        """The operator's tool-frame twist with its z speed replaced by the stand-off speed."""
        if operator is None:
            return TwistSample((0.0, 0.0, vz), (0.0, 0.0, 0.0), "tool", now, source)
        if operator.frame != "tool":
            raise ValueError(f"stand-off combines with a tool-frame twist, got frame {operator.frame!r}")
        lin = (operator.linear[0], operator.linear[1], vz)
        # The older input decides the age, so a stale operator command goes stale here too.
        return TwistSample(lin, operator.angular, "tool", min(now, operator.stamp), source)
