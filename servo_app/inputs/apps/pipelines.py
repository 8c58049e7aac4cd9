"""The four applications: teleoperation, admittance hand guiding, stand-off, target tracking.

Each wraps a pure control law from this package in the :class:`Application` pipeline (inputs by
role, staleness carried through, one command sample out).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict
from typing import Any, ClassVar

from servo_app.inputs.apps.admittance import Admittance, AdmittanceParams
from servo_app.inputs.apps.base import Application, Feedback, InputRef, require
from servo_app.inputs.apps.standoff import StandoffController, StandoffParams
from servo_app.inputs.apps.tracking import PoseExtrapolator, TrackingErrorMonitor
from servo_app.inputs.samples import Measurement, PoseSample, TwistSample
from servo_app.inputs.shaping import clamp_norm


class TeleopApp(Application):
    """A SpaceMouse (or any twist source) driving the TCP: optional frame override, scale, caps."""

    type_name = "teleop"
    roles: ClassVar[dict[str, tuple[str, bool]]] = {"twist": ("twist", True)}

    def __init__(self, name: str, inputs: Mapping[str, InputRef], *, frame: str | None = None, scale: float = 1.0,
                 max_linear_mm_s: float = math.inf, max_angular_deg_s: float = math.inf, **kw: Any) -> None:
        super().__init__(name, inputs, **kw)
        self.frame, self.scale = frame, scale
        self.max_linear, self.max_angular = max_linear_mm_s, max_angular_deg_s

    def compute(self, now: float, values: Mapping[str, Any], changed: set[str]) -> TwistSample:
        t: TwistSample = require(values["twist"], TwistSample, "twist", self.name)
        lin = clamp_norm([c * self.scale for c in t.linear], self.max_linear)
        ang = clamp_norm([c * self.scale for c in t.angular], self.max_angular)
        # The stop mark carried through: without it a pad's stop is idle here, and a live lower-priority
        # source takes the arm the operator has just stopped.
        return TwistSample(lin, ang, self.frame or t.frame, t.stamp, self.name, stop=t.stop)  # type: ignore[arg-type]


class AdmittanceApp(Application):
    """Force/torque -> twist (hand guiding); `zero()` takes the sensor's bias from the next samples."""

    type_name = "admittance"
    roles: ClassVar[dict[str, tuple[str, bool]]] = {"wrench": ("measurement", True)}

    def __init__(self, name: str, inputs: Mapping[str, InputRef], *, params: AdmittanceParams, **kw: Any) -> None:
        super().__init__(name, inputs, **kw)
        self.law = Admittance(params)
        self.last_wrench: tuple[float, ...] | None = None
        self._last_stamp: float | None = None

    def compute(self, now: float, values: Mapping[str, Any], changed: set[str]) -> TwistSample | None:
        if "wrench" not in changed:
            return None
        m: Measurement = require(values["wrench"], Measurement, "wrench", self.name)
        gap = None if self._last_stamp is None else m.stamp - self._last_stamp
        self._last_stamp = m.stamp
        if self.law.biasing and gap is not None and gap > self.inputs["wrench"].stale_after_s:
            # The sensor went quiet mid-zeroing: what it reads now (a hand on the tool, say) is no bias,
            # and averaged in, guiding would push by itself on release. Asked for again instead.
            self.law.cancel_bias()
            self.problems.record("zeroing_cancelled", f"sensor {m.source!r} went quiet for {gap:.2f} s while "
                                 "zeroing; the bias is unchanged: zero again with nobody touching the tool")
        out = self.law.twist(m, source=self.name)
        self.last_wrench = tuple(m.values[k] for k in self.law.p.keys)
        return out

    def zero(self, samples: int | None = None) -> None:
        self.law.request_bias(samples)

    def describe(self) -> dict[str, Any]:
        return {"bias": list(self.law.bias), "zeroing": self.law.biasing, "wrench": self.last_wrench,
                "keys": list(self.law.p.keys), "frame": self.law.p.frame}


class StandoffApp(Application):
    """Hold a distance reading at a target along tool z; an optional operator twist (tool frame)
    moves the other axes."""

    type_name = "standoff"
    roles: ClassVar[dict[str, tuple[str, bool]]] = {"distance": ("measurement", True),
                                                    "operator": ("twist", False)}

    def __init__(self, name: str, inputs: Mapping[str, InputRef], *, params: StandoffParams, field: str = "distance",
                 **kw: Any) -> None:
        super().__init__(name, inputs, **kw)
        self.law = StandoffController(params)
        self.field = field
        self.distance_mm: float | None = None

    def compute(self, now: float, values: Mapping[str, Any], changed: set[str]) -> TwistSample:
        d: Measurement = require(values["distance"], Measurement, "distance", self.name)
        if self.field not in d.values:
            raise KeyError(f"distance sample from {d.source!r} has no {self.field!r}; has {sorted(d.values)}")
        self.distance_mm = d.values[self.field]
        vz = self.law.step(self.distance_mm, d.stamp, now)
        op = values.get("operator")
        if op is None:
            return TwistSample((0.0, 0.0, vz), (0.0, 0.0, 0.0), "tool", d.stamp, self.name)
        op = require(op, TwistSample, "operator", self.name)
        if op.frame != "tool":
            raise ValueError(f"operator twist from {op.source!r} is in frame {op.frame!r}: stand-off takes tool-frame "
                             "twists (its z is replaced by the stand-off speed)")
        return TwistSample((op.linear[0], op.linear[1], vz), op.angular, "tool", min(d.stamp, op.stamp), self.name)

    def idle(self) -> None:
        self.law.hold()

    @property
    def integrates(self) -> bool:
        return self.law.p.ki > 0.0

    def describe(self) -> dict[str, Any]:
        return {"target_mm": self.law.p.target_mm, "distance_mm": self.distance_mm, "error_mm": self.law.error_mm}


class TrackingApp(Application):
    """Follow a pose stream: extrapolate the target from its stamps to now (plus a lookahead that
    covers the servo's own lag) on every tick, and report the tracking error against the robot."""

    type_name = "tracking"
    roles: ClassVar[dict[str, tuple[str, bool]]] = {"target": ("pose", True)}
    output_kind = "pose"
    wants_feedback = True

    def __init__(self, name: str, inputs: Mapping[str, InputRef], *, extrapolator: PoseExtrapolator,
                 lookahead_s: float = 0.0, linear_speed: float = 100.0, angular_speed: float = 30.0,
                 **kw: Any) -> None:
        super().__init__(name, inputs, **kw)
        self.extrapolator = extrapolator
        self.lookahead_s = lookahead_s
        self.linear_speed, self.angular_speed = linear_speed, angular_speed
        self.monitor = TrackingErrorMonitor(window=2000)

    def compute(self, now: float, values: Mapping[str, Any], changed: set[str]) -> PoseSample | None:
        target: PoseSample = require(values["target"], PoseSample, "target", self.name)
        if target.frame != "base":
            raise ValueError(f"target pose from {target.source!r} is in frame {target.frame!r}; tracking takes 'base'")
        if "target" in changed:
            self.extrapolator.add(target)
        p = self.extrapolator.predict(now + self.lookahead_s, source=self.name)
        if p is None:
            return None
        return PoseSample(p.xyzwpr, target.stamp, self.name)

    def observe(self, now: float, feedback: Feedback, active: bool) -> None:
        if not active or not feedback.get("status_received"):
            return
        target, seen = self.extrapolator.predict(now), self.extrapolator.latest
        if target is not None and seen is not None:
            # Stamped with the sample it came from: the report's ages are the latency compensated for.
            actual = [float(v) for v in feedback["cart_servo"]]
            self.monitor.update(PoseSample(target.xyzwpr, seen.stamp, self.name), actual, now)

    def reset_error(self) -> None:
        self.monitor.reset()

    def describe(self) -> dict[str, Any]:
        rep = self.monitor.report()
        return {"lookahead_s": self.lookahead_s, "tracking_error": None if rep is None else asdict(rep)}


APPLICATION_TYPES: dict[str, type[Application]] = {
    cls.type_name: cls for cls in (TeleopApp, AdmittanceApp, StandoffApp, TrackingApp)
}

__all__ = ["APPLICATION_TYPES", "AdmittanceApp", "StandoffApp", "StandoffParams", "TeleopApp", "TrackingApp"]
