"""Closed-form kinematics of a six-axis ortho-parallel arm with a spherical wrist (REFERENCE.md s2).

Chain (model convention, all joints revolute, radians)::

    world = FANUC world: origin on the J1 axis at the height of J2 (d1 above the base plate)
    J1 about +z at the origin
    J2 about +y at x = a1          (positive: upper arm leans forward)
    J3 about -y at z = a2 above J2 (positive: forearm lifts)
    J4 about -x at z = a3 above J3
    J5 about -y at x = d4 from J4  (negative: tool tilts down)
    J6 about -x at x = d6 from J5  = the flange centre

Flange frame: z along the J6 axis pointing out of the flange (+x at all-zero joints), x = +z and
y = -y of the world at all-zero joints, i.e. W, P, R = 180, -90, 0 there (the ROS-Industrial ``tool0``).

The rotations collapse to ``R = Rz(q1) Ry(q2 - q3) Rx(-q4) Ry(-q5) Rx(-q6) R0`` and the flange
position to a few sines and cosines, so FK is plain ``math`` (no MuJoCo) and fast enough for the
simulator's per-cycle limit checker.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from servo_app.robots.configuration import ArmConfiguration, configuration_of
from servo_app.robots.conventions import ArrayLike, fanuc_deg_to_model_rad, xyzwpr_to_matrix
from servo_app.robots.geometry import FLANGE_ROTATION
from servo_app.robots.ik import IkSolution, nearest, solve

if TYPE_CHECKING:
    from servo_app.robots.profile import RobotProfile


class ArmKinematics:
    """FK and analytic IK of one arm model; joints in the model convention unless a name says fanuc.

    ``tool_xyzwpr`` (optional) is the tool (TCP) frame relative to the flange, FANUC units
    (mm, deg); it only affects the ``*_tcp`` methods.
    """

    def __init__(self, profile: RobotProfile, tool_xyzwpr: ArrayLike | None = None) -> None:
        self.profile = profile
        d = profile.dims
        self.d1, self.a1, self.a2, self.a3, self.d4, self.d6 = d.d1, d.a1, d.a2, d.a3, d.d4, d.d6
        self.j23_factor = profile.j23_factor
        self.q_min = np.array(profile.joint_min_rad)
        self.q_max = np.array(profile.joint_max_rad)
        self.set_tool(tool_xyzwpr)

    def set_tool(self, tool_xyzwpr: ArrayLike | None) -> None:
        """Another tool (TCP) for the ``*_tcp`` methods; None: the flange."""
        self.tool = np.eye(4) if tool_xyzwpr is None else xyzwpr_to_matrix(tool_xyzwpr)
        self.tool_inv = np.linalg.inv(self.tool)

    # ---- forward kinematics -------------------------------------------------------------------

    def fk(self, q_model_rad: ArrayLike) -> np.ndarray:
        """4x4 flange pose in the FANUC world frame (metres) for model-convention joints (rad)."""
        q1, q2, q3, q4, q5, q6 = (float(v) for v in q_model_rad[:6])
        c1, s1 = math.cos(q1), math.sin(q1)
        c2, s2 = math.cos(q2), math.sin(q2)
        cf, sf = math.cos(q2 - q3), math.sin(q2 - q3)
        wrist = _wrist_rotation(q4, q5, q6)
        # Arm rotation Rz(q1) Ry(q2 - q3).
        arm = np.array([[c1 * cf, -s1, c1 * sf], [s1 * cf, c1, s1 * sf], [-sf, 0.0, cf]])
        t = np.eye(4)
        t[:3, :3] = arm @ wrist @ FLANGE_ROTATION
        # Flange position in the arm plane (x forward, z up), then rotated by J1.
        fx, fz = self.d4 + self.d6 * wrist[0, 0], self.a3 + self.d6 * wrist[2, 0]
        x = self.a1 + self.a2 * s2 + cf * fx + sf * fz
        z = self.a2 * c2 - sf * fx + cf * fz
        y = self.d6 * wrist[1, 0]
        t[0, 3] = c1 * x - s1 * y
        t[1, 3] = s1 * x + c1 * y
        t[2, 3] = z
        return t

    def fk_tcp(self, q_model_rad: ArrayLike) -> np.ndarray:
        """4x4 tool (TCP) pose: flange pose times the configured tool offset."""
        return self.fk(q_model_rad) @ self.tool

    def fk_fanuc_deg(self, q_fanuc_deg: ArrayLike) -> np.ndarray:
        """4x4 flange pose for FANUC-convention joints (deg, J3 from the horizontal)."""
        return self.fk(fanuc_deg_to_model_rad(np.asarray(q_fanuc_deg, dtype=float)[:6], self.j23_factor))

    def flange_xyz_mm_fanuc_deg(self, q_fanuc_deg: Sequence[float] | np.ndarray) -> np.ndarray:
        """Flange centre X, Y, Z (mm) for FANUC joints (deg): the limit checker's per-cycle fast path."""
        r = math.radians
        q1, q2, q4, q5 = r(q_fanuc_deg[0]), r(q_fanuc_deg[1]), r(q_fanuc_deg[3]), r(q_fanuc_deg[4])
        q3 = r(q_fanuc_deg[2]) + self.j23_factor * q2
        c1, s1 = math.cos(q1), math.sin(q1)
        cf, sf = math.cos(q2 - q3), math.sin(q2 - q3)
        c4, s4, c5, s5 = math.cos(q4), math.sin(q4), math.cos(q5), math.sin(q5)
        fx, fz = self.d4 + self.d6 * c5, self.a3 + self.d6 * c4 * s5
        x = self.a1 + self.a2 * math.sin(q2) + cf * fx + sf * fz
        z = self.a2 * math.cos(q2) - sf * fx + cf * fz
        y = self.d6 * s4 * s5
        return np.array([(c1 * x - s1 * y) * 1000.0, (s1 * x + c1 * y) * 1000.0, z * 1000.0])

    def wrist_centre(self, q_model_rad: ArrayLike) -> np.ndarray:
        """Wrist centre (intersection of J4, J5, J6 axes), metres, FANUC world frame."""
        q1, q2, q3 = (float(v) for v in q_model_rad[:3])
        cf, sf = math.cos(q2 - q3), math.sin(q2 - q3)
        x = self.a1 + self.a2 * math.sin(q2) + cf * self.d4 + sf * self.a3
        z = self.a2 * math.cos(q2) - sf * self.d4 + cf * self.a3
        return np.array([math.cos(q1) * x, math.sin(q1) * x, z])

    # ---- inverse kinematics (servo_app.robots.ik) -----------------------------------------------

    def ik(self, pose: np.ndarray, *, with_turns: bool = False, within_limits: bool = False,
           seed: ArrayLike | None = None) -> list[IkSolution]:
        """All closed-form solutions for a 4x4 flange pose; see :func:`servo_app.robots.ik.solve`."""
        return solve(self, pose, with_turns=with_turns, within_limits=within_limits, seed=seed)

    def ik_nearest(self, pose: np.ndarray, seed_q: ArrayLike, config: ArmConfiguration | None = None
                   ) -> np.ndarray | None:
        """The in-limits solution nearest ``seed_q``; see :func:`servo_app.robots.ik.nearest`."""
        return nearest(self, pose, seed_q, config)

    def configuration(self, q_model_rad: ArrayLike) -> ArmConfiguration:
        """FANUC configuration of a joint vector; see :mod:`servo_app.robots.configuration`."""
        return configuration_of(q_model_rad, self)

    def ik_tcp(self, tcp_pose: np.ndarray, *, with_turns: bool = False, within_limits: bool = False,
               seed: ArrayLike | None = None) -> list[IkSolution]:
        """Like :meth:`ik` for a TCP pose (the configured tool offset is removed first)."""
        return self.ik(tcp_pose @ self.tool_inv, with_turns=with_turns, within_limits=within_limits, seed=seed)

    def within_limits(self, q_model_rad: ArrayLike, tol: float = 1e-9) -> bool:
        q = np.asarray(q_model_rad, dtype=float)[:6]
        return bool(np.all(q >= self.q_min - tol) and np.all(q <= self.q_max + tol))


def _wrist_rotation(q4: float, q5: float, q6: float) -> np.ndarray:
    """Rx(-q4) Ry(-q5) Rx(-q6), written out (X-Y-X Euler angles -q4, -q5, -q6)."""
    ca, sa = math.cos(q4), -math.sin(q4)
    cb, sb = math.cos(q5), -math.sin(q5)
    cg, sg = math.cos(q6), -math.sin(q6)
    return np.array([
        [cb, sb * sg, sb * cg],
        [sa * sb, ca * cg - sa * cb * sg, -ca * sg - sa * cb * cg],
        [-ca * sb, sa * cg + ca * cb * sg, -sa * sg + ca * cb * cg],
    ])
