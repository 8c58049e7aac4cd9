"""FANUC-style arm configuration (manual B-83284EN ch. 4): "F U T, 0, 0, 0".

Definitions used here (model-convention joints in radians; ``psi = atan2(a3, d4)`` is the angle of
the J3 -> wrist-centre vector above the forearm axis):

- **Flip / No-flip** (``flip``): the sign of J5 wrapped into (-180, 180]; F when J5 > 0 (tool tilted
  *up* relative to the forearm, since J5 turns about -y), N when J5 <= 0. J5 = 0 is the wrist
  singularity; it reads N. The usual "tool pointing down" pose 0, 0, 0, 0, -90, 0 reads N U T.
- **Up / Down** (``up``): U when the wrist centre lies on the *front* side of the upper-arm line
  through J2 and J3 (the side the forearm points to at zero), i.e. ``d4 cos q3 - a3 sin q3 > 0``
  (equivalently ``cos(q3 + psi) > 0``). Measured in the arm's own plane, independent of J1 and of
  Top/Bottom (a backward over-the-shoulder reach is therefore D).
- **Top / Bottom** (``top``): T when the wrist centre is in front of the J1 axis in the arm's own
  frame (rotated by J1), i.e. ``a1 + a2 sin q2 + d4 cos(q2 - q3) + a3 sin(q2 - q3) > 0``.
- **Turn numbers** of J1, J4, J6: turn k means the angle is in (-180 + 360 k, 180 + 360 k] degrees;
  0 for the usual range. J2, J3, J5 carry no turn number (as on the controller).

Up/Down, Top/Bottom and Flip are the three binary choices of the closed-form IK (8 solutions); the
turn numbers pick among the 360-degree copies of J1, J4, J6 that the joint ranges allow.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from servo_app.robots.conventions import ArrayLike
from servo_app.robots.geometry import ArmGeometry
from servo_app.robots.kernels import pack_region, rows_in_region

TWO_PI = 2.0 * math.pi
_PATTERN = re.compile(r"^\s*([NF])\s*([UD])\s*([TB])\s*(?:,?\s*(-?\d+)\s*,?\s*(-?\d+)\s*,?\s*(-?\d+))?\s*$",
                      re.IGNORECASE)


@dataclass(frozen=True)
class ArmConfiguration:
    flip: bool
    up: bool
    top: bool
    turn1: int = 0
    turn4: int = 0
    turn6: int = 0

    def __str__(self) -> str:
        return (f"{'F' if self.flip else 'N'} {'U' if self.up else 'D'} {'T' if self.top else 'B'}, "
                f"{self.turn1}, {self.turn4}, {self.turn6}")

    @classmethod
    def parse(cls, text: str) -> ArmConfiguration:
        """Parse "N U T, 0, 0, 0" (also "NUT 000"-less forms like "FUT" or "F D B, -1, 0, 1")."""
        m = _PATTERN.match(text)
        if m is None:
            raise ValueError(f"not a configuration string: {text!r}")
        f, u, t, *turns = m.groups()
        n1, n4, n6 = (int(v) if v is not None else 0 for v in turns)
        return cls(f.upper() == "F", u.upper() == "U", t.upper() == "T", n1, n4, n6)

    def same_branch(self, other: ArmConfiguration) -> bool:
        """Equal flip, up and top (turn numbers ignored)."""
        return (self.flip, self.up, self.top) == (other.flip, other.up, other.top)


def wrap_pi(angle_rad: float) -> float:
    """Wrap to (-pi, pi]; ``math.remainder`` is exact, so no result lands a rounding step outside."""
    r = math.remainder(angle_rad, 2.0 * math.pi)
    return r + 2.0 * math.pi if r <= -math.pi else r


def turn_number(angle_rad: float) -> int:
    """k such that the angle is in (-pi + 2 pi k, pi + 2 pi k]."""
    return round((angle_rad - wrap_pi(angle_rad)) / (2.0 * math.pi))


def configuration_of(q_model_rad: ArrayLike, kin: ArmGeometry) -> ArmConfiguration:
    """The configuration of a model-convention joint vector (rad); see the module docstring."""
    q1, q2, q3, q4, q5, q6 = (float(v) for v in q_model_rad[:6])
    up = kin.d4 * math.cos(q3) - kin.a3 * math.sin(q3) > 0.0
    phi = q2 - q3
    x_wrist = kin.a1 + kin.a2 * math.sin(q2) + kin.d4 * math.cos(phi) + kin.a3 * math.sin(phi)
    return ArmConfiguration(flip=wrap_pi(q5) > 0.0, up=up, top=x_wrist > 0.0,
                            turn1=turn_number(q1), turn4=turn_number(q4), turn6=turn_number(q6))


def boundary_distances(q_model_rad: ArrayLike, kin: ArmGeometry) -> np.ndarray:
    """How far ``q`` is from each configuration boundary, as angles (rad) where the boundary is one.

    [flip (J5 from 0 or 180 deg), up/down (elbow from the stretched-forearm line), top/bottom (wrist
    centre from the J1 axis, divided by the arm's reach), turn boundaries of J1, J4, J6 (from +-180
    deg)]. Used to keep joint-space motion a margin away from changing the configuration.
    """
    q1, q2, q3, q4, q5, q6 = (float(v) for v in np.asarray(q_model_rad, dtype=float)[:6])
    w5 = abs(wrap_pi(q5))
    up = math.cos(q3 + _elbow_angle(kin))
    return np.array([
        min(w5, math.pi - w5),
        math.asin(min(1.0, abs(up))),
        abs(wrist_centre_offset(q2, q3, kin)) / _reach(kin),
        math.pi - abs(wrap_pi(q1)), math.pi - abs(wrap_pi(q4)), math.pi - abs(wrap_pi(q6)),
    ])


def wrist_centre_offset(q2: ArrayLike, q3: ArrayLike, kin: ArmGeometry) -> np.ndarray:
    """Signed distance (m) of the wrist centre in front of the J1 axis in the arm's plane (> 0: Top)."""
    phi = np.subtract(q2, q3)
    return kin.a1 + kin.a2 * np.sin(q2) + kin.d4 * np.cos(phi) + kin.a3 * np.sin(phi)


def _elbow_angle(kin: ArmGeometry) -> float:
    """psi: Up <=> cos(q3 + psi) > 0 (the module docstring's ``d4 cos q3 - a3 sin q3 > 0``)."""
    return math.atan2(kin.a3, kin.d4)


def _reach(kin: ArmGeometry) -> float:
    return kin.a2 + math.hypot(kin.d4, kin.a3)


@dataclass(frozen=True)
class ConfigurationRegion:
    """The joint vectors (model rad) that keep ``reference``, each boundary at least a margin away.

    Every boundary but Top/Bottom is an interval of one joint: flip keeps J5 between 0 and +-180 deg,
    up/down keeps q3 within 90 deg of the elbow's centre line, a turn number keeps J1, J4 or J6
    inside its 360-degree turn. So the region is a joint box ``[lower, upper]`` (also the joint ranges
    after :meth:`within`) plus the wrist centre's side of the J1 axis. Checking a path is a few
    vectorised comparisons, cheap enough to run on dozens of points every cycle.
    """

    reference: ArmConfiguration
    lower: np.ndarray  # (6,) model rad, inclusive
    upper: np.ndarray
    top_margin_m: float  # the wrist centre stays at least this far on its side of the J1 axis
    kin: ArmGeometry

    @classmethod
    def around(cls, q_model_rad: ArrayLike, kin: ArmGeometry, margins: ArrayLike) -> ConfigurationRegion:
        """The region of ``q``'s configuration; ``margins`` in :func:`boundary_distances`' order and units."""
        q = np.asarray(q_model_rad, dtype=float)[:6]
        m_flip, m_up, m_top, m1, m4, m6 = (float(v) for v in np.asarray(margins, dtype=float))
        ref = configuration_of(q, kin)
        lo = np.full(6, -np.inf)
        hi = np.full(6, np.inf)
        for i, k, m in ((0, ref.turn1, m1), (3, ref.turn4, m4), (5, ref.turn6, m6)):
            lo[i], hi[i] = -math.pi + TWO_PI * k + m, math.pi + TWO_PI * k - m
        k5 = turn_number(float(q[4]))  # flip: the sign of J5 wrapped into (-180, 180]
        lo[4], hi[4] = ((TWO_PI * k5 + m_flip, TWO_PI * k5 + math.pi - m_flip) if ref.flip
                        else (TWO_PI * k5 - math.pi + m_flip, TWO_PI * k5 - m_flip))
        psi = _elbow_angle(kin)
        centre = 0.0 if ref.up else math.pi
        mid = centre + TWO_PI * round((float(q[2]) + psi - centre) / TWO_PI) - psi
        lo[2], hi[2] = mid - math.pi / 2 + m_up, mid + math.pi / 2 - m_up
        return cls(ref, lo, hi, m_top * _reach(kin), kin)

    def within(self, lower: ArrayLike, upper: ArrayLike) -> ConfigurationRegion:
        """This region cut to the joint ranges ``[lower, upper]`` (model rad)."""
        return replace(self, lower=np.maximum(self.lower, lower), upper=np.minimum(self.upper, upper))

    @cached_property
    def packed(self) -> np.ndarray:
        """This region as one float64 array, for the compiled kernels (:mod:`servo_app.robots.kernels`)."""
        k = self.kin
        return pack_region(self.lower, self.upper, k.a1, k.a2, k.a3, k.d4, self.reference.top, self.top_margin_m)

    def contains(self, q_model_rad: np.ndarray) -> np.ndarray:
        """Per row of ``q`` ((n, 6) or (6,)): inside the box and on the reference's side of the J1 axis."""
        q = np.atleast_2d(np.asarray(q_model_rad, dtype=float))
        out = np.empty(q.shape[0], dtype=bool)
        rows_in_region(q, self.packed, out)
        return out
