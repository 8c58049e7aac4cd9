"""What the console needs to draw a FANUC six-axis arm: profile geometry and the joint centres from FK.

Read-only and computed on request (a handful of sines), so the console can poll it a few times a
second. The flange point is exactly :meth:`ArmKinematics.fk`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from servo_app.robots.conventions import fanuc_deg_to_model_rad, matrix_to_xyzwpr
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import RobotProfile


def arm_points(kin: ArmKinematics, q_fanuc_deg: Sequence[float]) -> list[dict[str, Any]]:
    """Base, J1..J5 centres and the flange (mm, FANUC world) for FANUC-convention joints (deg)."""
    q = fanuc_deg_to_model_rad(np.asarray(q_fanuc_deg, dtype=float)[:6], kin.j23_factor)
    q1, q2, q3 = (float(v) for v in q[:3])
    c1, s1 = math.cos(q1), math.sin(q1)
    sf, cf = math.sin(q2 - q3), math.cos(q2 - q3)

    def world(x: float, z: float) -> list[float]:
        # Arm-plane (x forward, z up) point rotated by J1, in mm.
        return [c1 * x * 1000.0, s1 * x * 1000.0, z * 1000.0]

    # Same chain as ArmKinematics.fk: J3 at the end of the upper arm, then the forearm's a3 offset
    # (perpendicular) and d4 (along it) to the wrist centre, where the J4, J5, J6 axes meet.
    x3, z3 = kin.a1 + kin.a2 * math.sin(q2), kin.a2 * math.cos(q2)
    pose = kin.fk(q)
    flange = pose[:3, 3] * 1000.0
    approach = pose[:3, 2]  # the flange z axis: which way the tool points
    return [
        {"name": "base", "xyz_mm": [0.0, 0.0, -kin.d1 * 1000.0]},
        {"name": "J1", "xyz_mm": [0.0, 0.0, 0.0]},
        {"name": "J2", "xyz_mm": world(kin.a1, 0.0)},
        {"name": "J3", "xyz_mm": world(x3, z3)},
        {"name": "J4", "xyz_mm": world(x3 + sf * kin.a3, z3 + cf * kin.a3)},
        {"name": "J5", "xyz_mm": [float(v) * 1000.0 for v in kin.wrist_centre(q)]},
        {"name": "flange", "xyz_mm": [float(v) for v in flange],
         "approach": [float(v) for v in approach],
         "xyzwpr": [float(v) for v in matrix_to_xyzwpr(pose)]},  # the tool's TCP is drawn from it
    ]


def fanuc_view(profile: RobotProfile, q_fanuc_deg: Sequence[float]) -> dict[str, Any]:
    kin = ArmKinematics(profile)
    d = profile.dims
    q6 = [float(v) for v in q_fanuc_deg[:6]]
    q_model_deg = np.degrees(fanuc_deg_to_model_rad(np.asarray(q6), profile.j23_factor))
    reach = (d.a1 + d.a2 + math.hypot(d.a3, d.d4) + d.d6) * 1000.0
    names = [f"J{i + 1}" for i in range(profile.dof)]
    return {
        "backend": "fanuc",
        "kind": "arm6",
        "model": profile.name,
        "display_name": profile.display_name,
        "dof": profile.dof,
        "joint_names": names,
        "axis_label": "Joint",
        "pose_names": ["X", "Y", "Z", "W", "P", "R"],
        "pose_caption": "TCP X Y Z (mm), W P R (°): controller feedback (its flange pose times the active tool)",
        # Ranges are in the model convention (J3's FANUC range moves with J2): j23_factor converts.
        "axes": [{"name": n, "unit": "deg", "min": lo, "max": hi, "speed": v} for n, lo, hi, v in
                 zip(names, profile.joint_min_deg, profile.joint_max_deg, profile.vel_limit, strict=True)],
        "j23_factor": profile.j23_factor,
        "dims_mm": {k: getattr(d, k) * 1000.0 for k in ("d1", "a1", "a2", "a3", "d4", "d6")},
        "joint_min_deg": list(profile.joint_min_deg),
        "joint_max_deg": list(profile.joint_max_deg),
        "vel_limit_deg_s": list(profile.vel_limit),
        "max_flange_speed_mm_s": profile.max_flange_speed,
        "q": q6,
        "q_fanuc_deg": q6,
        "q_model_deg": [float(v) for v in q_model_deg],
        "points": arm_points(kin, q6),
        "view_box_mm": {"min": [-reach, -reach, -d.d1 * 1000.0], "max": [reach, reach, reach]},
    }
