"""Kinematic models of the two Janome robot types, in the robot's own coordinates X Y Z R.

- Cartesian (JR3000 desktop, JC-3): X Y Z are linear axes, R a rotation; the work envelope is the
  box of the strokes.
- SCARA (JS3): J1 and J2 swing two arms of lengths l1, l2 in the XY plane, Z is linear, R (J4) a
  rotation. Positions are still commanded in X Y Z R with an arm configuration (moveAPTP's
  coordinate argument: 1 righty, -1 lefty). This code's convention: righty has J2 > 0 (seen from
  above, with the hand pointing away from the base, the elbow lies to the right of the line from
  J1 to the hand); check the sign against the robot's pendant before trusting it.
  R is the J4 angle (the manual names it "R (J4) axis coordinates"), not the tool angle in the world.

Every check returns a :class:`Violation` (error code, 1-based axis, message naming axis and value)
or None, so the simulator can answer with the point job's error code and servo_app can refuse a
command with a clear message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from servo_app.janome.protocol import Arm, ErrorCode, RobotKind

AXES = ("X", "Y", "Z", "R")
UNITS = ("mm", "mm", "mm", "deg")


class Unreachable(ValueError):
    """No SCARA joint solution; the message names the position and the reason."""


@dataclass(frozen=True)
class Violation:
    code: ErrorCode
    axis: int  # 1 X, 2 Y, 3 Z, 4 R; 0 when not one axis (reach, singularity)
    message: str


def _range_violation(i: int, value: float, lo: float, hi: float) -> Violation | None:
    if lo <= value <= hi:
        return None
    return Violation(ErrorCode.OUT_OF_RANGE, i + 1,
                     f"{AXES[i]}={value:.3f} {UNITS[i]} is outside the stroke [{lo:g}, {hi:g}]")


class Workspace(Protocol):
    kind: RobotKind

    def check(self, p: np.ndarray, arm: int) -> Violation | None:
        """None if X Y Z R ``p`` can be reached in arm configuration ``arm``."""

    def check_path(self, p0: np.ndarray, p1: np.ndarray, arm: int) -> Violation | None:
        """None if the straight line p0 -> p1 (a lineMove) stays reachable all along."""

    def clip_segment(self, p0: np.ndarray, p1: np.ndarray, arm: int) -> np.ndarray:
        """The point furthest along p0 -> p1 up to which the path is reachable (p0 if none)."""


@dataclass(frozen=True)
class CartesianWorkspace:
    lo: tuple[float, float, float, float]
    hi: tuple[float, float, float, float]
    kind: RobotKind = RobotKind.CARTESIAN

    def check(self, p: np.ndarray, arm: int = Arm.RIGHTY) -> Violation | None:
        for i in range(4):
            v = _range_violation(i, float(p[i]), self.lo[i], self.hi[i])
            if v is not None:
                return v
        return None

    def check_path(self, p0: np.ndarray, p1: np.ndarray, arm: int = Arm.RIGHTY) -> Violation | None:
        return self.check(p0, arm) or self.check(p1, arm)  # a box is convex

    def clip_segment(self, p0: np.ndarray, p1: np.ndarray, arm: int = Arm.RIGHTY) -> np.ndarray:
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        d = p1 - p0
        t = 1.0
        for i in range(4):
            if d[i] > 0:
                t = min(t, (self.hi[i] - p0[i]) / d[i])
            elif d[i] < 0:
                t = min(t, (self.lo[i] - p0[i]) / d[i])
        return p0 + max(t, 0.0) * d


@dataclass(frozen=True)
class ScaraArm:
    """Two arms in the XY plane: lengths (mm) and joint ranges (deg); configuration, not constants."""

    l1: float
    l2: float
    j1_min: float
    j1_max: float
    j2_min: float
    j2_max: float
    singular_margin_deg: float = 1.0  # |J2| below this counts as stretched: the configuration could flip

    def fk(self, j1_deg: float, j2_deg: float) -> tuple[float, float]:
        a1, a12 = math.radians(j1_deg), math.radians(j1_deg + j2_deg)
        return (self.l1 * math.cos(a1) + self.l2 * math.cos(a12), self.l1 * math.sin(a1) + self.l2 * math.sin(a12))

    def ik(self, x: float, y: float, arm: int) -> tuple[float, float]:
        """(J1, J2) in deg for the hand at (x, y) in configuration ``arm``; raises Unreachable."""
        if arm not in (Arm.RIGHTY, Arm.LEFTY):
            raise Unreachable(f"arm={arm!r} must be 1 (righty) or -1 (lefty)")
        r2 = x * x + y * y
        c2 = (r2 - self.l1 ** 2 - self.l2 ** 2) / (2.0 * self.l1 * self.l2)
        reach = math.sqrt(r2)
        if c2 > 1.0 + 1e-12:
            raise Unreachable(f"X={x:.3f} Y={y:.3f}: {reach:.3f} mm from J1 is beyond the reach "
                              f"l1 + l2 = {self.l1 + self.l2:g} mm")
        if c2 < -1.0 - 1e-12:
            raise Unreachable(f"X={x:.3f} Y={y:.3f}: {reach:.3f} mm from J1 is inside the inner radius "
                              f"|l1 - l2| = {abs(self.l1 - self.l2):g} mm")
        j2 = math.acos(min(1.0, max(-1.0, c2))) * (1.0 if arm == Arm.RIGHTY else -1.0)
        j1 = math.atan2(y, x) - math.atan2(self.l2 * math.sin(j2), self.l1 + self.l2 * math.cos(j2))
        j1_deg, j2_deg = math.degrees(j1), math.degrees(j2)
        # atan2 gives (-180, 180]: the joint range may need the turn on either side
        for cand in (j1_deg, j1_deg + 360.0, j1_deg - 360.0):
            if self.j1_min <= cand <= self.j1_max:
                return cand, j2_deg
        return j1_deg, j2_deg

    def joint_violation(self, j1: float, j2: float, arm: int) -> str | None:
        name = "righty" if arm == Arm.RIGHTY else "lefty"
        if not self.j1_min <= j1 <= self.j1_max:
            return f"J1={j1:.3f} deg is outside [{self.j1_min:g}, {self.j1_max:g}]"
        if not self.j2_min <= j2 <= self.j2_max:
            return f"J2={j2:.3f} deg ({name}) is outside [{self.j2_min:g}, {self.j2_max:g}]"
        if abs(j2) < self.singular_margin_deg:
            return (f"J2={j2:.3f} deg is within {self.singular_margin_deg:g} deg of the stretched arm, where "
                    f"the {name} configuration could flip")
        return None


@dataclass(frozen=True)
class ScaraWorkspace:
    arm_model: ScaraArm
    lo: tuple[float, float, float, float]  # X, Y: a bounding box of the work area; Z, R: strokes
    hi: tuple[float, float, float, float]
    kind: RobotKind = RobotKind.SCARA
    path_samples: int = 16

    def joints(self, p: np.ndarray, arm: int) -> tuple[float, float, float, float]:
        """(J1, J2, Z, R); raises Unreachable."""
        j1, j2 = self.arm_model.ik(float(p[0]), float(p[1]), arm)
        return j1, j2, float(p[2]), float(p[3])

    def position(self, joints: tuple[float, float, float, float] | np.ndarray) -> np.ndarray:
        x, y = self.arm_model.fk(float(joints[0]), float(joints[1]))
        return np.array([x, y, float(joints[2]), float(joints[3])])

    def check(self, p: np.ndarray, arm: int) -> Violation | None:
        for i in range(4):
            v = _range_violation(i, float(p[i]), self.lo[i], self.hi[i])
            if v is not None:
                return v
        try:
            j1, j2 = self.arm_model.ik(float(p[0]), float(p[1]), arm)
        except Unreachable as exc:
            return Violation(ErrorCode.UNREACHABLE, 0, str(exc))
        why = self.arm_model.joint_violation(j1, j2, arm)
        if why is not None:
            return Violation(ErrorCode.UNREACHABLE, 0, f"X={p[0]:.3f} Y={p[1]:.3f}: {why}")
        return None

    def check_path(self, p0: np.ndarray, p1: np.ndarray, arm: int) -> Violation | None:
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        n = self._samples(p0, p1)
        for k in range(n + 1):
            v = self.check(p0 + (p1 - p0) * (k / n), arm)
            if v is not None:
                return v
        return None

    def clip_segment(self, p0: np.ndarray, p1: np.ndarray, arm: int) -> np.ndarray:
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        n = self._samples(p0, p1)
        good: float | None = 0.0 if self.check(p0, arm) is None else None
        for k in range(1, n + 1):  # the first exit along the line, then bisect to it
            t = k / n
            ok = self.check(p0 + (p1 - p0) * t, arm) is None
            if good is None:  # starting outside (e.g. inside the margin): first find the way in
                if ok:
                    good = t
                continue
            if not ok:
                lo, hi = good, t
                for _ in range(30):
                    mid = 0.5 * (lo + hi)
                    if self.check(p0 + (p1 - p0) * mid, arm) is None:
                        lo = mid
                    else:
                        hi = mid
                return p0 + (p1 - p0) * lo
            good = t
        return p0 if good is None else p1

    def _samples(self, p0: np.ndarray, p1: np.ndarray) -> int:
        # about one sample per mm in XY, at least path_samples: the annulus is convex nowhere
        return max(self.path_samples, math.ceil(float(np.hypot(*(p1[:2] - p0[:2])))))
