"""Servo position and motor currents of the simulated arm.

The servo position follows the command position with a pure delay plus a first-order lag. The
FAQ gives about 50 ms command-to-position delay at 8 ms (communication included) and about half
at 4 ms; the defaults, 2 cycles of delay and a 3-cycle time constant, give 5 cycles + one cycle of
communication = 48 ms at 8 ms and 24 ms at 4 ms for a ramp.

Currents are only plausible, not identified: a gravity term (upper arm and forearm), an
inertia-like term proportional to the servo acceleration and a little viscous/Coulomb friction.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

import numpy as np

N_JOINTS = 9

# Amps per deg/s^2 (inertia-like), amps of gravity at the worst posture, friction amps.
_INERTIA_A = np.array([6e-4, 8e-4, 5e-4, 1.5e-4, 1.5e-4, 5e-5])
_FRICTION_A = np.array([0.15, 0.15, 0.12, 0.05, 0.05, 0.03])


class ServoModel:
    """Servo joints (FANUC deg, 9 axes) lagging the command joints."""

    def __init__(self, q0: Sequence[float], interval_s: float, *, delay_cycles: int = 2,
                 tau_cycles: float = 3.0, j23_factor: float = 1.0) -> None:
        self.dt = interval_s
        self.delay_cycles = max(0, int(delay_cycles))
        self.alpha = 1.0 - math.exp(-1.0 / tau_cycles) if tau_cycles > 0 else 1.0
        self.j23_factor = j23_factor
        self.set_position(q0)

    def set_position(self, q: Sequence[float]) -> None:
        """Put the arm at rest at ``q`` (command and servo alike)."""
        q9 = np.zeros(N_JOINTS)
        vals = np.asarray(q, dtype=float)[:N_JOINTS]
        q9[: len(vals)] = vals
        self.q = q9
        self.qd = np.zeros(N_JOINTS)
        self.qdd = np.zeros(N_JOINTS)
        self._line: deque[np.ndarray] = deque([q9.copy() for _ in range(self.delay_cycles + 1)],
                                              maxlen=self.delay_cycles + 1)

    def update(self, cmd: np.ndarray) -> None:
        """One control cycle towards the command position ``cmd`` (9 values)."""
        self._line.append(cmd.copy())
        target = self._line[0]
        q_new = self.q + self.alpha * (target - self.q)
        qd_new = (q_new - self.q) / self.dt
        self.qdd = (qd_new - self.qd) / self.dt
        self.qd = qd_new
        self.q = q_new

    @property
    def moving(self) -> bool:
        return bool(np.any(np.abs(self.qd[:6]) > 0.05))

    def currents(self) -> np.ndarray:
        """Motor currents (A), 9 values (extended axes 0)."""
        q = self.q
        r2 = math.radians(q[1])
        fore = math.radians(q[2] + (self.j23_factor - 1.0) * q[1])  # forearm from the horizontal
        gravity = np.zeros(6)
        gravity[1] = 2.2 * math.sin(r2) + 1.3 * math.cos(fore)
        gravity[2] = 1.3 * math.cos(fore)
        gravity[4] = 0.2 * math.cos(fore - math.radians(q[4]))
        out = np.zeros(N_JOINTS)
        qd, qdd = self.qd[:6], self.qdd[:6]
        out[:6] = gravity + _INERTIA_A * qdd + _FRICTION_A * np.tanh(qd / 5.0) + 0.002 * qd
        return out
