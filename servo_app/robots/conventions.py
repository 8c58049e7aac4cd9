"""Unit and angle conventions between the FANUC controller and our kinematic model.

Joints
    *Model convention* (MJCF, FK, IK): radians, each joint relative to its parent link.
    *FANUC convention* (J519 wire, teach pendant): degrees, J3 measured from the horizontal
    (manual 61.5), so ``J3_fanuc = q3_model - j23_factor * q2_model``. ``j23_factor`` is a per-robot
    profile setting: 1 for the controllers of the manual, 0 for a controller that already streams
    model-convention joints. Only J3 differs; other joints are equal up to the unit.

Poses
    FANUC XYZWPR: X Y Z in millimetres, W P R in degrees about the *fixed* X, Y, Z axes, so
    ``R = Rz(R) @ Ry(P) @ Rx(W)``. Matrices here are 4x4 homogeneous transforms in metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

ArrayLike = Sequence[float] | np.ndarray

# Below this |cos P| the W/R split is ill-conditioned (gimbal lock): W is set to 0 and R takes it all.
_GIMBAL_EPS = 1e-9


def fanuc_deg_to_model_rad(q_deg: ArrayLike, j23_factor: float) -> np.ndarray:
    """FANUC joints (deg, J3 from the horizontal) -> model joints (rad). Extra axes pass unchanged
    in radians (only the first six are arm joints)."""
    q = np.radians(np.asarray(q_deg, dtype=float))
    if q.shape[-1] >= 3:
        q[..., 2] = q[..., 2] + j23_factor * q[..., 1]
    return q


def model_rad_to_fanuc_deg(q_rad: ArrayLike, j23_factor: float) -> np.ndarray:
    """Model joints (rad) -> FANUC joints (deg, J3 from the horizontal)."""
    q = np.asarray(q_rad, dtype=float).copy()
    if q.shape[-1] >= 3:
        q[..., 2] = q[..., 2] - j23_factor * q[..., 1]
    return np.degrees(q)


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def wpr_to_rotation(w_deg: float, p_deg: float, r_deg: float) -> np.ndarray:
    """3x3 rotation of FANUC W, P, R (deg, fixed axes X, Y, Z): Rz(R) @ Ry(P) @ Rx(W)."""
    w, p, r = math.radians(w_deg), math.radians(p_deg), math.radians(r_deg)
    cw, sw, cp, sp, cr, sr = math.cos(w), math.sin(w), math.cos(p), math.sin(p), math.cos(r), math.sin(r)
    return np.array([
        [cr * cp, cr * sp * sw - sr * cw, cr * sp * cw + sr * sw],
        [sr * cp, sr * sp * sw + cr * cw, sr * sp * cw - cr * sw],
        [-sp, cp * sw, cp * cw],
    ])


def rotation_to_wpr(rot: np.ndarray) -> tuple[float, float, float]:
    """W, P, R in degrees of a 3x3 rotation; W, R in (-180, 180], P in [-90, 90].

    At gimbal lock (P = +-90) only W - R (P = 90) or W + R (P = -90) is defined: R is reported as 0
    (so the all-zero pose of an arm reads W, P, R = 180, -90, 0).
    Never returns NaN for a finite input (values slightly outside [-1, 1] from rounding are clipped).
    """
    r20 = min(1.0, max(-1.0, float(rot[2, 0])))
    cp = math.hypot(float(rot[0, 0]), float(rot[1, 0]))
    p = math.atan2(-r20, cp)
    if cp > _GIMBAL_EPS:
        w = math.atan2(float(rot[2, 1]), float(rot[2, 2]))
        r = math.atan2(float(rot[1, 0]), float(rot[0, 0]))
    else:
        r = 0.0
        # With R = 0: P = +90 -> R[0,1] = sin W, R[1,1] = cos W; P = -90 -> R[0,1] = -sin W.
        w = math.atan2(math.copysign(1.0, -r20) * float(rot[0, 1]), float(rot[1, 1]))
    return _wrap_deg(math.degrees(w)), math.degrees(p), _wrap_deg(math.degrees(r))


def _wrap_deg(a: float) -> float:
    """Wrap to (-180, 180]."""
    a = math.fmod(a, 360.0)
    if a <= -180.0:
        a += 360.0
    elif a > 180.0:
        a -= 360.0
    return a


def xyzwpr_to_matrix(xyzwpr: ArrayLike) -> np.ndarray:
    """FANUC X Y Z (mm) W P R (deg) -> 4x4 homogeneous transform in metres."""
    x, y, z, w, p, r = (float(v) for v in xyzwpr[:6])
    t = np.eye(4)
    t[:3, :3] = wpr_to_rotation(w, p, r)
    t[:3, 3] = (x / 1000.0, y / 1000.0, z / 1000.0)
    return t


def matrix_to_xyzwpr(t: np.ndarray) -> np.ndarray:
    """4x4 transform in metres -> FANUC X Y Z (mm) W P R (deg), shape (6,). See rotation_to_wpr."""
    w, p, r = rotation_to_wpr(t[:3, :3])
    return np.array([t[0, 3] * 1000.0, t[1, 3] * 1000.0, t[2, 3] * 1000.0, w, p, r])
