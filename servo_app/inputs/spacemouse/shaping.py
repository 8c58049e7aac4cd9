"""From six raw SpaceMouse counts to a twist in mm/s and deg/s.

Order matters: remap axes into the robot convention, normalise by full scale, deadband (so a cap
at rest that reads a few counts commands nothing), response curve, drop disabled groups, then the
dominant-axis lock (after the masks, so a disabled group cannot win it), then scale to speeds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from servo_app.inputs.shaping import clamp, cubic_blend, deadband_normalized

# The HID reports use X right, Y toward the user and Z down. Turning that half a turn about X gives
# X right, Y away from the user, Z up, the way a robot base frame is usually drawn; the same proper
# rotation applies to both the translation and the rotation vector.
DEFAULT_AXIS_SIGNS = (1, -1, -1, 1, -1, -1)


@dataclass(frozen=True)
class Shaping:
    full_scale: float = 350.0
    deadband: float = 0.05  # fraction of full scale
    curve: float = 0.0  # cubic blend factor, 0 = linear, 1 = pure cubic
    dominant_axis: bool = False
    translation: bool = True
    rotation: bool = True
    max_linear_mm_s: float = 100.0
    max_angular_deg_s: float = 30.0
    axis_map: tuple[int, ...] = (0, 1, 2, 3, 4, 5)  # output axis i takes raw axis axis_map[i]
    axis_signs: tuple[int, ...] = DEFAULT_AXIS_SIGNS
    scale: float = 1.0  # overall speed override


def shape(raw: Sequence[float], s: Shaping) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    u = [s.axis_signs[i] * raw[s.axis_map[i]] / s.full_scale for i in range(6)]
    u = [cubic_blend(deadband_normalized(clamp(x, -1.0, 1.0), s.deadband), s.curve) for x in u]
    if not s.translation:
        u[0:3] = [0.0, 0.0, 0.0]
    if not s.rotation:
        u[3:6] = [0.0, 0.0, 0.0]
    if s.dominant_axis and any(u):
        k = max(range(6), key=lambda i: abs(u[i]))
        u = [x if i == k else 0.0 for i, x in enumerate(u)]
    lin = s.max_linear_mm_s * s.scale
    ang = s.max_angular_deg_s * s.scale
    return (u[0] * lin, u[1] * lin, u[2] * lin), (u[3] * ang, u[4] * ang, u[5] * ang)
