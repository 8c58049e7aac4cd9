"""Compiled kernels of the arm's conventions, configuration region and flange position (numba).

The servo cycle tests dozens of joint vectors a cycle against the held configuration and computes
the flange position up to four times: as numpy calls on 6-vectors that was most of a joint-jog
cycle. The arithmetic is written in the same order as the numpy readings it replaces
(``conventions.fanuc_deg_to_model_rad``, ``ConfigurationRegion.contains``,
``ArmKinematics.flange_xyz_mm_fanuc_deg``), which tests/test_robots_kernels.py checks against them.

A configuration region travels as one float64 array (:func:`pack_region`), so a kernel call
converts one argument instead of a dozen.
"""

from __future__ import annotations

import math

import numpy as np

from servo_app.jit import kernel

DEG_TO_RAD = math.pi / 180.0  # numpy's radians() multiplies by this constant (and so does math.radians)
RAD_TO_DEG = 180.0 / math.pi

# Layout of a packed region: the joint box, the arm dimensions the Top/Bottom test needs, its side
# (1.0: Top) and its margin (m).
REGION_LOWER, REGION_UPPER = 0, 6
REGION_A1, REGION_A2, REGION_A3, REGION_D4 = 12, 13, 14, 15
REGION_TOP, REGION_TOP_MARGIN = 16, 17
REGION_SIZE = 18

# Layout of packed arm dimensions for the flange position (m).
DIMS_A1, DIMS_A2, DIMS_A3, DIMS_D4, DIMS_D6 = 0, 1, 2, 3, 4
DIMS_SIZE = 5


def pack_region(lower: np.ndarray, upper: np.ndarray, a1: float, a2: float, a3: float, d4: float,
                top: bool, top_margin_m: float) -> np.ndarray:
    packed = np.empty(REGION_SIZE)
    packed[REGION_LOWER:REGION_LOWER + 6] = lower
    packed[REGION_UPPER:REGION_UPPER + 6] = upper
    packed[REGION_A1], packed[REGION_A2], packed[REGION_A3], packed[REGION_D4] = a1, a2, a3, d4
    packed[REGION_TOP] = 1.0 if top else 0.0
    packed[REGION_TOP_MARGIN] = top_margin_m
    return packed


def pack_dims(a1: float, a2: float, a3: float, d4: float, d6: float) -> np.ndarray:
    return np.array([a1, a2, a3, d4, d6], dtype=float)


@kernel("boolean(float64, float64, float64, float64, float64, float64, float64[::1])")
def joints_in_region(q1: float, q2: float, q3: float, q4: float, q5: float, q6: float, region: np.ndarray) -> bool:
    """One model-convention joint vector (rad) inside a packed region: ``ConfigurationRegion.contains``."""
    q = (q1, q2, q3, q4, q5, q6)
    for i in range(6):
        if not (q[i] >= region[REGION_LOWER + i] and q[i] <= region[REGION_UPPER + i]):
            return False
    phi = q2 - q3
    x = (region[REGION_A1] + region[REGION_A2] * math.sin(q2) + region[REGION_D4] * math.cos(phi)
         + region[REGION_A3] * math.sin(phi))
    side = x > 0.0 if region[REGION_TOP] == 1.0 else x <= 0.0
    return side and abs(x) >= region[REGION_TOP_MARGIN]


@kernel("void(float64[:, :], float64[::1], boolean[::1])")
def rows_in_region(q_model_rad: np.ndarray, region: np.ndarray, out: np.ndarray) -> None:
    """Per row of ``q_model_rad`` (n, >= 6): inside the packed region."""
    for k in range(q_model_rad.shape[0]):
        q = q_model_rad[k]
        out[k] = joints_in_region(q[0], q[1], q[2], q[3], q[4], q[5], region)


@kernel("boolean(float64[::1], float64, float64[::1])")
def fanuc_deg_in_region(q_fanuc_deg: np.ndarray, j23_factor: float, region: np.ndarray) -> bool:
    """FANUC joints (deg) converted as ``fanuc_deg_to_model_rad`` does, then :func:`joints_in_region`."""
    q2 = q_fanuc_deg[1] * DEG_TO_RAD
    q3 = q_fanuc_deg[2] * DEG_TO_RAD + j23_factor * q2
    return joints_in_region(q_fanuc_deg[0] * DEG_TO_RAD, q2, q3, q_fanuc_deg[3] * DEG_TO_RAD,
                            q_fanuc_deg[4] * DEG_TO_RAD, q_fanuc_deg[5] * DEG_TO_RAD, region)


@kernel("UniTuple(float64, 3)(float64[::1], float64, float64[::1])")
def flange_point_mm(q_fanuc_deg: np.ndarray, j23_factor: float, dims: np.ndarray) -> tuple[float, float, float]:
    """Flange centre X, Y, Z (mm) of FANUC joints (deg): ``ArmKinematics.flange_xyz_mm_fanuc_deg``."""
    a1, a2, a3, d4, d6 = dims[DIMS_A1], dims[DIMS_A2], dims[DIMS_A3], dims[DIMS_D4], dims[DIMS_D6]
    q1, q2 = q_fanuc_deg[0] * DEG_TO_RAD, q_fanuc_deg[1] * DEG_TO_RAD
    q4, q5 = q_fanuc_deg[3] * DEG_TO_RAD, q_fanuc_deg[4] * DEG_TO_RAD
    q3 = q_fanuc_deg[2] * DEG_TO_RAD + j23_factor * q2
    c1, s1 = math.cos(q1), math.sin(q1)
    cf, sf = math.cos(q2 - q3), math.sin(q2 - q3)
    c4, s4, c5, s5 = math.cos(q4), math.sin(q4), math.cos(q5), math.sin(q5)
    fx, fz = d4 + d6 * c5, a3 + d6 * c4 * s5
    x = a1 + a2 * math.sin(q2) + cf * fx + sf * fz
    z = a2 * math.cos(q2) - sf * fx + cf * fz
    y = d6 * s4 * s5
    return (c1 * x - s1 * y) * 1000.0, (s1 * x + c1 * y) * 1000.0, z * 1000.0


@kernel("float64(float64[::1], float64[::1], float64, float64[::1])")
def flange_distance_mm(q0_fanuc_deg: np.ndarray, q1_fanuc_deg: np.ndarray, j23_factor: float,
                       dims: np.ndarray) -> float:
    """Distance (mm) between the flange centres of two FANUC joint vectors (deg)."""
    x0, y0, z0 = flange_point_mm(q0_fanuc_deg, j23_factor, dims)
    x1, y1, z1 = flange_point_mm(q1_fanuc_deg, j23_factor, dims)
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@kernel("void(float64[:, ::1], float64, float64[::1], float64, float64[::1])")
def flange_speeds_mm_s(q_fanuc_deg: np.ndarray, j23_factor: float, dims: np.ndarray, dt: float,
                       out: np.ndarray) -> None:
    """Flange-centre speed (mm/s) from each row of FANUC joints (deg) to the next, ``dt`` apart, into
    ``out`` (one fewer than the rows): a whole plan at once, each point as the checker computes it."""
    x0, y0, z0 = flange_point_mm(q_fanuc_deg[0], j23_factor, dims)
    for i in range(1, q_fanuc_deg.shape[0]):
        x1, y1, z1 = flange_point_mm(q_fanuc_deg[i], j23_factor, dims)
        dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
        out[i - 1] = math.sqrt(dx * dx + dy * dy + dz * dz) / dt
        x0, y0, z0 = x1, y1, z1


@kernel("void(float64[::1], float64, float64[::1])")
def fanuc_deg_to_model_rad_into(q_fanuc_deg: np.ndarray, j23_factor: float, out: np.ndarray) -> None:
    """``conventions.fanuc_deg_to_model_rad`` of a joint vector, into ``out``."""
    for i in range(q_fanuc_deg.shape[0]):
        out[i] = q_fanuc_deg[i] * DEG_TO_RAD
    if q_fanuc_deg.shape[0] >= 3:
        out[2] = out[2] + j23_factor * out[1]
