"""The simulator's view of the arm kinematics: flange position for the limit checker, XYZWPR for status,
and the arm itself for converting Cartesian-format commands.

Kept behind plain optional fields so that the controller model runs (with zeros for the Cartesian
pose, stage-1 acceleration/jerk limits and MOTN-619 for Cartesian commands) even for a profile the
kinematics cannot handle.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from servo_app.robots.profile import RobotProfile

if TYPE_CHECKING:
    from servo_app.robots.kinematics import ArmKinematics

FlangeFn = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class SimKinematics:
    flange_xyz_mm: FlangeFn | None  # FANUC joints (deg) -> flange centre XYZ (mm), FANUC world
    pose_xyzwpr: Callable[[np.ndarray], np.ndarray] | None  # FANUC joints (deg) -> X Y Z W P R
    arm: ArmKinematics | None = None  # IK for Cartesian-format commands; None: MOTN-619


def load_kinematics(profile: RobotProfile) -> SimKinematics:
    """Kinematics of ``profile`` from servo_app.robots; callables are None when unavailable."""
    try:
        from servo_app.robots.conventions import matrix_to_xyzwpr
        from servo_app.robots.kinematics import ArmKinematics

        arm = ArmKinematics(profile)
    except (ImportError, AttributeError, ValueError):
        return SimKinematics(None, None)

    def pose(q_deg: np.ndarray) -> np.ndarray:
        return matrix_to_xyzwpr(arm.fk_fanuc_deg(q_deg[:6]))

    return SimKinematics(arm.flange_xyz_mm_fanuc_deg, pose, arm)


NO_KINEMATICS = SimKinematics(None, None)
