"""Cartesian-format desired positions -> FANUC joints, the way the controller converts them.

One implementation for the simulator (every command, every 4-8 ms) and ``servo-app check`` (offline),
so both judge a Cartesian stream alike. After the conversion the joints go through exactly the
checks of joint format (FAQ: "In case of Cartesian format, after converting to the Joint format
internally, the same process is performed").

A Cartesian desired position is X Y Z (mm) W P R (deg) of the flange centre in the world frame (61.7:
no tool or user frame; extended axes E1-E3 are not converted). The rule, per command:

- candidates: the closed-form IK solutions (up to 8: Flip x Up x Top), each joint moved by whole
  turns to the copy nearest the previous command position, so the wrist can run past +-180 instead of
  jumping 360 degrees. The candidate nearest the previous command position (Euclidean in model
  joints) is where the motion continues: the controller has no other way to give an XYZWPR a
  configuration;
- held configuration: the configuration of the command position at the start of streaming (IBGN
  start). Its flip, up, top AND turn numbers of J1, J4, J6 must equal those of the continued
  solution, else MOTN-156 "Configuration changed" (61.5, 61.9). That covers a wrist flip through
  J5 = 0, the elbow through stretched, the wrist centre across the J1 axis, J1/J4/J6 across +-180
  (a turn number, REFERENCE.md s2), and a pose that is reachable only in another configuration;
- no IK solution at all (outside the work envelope): MOTN-018 "Position not reachable". 61.9 names
  no code ("the robot will stop with an alarm"); MOTN-018 is FANUC's general one: our choice;
- joint ranges are not filtered here: a pose whose continued solution needs a joint beyond its
  stroke gets the joint-format range alarm (MOTN-017) from the limit checker, like a joint command.

The wire carries float32: W P R are known to about 3e-7 rad. Near the wrist singularity (J5 near 0
or 180 deg) that noise moves J4 by about 3e-7 / sin(J5) rad: at J5 = 0 it picks J4 at random (up to
90 deg away, and either sign of J5), and within a degree of it the jerk of J4 alone exceeds its limit.
So J4 moves only by what the pose needs beyond ``POSE_TOL``: J4 changes by at most ``POSE_TOL /
|sin J5|`` less than the exact solution, and J5, J6 are refitted (flange orientation error below
about ``POSE_TOL`` rad, position error about d6 * POSE_TOL: a few float32 steps). Likewise a J5
within ``POSE_TOL`` of 0 or 180 deg counts as the held flip: a path must really leave the
singularity on the other side to change the configuration. The shoulder singularity (wrist centre on
the J1 axis) is not smoothed: the IK takes J1 from the previous position only when exactly on it.
Cost: one closed-form IK (about 0.1 ms), a 3x3 refit and one configuration per command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from servo_app.robots.configuration import ArmConfiguration, configuration_of
from servo_app.robots.conventions import (
    ArrayLike,
    fanuc_deg_to_model_rad,
    model_rad_to_fanuc_deg,
    rot_x,
    rot_y,
    rot_z,
    xyzwpr_to_matrix,
)
from servo_app.robots.geometry import FLANGE_ROTATION
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import RobotProfile

CONFIG_CODE = "MOTN-156"
UNREACHABLE_CODE = "MOTN-018"
POSE_TOL = 1e-6  # rad: a few float32 steps of W P R (2.7e-7 rad at 180 deg), the wire's resolution

_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class Conversion:
    """The joints for one Cartesian desired position, or why there are none.

    ``joints_deg``: FANUC joints J1..J6 (deg) when ``code`` is None. ``code``: MOTN-156 or MOTN-018.
    ``config``: configuration of the continued solution (None when unreachable); on MOTN-156 it is
    the configuration the path went into.
    """

    joints_deg: np.ndarray | None
    code: str | None
    config: ArmConfiguration | None

    @property
    def ok(self) -> bool:
        return self.code is None


class CartesianConverter:
    """XYZWPR -> FANUC joints in the configuration held since the start of the stream."""

    def __init__(self, arm: ArmKinematics) -> None:
        self.arm = arm
        self.held: ArmConfiguration | None = None

    @classmethod
    def for_profile(cls, profile: RobotProfile) -> CartesianConverter:
        return cls(ArmKinematics(profile))

    def reset(self, start_q_deg: ArrayLike | None = None) -> None:
        """A new stream: hold the configuration of ``start_q_deg`` (FANUC deg, the command position at
        IBGN start). None (offline, start unknown): the first converted position sets it."""
        self.held = None if start_q_deg is None else configuration_of(self._model(start_q_deg), self.arm)

    def convert(self, xyzwpr: ArrayLike, prev_q_deg: ArrayLike) -> Conversion:
        """Joints for the flange pose ``xyzwpr`` continuing from ``prev_q_deg`` (FANUC deg, the previous
        command position). Values must be finite (MOTN-605 is checked before)."""
        seed = self._model(prev_q_deg)
        pose = xyzwpr_to_matrix(xyzwpr)
        sols = self.arm.ik(pose, seed=seed)
        if not sols:
            return Conversion(None, UNREACHABLE_CODE, None)
        q = np.array([s.q_model_rad for s in sols])
        q += _TWO_PI * np.round((seed - q) / _TWO_PI)  # the turn copy nearest the previous position
        best = q[int(np.argmin(np.sum((q - seed) ** 2, axis=1)))]
        s5 = abs(math.sin(best[4]))
        d4 = best[3] - seed[3]
        if d4 != 0.0:  # J4 moves only as far as the pose needs beyond the wire's resolution
            slack = POSE_TOL / s5 if s5 > 0.0 else math.inf
            best = _fit_wrist(best, seed[3] + math.copysign(max(0.0, abs(d4) - slack), d4), seed, pose[:3, :3])
        config = configuration_of(best, self.arm)
        if self.held is not None and abs(math.sin(best[4])) < POSE_TOL:
            config = replace(config, flip=self.held.flip)  # J5's sign there is wire noise
        if self.held is None:
            self.held = config
        elif config != self.held:
            return Conversion(None, CONFIG_CODE, config)
        return Conversion(model_rad_to_fanuc_deg(best, self.arm.j23_factor), None, config)

    def _model(self, q_deg: ArrayLike) -> np.ndarray:
        return fanuc_deg_to_model_rad(np.asarray(q_deg, dtype=float)[:6], self.arm.j23_factor)


def _fit_wrist(q: np.ndarray, q4: float, seed: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """``q`` with J4 = ``q4`` and J5, J6 fitted to the flange rotation ``rot`` (turn copies nearest ``seed``)."""
    # Rx(-q4) Ry(-q5) Rx(-q6) = (Rz(q1) Ry(q2 - q3))^T rot R0^T (kinematics module); undo Rx(-q4).
    m = (rot_z(q[0]) @ rot_y(q[1] - q[2])).T @ rot @ FLANGE_ROTATION.T
    n = rot_x(q4) @ m  # = Ry(-q5) Rx(-q6), up to the small part of the tilt this J4 cannot reach
    out = q.copy()
    out[3] = q4
    out[4] = -math.atan2(-n[2, 0], n[0, 0])
    out[5] = -math.atan2(-n[1, 2], n[1, 1])
    out[4:] += _TWO_PI * np.round((seed[4:] - out[4:]) / _TWO_PI)
    return out
