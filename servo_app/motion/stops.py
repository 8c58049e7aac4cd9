"""Stops in place of the controller's HOLD (manual 61.7: HOLD is not supported during IBGN).

Two modes, both a time-optimal jerk-limited deceleration to rest from the current commanded state:
``soft`` within the normal (fraction-scaled) limits, ``fast`` within the full limits minus a small
margin. This module holds the reference computation a benchmark compares a stop against: ruckig's
own time-optimal profile from the same state to zero velocity.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, RuckigError, Synchronization, Trajectory

StopMode = Literal["soft", "fast"]
STOP_MODES: tuple[StopMode, ...] = ("soft", "fast")


def _plan_stop(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, vmax: np.ndarray, amax: np.ndarray,
               jmax: np.ndarray, sync: Synchronization) -> Trajectory:
    """Ruckig's time-optimal profile from the state to rest (velocity interface); ValueError if it
    cannot plan one."""
    n = len(pos)
    inp = InputParameter(n)
    inp.control_interface = ControlInterface.Velocity
    inp.synchronization = sync
    inp.current_position = [float(x) for x in pos]
    inp.current_velocity = [float(x) for x in vel]
    inp.current_acceleration = [float(x) for x in acc]
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = [float(x) for x in vmax]
    inp.max_acceleration = [float(x) for x in amax]
    inp.max_jerk = [float(x) for x in jmax]
    traj = Trajectory(n)
    try:
        result = Ruckig(n).calculate(inp, traj)
    except RuckigError as exc:  # its rare numerical edge cases, as a failed result
        raise ValueError(f"ruckig could not plan the stop: {exc}") from None
    if result not in (Result.Working, Result.Finished):
        raise ValueError(f"ruckig could not plan the stop: {result}")
    return traj


def time_optimal_stop_duration(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray,
                               vmax: np.ndarray, amax: np.ndarray, jmax: np.ndarray) -> float:
    """Shortest time (s) in which every axis reaches zero velocity and acceleration.

    Axes are planned independently (no synchronization): the arm is at rest when its slowest axis
    is, so the maximum of the per-axis optima is the lower bound for any stop.
    """
    return float(_plan_stop(pos, vel, acc, vmax, amax, jmax, Synchronization.No).duration)


def stop_path(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, vmax: np.ndarray, amax: np.ndarray,
              jmax: np.ndarray, samples: int = 16) -> np.ndarray:
    """Positions along the phase-synchronised stop the shaper would make, ``samples`` of them ending at
    the rest position: lets a caller check a stop's path before choosing it. Where ruckig cannot
    synchronise (it raised "error in step 2" for a new target about once a second when joint targets
    replaced each other every 5 ms: from the states of the stops they cause), the less synchronised
    stop the shaper then makes (``JointShaper._replan``); ValueError if none plans."""
    error = ValueError("no synchronization tried")
    for sync in (Synchronization.Phase, Synchronization.Time, Synchronization.No):
        try:
            traj = _plan_stop(pos, vel, acc, vmax, amax, jmax, sync)
            break
        except ValueError as exc:
            error = exc
    else:
        raise error
    times = np.linspace(traj.duration / samples, traj.duration, samples)
    return np.array([traj.at_time(float(t))[0] for t in times])


def ease_out(speed: float, acc: float, jerk: float) -> Trajectory:
    """A jerk-limited fall of one speed share to zero (its velocity ``at_time(t)[1][0]``)."""
    return _plan_stop(np.zeros(1), np.array([speed]), np.zeros(1), np.array([max(speed, 1.0)]),
                      np.array([acc]), np.array([jerk]), Synchronization.No)
