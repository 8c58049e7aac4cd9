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
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from servo_app.robots.conventions import ArrayLike

if TYPE_CHECKING:
    from servo_app.robots.kinematics import ArmKinematics

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


def configuration_of(q_model_rad: ArrayLike, kin: ArmKinematics) -> ArmConfiguration:
    """The configuration of a model-convention joint vector (rad); see the module docstring."""
    q1, q2, q3, q4, q5, q6 = (float(v) for v in q_model_rad[:6])
    up = kin.d4 * math.cos(q3) - kin.a3 * math.sin(q3) > 0.0
    phi = q2 - q3
    x_wrist = kin.a1 + kin.a2 * math.sin(q2) + kin.d4 * math.cos(phi) + kin.a3 * math.sin(phi)
    return ArmConfiguration(flip=wrap_pi(q5) > 0.0, up=up, top=x_wrist > 0.0,
                            turn1=turn_number(q1), turn4=turn_number(q4), turn6=turn_number(q6))


def boundary_distances(q_model_rad: ArrayLike, kin: ArmKinematics) -> np.ndarray:
    """How far ``q`` is from each configuration boundary, as angles (rad) where the boundary is one.

    [flip (J5 from 0 or 180 deg), up/down (elbow from the stretched-forearm line), top/bottom (wrist
    centre from the J1 axis, divided by the arm's reach), turn boundaries of J1, J4, J6 (from +-180
    deg)]. Used to keep joint-space motion a margin away from changing the configuration.
    """
    return _signs_and_distances(np.atleast_2d(np.asarray(q_model_rad, dtype=float)), kin)[1][0]


def keeps_configuration(q_model_rad: np.ndarray, kin: ArmKinematics, ref: ArmConfiguration,
                        margins: np.ndarray) -> np.ndarray:
    """For each row of ``q_model_rad`` (n, 6): same configuration as ``ref`` and at least ``margins``
    (as :func:`boundary_distances`) from every boundary. Vectorised: the servo cycle checks whole
    paths of joint vectors every cycle."""
    q = np.atleast_2d(np.asarray(q_model_rad, dtype=float))
    same, dist = _signs_and_distances(q, kin, ref)
    return same & np.all(dist >= margins, axis=1)


def _signs_and_distances(q: np.ndarray, kin: ArmKinematics, ref: ArmConfiguration | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Per row: whether the configuration equals ``ref`` (all True without one), and the distances."""
    q1, q2, q3, q4, q5, q6 = q[:, :6].T
    elbow = math.hypot(kin.d4, kin.a3)
    up = (kin.d4 * np.cos(q3) - kin.a3 * np.sin(q3)) / elbow  # = cos(q3 + atan2(a3, d4))
    phi = q2 - q3
    x_wrist = kin.a1 + kin.a2 * np.sin(q2) + kin.d4 * np.cos(phi) + kin.a3 * np.sin(phi)

    def wrap(a: np.ndarray) -> np.ndarray:
        return np.remainder(a + np.pi, 2 * np.pi) - np.pi  # [-pi, pi)

    def turns(a: np.ndarray) -> np.ndarray:
        return np.ceil((a - np.pi) / (2 * np.pi)).astype(int)  # k with a in (-pi + 2 pi k, pi + 2 pi k]

    w5 = wrap(q5)
    dist = np.stack([
        np.minimum(np.abs(w5), np.pi - np.abs(w5)),
        np.arcsin(np.minimum(1.0, np.abs(up))),
        np.abs(x_wrist) / (kin.a2 + elbow),
        np.pi - np.abs(wrap(q1)), np.pi - np.abs(wrap(q4)), np.pi - np.abs(wrap(q6)),
    ], axis=1)
    if ref is None:
        return np.ones(len(q), dtype=bool), dist
    same = ((w5 > 0) == ref.flip) & ((up > 0) == ref.up) & ((x_wrist > 0) == ref.top)
    same &= (turns(q1) == ref.turn1) & (turns(q4) == ref.turn4) & (turns(q6) == ref.turn6)
    return same, dist
