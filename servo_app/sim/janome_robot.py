"""The simulated Janome arm: where it is, and how a lineMove / monoMove / moveAPTP goes.

Pure (no clock: a planned move is a function of time since its start). Cartesian (JR3000, JC-3) and
SCARA (JS3) from the same profile format. Moves are point to point from rest to rest with a
trapezoidal speed profile; a target outside a stroke, or (SCARA) not reachable in the commanded arm
configuration all along a straight line, is refused with the point job's error code and the axis.
A SCARA line move keeps its arm configuration (the robot cannot flip it mid-line); a PTP move goes in
joint space and may change it, as moveAPTP's coordinate argument says.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from servo_app.janome.kinematics import ScaraWorkspace, Violation
from servo_app.janome.profile import JanomeProfile
from servo_app.janome.protocol import Arm, Cmd, ErrorCode, RobotKind, Target
from servo_app.janome.trapezoid import covered, move_time


@dataclass(frozen=True)
class MovePlan:
    kind: str  # "line", "mono" (R only) or "ptp"
    start: np.ndarray  # X Y Z R
    end: np.ndarray
    duration: float  # s
    arm: int  # configuration at the end
    # progress along the move: the longest axis profile (distance, speed, accel); others follow in proportion
    lead: tuple[float, float, float]
    start_joints: np.ndarray | None = None  # SCARA PTP: interpolated in joint space
    end_joints: np.ndarray | None = None

    def progress(self, t: float) -> float:
        d, v, a = self.lead
        return 1.0 if d <= 0 else covered(t, d, v, a) / d

    def position(self, t: float, ws: ScaraWorkspace | None = None) -> np.ndarray:
        u = self.progress(t)
        if self.start_joints is not None and self.end_joints is not None and ws is not None:
            return ws.position(self.start_joints + (self.end_joints - self.start_joints) * u)
        return self.start + (self.end - self.start) * u


class JanomeRobot:
    def __init__(self, profile: JanomeProfile, start: tuple[float, ...] | None = None, arm: int | None = None,
                 ptp_speed_fraction: float = 0.5) -> None:
        self.profile = profile
        self.ws = profile.workspace()
        self.arm = int(profile.elbow if arm is None else arm)
        if profile.kind == RobotKind.CARTESIAN:
            self.arm = int(Arm.RIGHTY)
        self.position = np.array(profile.home if start is None else start, dtype=float)
        if self.position.shape != (4,):
            raise ValueError(f"start={start!r} must be 4 values X Y Z R")
        why = self.ws.check(self.position, self.arm)
        if why is not None:
            raise ValueError(f"start position refused: {why.message}")
        if not 0 < ptp_speed_fraction <= 1:
            raise ValueError(f"ptp_speed_fraction={ptp_speed_fraction} must be in (0, 1]")
        self.ptp_speed_fraction = ptp_speed_fraction

    @property
    def scara(self) -> ScaraWorkspace | None:
        return self.ws if isinstance(self.ws, ScaraWorkspace) else None

    def joints(self) -> np.ndarray:
        """SCARA: J1 J2 (deg) Z R; cartesian: X Y Z R."""
        ws = self.scara
        if ws is None:
            return self.position.copy()
        return np.array(ws.joints(self.position, self.arm))

    # ------------------------------------------------------------------ planning
    def plan(self, t: Target) -> MovePlan | Violation:
        end = np.array(t.xyzr, dtype=float)
        if t.cmd == Cmd.PTP:
            return self._plan_ptp(end, t.arm)
        if t.cmd != Cmd.LINE:
            return Violation(ErrorCode.BAD_COMMAND, 3, f"cmd={t.cmd} is not a move")
        if self.profile.kind == RobotKind.SCARA and t.arm != self.arm:
            return Violation(ErrorCode.UNREACHABLE, 0, f"arm={t.arm}: a line move cannot change the arm "
                                                       f"configuration (now {self.arm})")
        why = self.ws.check(end, self.arm) or self.ws.check_path(self.position, end, self.arm)
        if why is not None:
            return why
        d = end - self.position
        lin, rot = float(np.linalg.norm(d[:3])), abs(float(d[3]))
        p = self.profile
        profiles = []
        if lin > 0:
            if not 0 < t.speed <= p.cp_speed:
                return Violation(ErrorCode.BAD_SPEED, 0, f"speed={t.speed} mm/s must be in (0, {p.cp_speed:g}]")
            profiles.append((lin, t.speed, p.cp_accel))
        if rot > 0:
            rspeed = t.rspeed if t.rspeed > 0 else p.speed[3]
            if rspeed > p.speed[3]:
                return Violation(ErrorCode.BAD_SPEED, 4, f"rspeed={t.rspeed} deg/s is above {p.speed[3]:g}")
            profiles.append((rot, rspeed, p.accel[3]))
        return self._plan(("line" if lin > 0 else "mono"), end, profiles, self.arm)

    def _plan_ptp(self, end: np.ndarray, arm: int) -> MovePlan | Violation:
        p, f = self.profile, self.ptp_speed_fraction
        if self.profile.kind == RobotKind.CARTESIAN:
            why = self.ws.check(end, Arm.RIGHTY)
            if why is not None:
                return why
            d = np.abs(end - self.position)
            profiles = [(float(d[i]), p.speed[i] * f, p.accel[i]) for i in range(4) if d[i] > 0]
            return self._plan("ptp", end, profiles, Arm.RIGHTY)
        ws = self.scara
        assert ws is not None and p.joint_speed is not None and p.joint_accel is not None
        why = ws.check(end, arm)
        if why is not None:
            return why
        j0 = np.array(ws.joints(self.position, self.arm))
        j1 = np.array(ws.joints(end, arm))
        speeds = (p.joint_speed[0], p.joint_speed[1], p.speed[2], p.speed[3])
        accels = (p.joint_accel[0], p.joint_accel[1], p.accel[2], p.accel[3])
        d = np.abs(j1 - j0)
        profiles = [(float(d[i]), speeds[i] * f, accels[i]) for i in range(4) if d[i] > 0]
        plan = self._plan("ptp", end, profiles, arm)
        return MovePlan(plan.kind, plan.start, plan.end, plan.duration, arm, plan.lead, j0, j1)

    def _plan(self, kind: str, end: np.ndarray, profiles: list[tuple[float, float, float]], arm: int) -> MovePlan:
        if not profiles:
            return MovePlan(kind, self.position.copy(), end, 0.0, arm, (0.0, 1.0, 1.0))
        times = [move_time(*pr) for pr in profiles]
        i = int(np.argmax(times))
        return MovePlan(kind, self.position.copy(), end, times[i], arm, profiles[i])

    # ------------------------------------------------------------------ moving
    def at(self, plan: MovePlan, t: float) -> np.ndarray:
        return plan.position(t, self.scara)

    def finish(self, plan: MovePlan) -> None:
        self.position = plan.end.copy()
        self.arm = plan.arm
