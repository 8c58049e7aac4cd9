"""Pose arithmetic a script needs without numpy: an offset expressed in the tool's own axes."""

from __future__ import annotations

import math
from collections.abc import Sequence


def offset_in_tool(xyzwpr: Sequence[float], dx: float = 0.0, dy: float = 0.0, dz: float = 0.0) -> tuple[float, ...]:
    """The pose moved by (dx, dy, dz) mm along the tool's own X, Y, Z axes, orientation unchanged.

    FANUC W, P, R are fixed-axis rotations about X, Y, Z: R = Rz(R) Ry(P) Rx(W); the offset in the
    world frame is R @ (dx, dy, dz)."""
    x, y, z, w_deg, p_deg, r_deg = (float(v) for v in xyzwpr)
    w, p, r = math.radians(w_deg), math.radians(p_deg), math.radians(r_deg)
    cw, sw, cp, sp, cr, sr = math.cos(w), math.sin(w), math.cos(p), math.sin(p), math.cos(r), math.sin(r)
    ox = cr * cp * dx + (cr * sp * sw - sr * cw) * dy + (cr * sp * cw + sr * sw) * dz
    oy = sr * cp * dx + (sr * sp * sw + cr * cw) * dy + (sr * sp * cw - cr * sw) * dz
    oz = -sp * dx + cp * sw * dy + cp * cw * dz
    return (x + ox, y + oy, z + oz, w_deg, p_deg, r_deg)
