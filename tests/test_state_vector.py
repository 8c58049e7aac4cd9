"""The state vector both servo processes publish."""

from __future__ import annotations

import numpy as np

from servo_app.state import command_derivatives


def test_command_derivatives_are_the_controllers_finite_differences() -> None:
    dt = 0.008
    q = [np.array([0.0, 1.0]), np.array([0.1, 1.0]), np.array([0.3, 1.0]), np.array([0.6, 1.0]),
         np.array([1.0, 1.0])]
    d = command_derivatives(q, dt)  # the last four: 0.1, 0.3, 0.6, 1.0
    np.testing.assert_allclose(d["q_cmd"], [1.0, 1.0])
    np.testing.assert_allclose(d["vel"], [0.4 / dt, 0.0])
    np.testing.assert_allclose(d["acc"], [0.1 / dt**2, 0.0])
    np.testing.assert_allclose(d["jerk"], [0.0, 0.0], atol=1e-6)
    # At the start the first command stands in for those not sent yet: one command is at rest.
    one = command_derivatives(q[:1], dt)
    assert not any(np.any(one[k]) for k in ("vel", "acc", "jerk"))
