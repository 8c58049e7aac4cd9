"""What the console needs to draw a Janome robot: the axes are the positions.

- Cartesian robots: the X beam, the Y carriage and the tool.
- SCARA: J1, the elbow (from the profile's arm configuration) and the R shaft down to Z.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from servo_app.janome.kinematics import Unreachable
from servo_app.janome.profile import JanomeProfile
from servo_app.janome.protocol import RobotKind


def janome_view(profile: JanomeProfile, q_xyzr: Sequence[float],
                speeds: Sequence[float] | None = None) -> dict[str, Any]:
    """``speeds``: each axis's speed limit (default the profile's axes.speed)."""
    x, y, z, r = (float(v) for v in q_xyzr[:4])
    lo, hi = list(profile.axis_min), list(profile.axis_max)
    top = hi[2]  # the arm (SCARA) or the beam (Cartesian) at the top of the Z stroke
    scara = profile.kind == RobotKind.SCARA and profile.arm is not None
    if scara:
        arm = profile.arm
        assert arm is not None
        try:
            j1, _ = arm.ik(x, y, int(profile.elbow))
            elbow = [arm.l1 * math.cos(math.radians(j1)), arm.l1 * math.sin(math.radians(j1)), top]
        except Unreachable:  # no feedback yet, or outside the reach: draw the hand alone
            elbow = [x, y, top]
        reach = arm.l1 + arm.l2
        points = [{"name": "base", "xyz_mm": [0.0, 0.0, lo[2]]}, {"name": "J1", "xyz_mm": [0.0, 0.0, top]},
                  {"name": "J2", "xyz_mm": elbow}, {"name": "R", "xyz_mm": [x, y, top]},
                  {"name": "tool", "xyz_mm": [x, y, z], "approach": [0.0, 0.0, -1.0]}]
        box = {"min": [-reach, -reach, lo[2]], "max": [reach, reach, top]}
    else:
        points = [{"name": "beam", "xyz_mm": [x, lo[1], top]}, {"name": "carriage", "xyz_mm": [x, y, top]},
                  {"name": "tool", "xyz_mm": [x, y, z], "approach": [0.0, 0.0, -1.0]}]
        box = {"min": lo[:3], "max": hi[:3]}
    units = ["mm", "mm", "mm", "deg"]
    names = ["X", "Y", "Z", "R"]
    return {
        "backend": "janome",
        "kind": "scara" if scara else "cartesian",
        "model": profile.name,
        "display_name": profile.display_name,
        "dof": 4,
        "joint_names": names,
        "axis_label": "Axis",
        "pose_names": ["X", "Y", "Z", "R"],
        "pose_caption": "tool X Y Z (mm), R (°): controller feedback",
        "axes": [{"name": n, "unit": u, "min": a, "max": b, "speed": v} for n, u, a, b, v in
                 zip(names, units, lo, hi, speeds or profile.speed, strict=True)],
        "j23_factor": 0.0,
        "q": [x, y, z, r],
        "points": points,
        "view_box_mm": box,
    }
