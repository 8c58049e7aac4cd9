"""What the closed-form IK and the configuration rules need of an arm: its dimensions and ranges.

:class:`~servo_app.robots.kinematics.ArmKinematics` provides it; ``ik`` and ``configuration`` take this
protocol instead of importing the kinematics, so the three modules import one way only:
``kinematics`` -> ``ik`` -> ``configuration`` -> ``geometry``.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from servo_app.robots.conventions import ArrayLike

# Flange frame relative to the J6 link frame: columns are the flange x, y, z axes.
FLANGE_ROTATION = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])


class ArmGeometry(Protocol):
    """An ortho-parallel arm with a spherical wrist (metres; model convention, radians)."""

    a1: float
    a2: float
    a3: float
    d4: float
    d6: float
    q_min: np.ndarray
    q_max: np.ndarray

    def within_limits(self, q_model_rad: ArrayLike, tol: float = 1e-9) -> bool: ...
