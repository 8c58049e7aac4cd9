"""Closed-form inverse kinematics of the ortho-parallel arm with a spherical wrist.

This is the OPW solution (Brandstoetter, Angerer, Hofbaur 2014; parameters a1 = a1, a2 = -a3, b = 0,
c1 = d1, c2 = a2, c3 = d4, c4 = d6) written out directly for this chain's axis signs (J3, J5 about -y;
J4, J6 about -x) instead of mapping through the paper's sign offsets; tests check it against FK.

Steps: the wrist centre ``C = p - d6 * z_flange`` fixes J1 (front or back: Top/Bottom), then the
planar two-link problem J2/J3 (elbow Up/Down), then the wrist rotation ``Rx(-q4) Ry(-q5) Rx(-q6)``
as X-Y-X Euler angles (No-flip/Flip): 2 x 2 x 2 = 8 solutions.

Degenerate cases never give NaN:

- unreachable wrist centre for a branch: that branch has no solution (an empty list overall);
- shoulder singularity (wrist centre on the J1 axis): J1 is free, the seed's J1 (else 0) is used;
- wrist singularity (J5 = 0 or 180 deg): only J4 + J6 (or J4 - J6) is defined; J4 is taken from the
  seed (else 0), J6 gets the rest, and a single wrist solution is returned for that arm branch;
- solutions near such a case carry ``singular=True``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from servo_app.robots.configuration import ArmConfiguration, configuration_of, wrap_pi
from servo_app.robots.conventions import ArrayLike
from servo_app.robots.geometry import FLANGE_ROTATION, ArmGeometry

_DEGENERATE = 1e-9  # below this the free angle is chosen (exact singularity, up to rounding)
SINGULAR_TOL = 1e-6  # solutions closer than this (sine / metres) to a singularity are flagged
_REACH_TOL = 1e-9  # relative slack on the elbow's law of cosines before a pose is unreachable
_TWO_PI = 2.0 * math.pi
_LIMIT_TOL = 1e-9  # rad, as ArmKinematics.within_limits


@dataclass(frozen=True)
class IkSolution:
    q_model_rad: np.ndarray
    config: ArmConfiguration
    singular: bool  # near a shoulder, elbow or wrist singularity: neighbours may be far in joint space
    within_limits: bool


def solve(kin: ArmGeometry, pose: np.ndarray, *, with_turns: bool = False, within_limits: bool = False,
          seed: ArrayLike | None = None) -> list[IkSolution]:
    """All solutions for a 4x4 flange pose (FANUC world frame, metres).

    Without ``with_turns``: up to 8 solutions, J1, J4, J6 in (-180, 180] (turn 0) and J2, J3, J5 in
    (-180, 180] or moved by 360 into their range when that fits. With ``with_turns``: also every
    360-degree copy of any joint that fits inside the joint ranges (turn numbers of J1, J4, J6 != 0).
    ``within_limits`` drops solutions outside the joint ranges. A non-finite or malformed pose gives [].
    """
    t = np.asarray(pose, dtype=float)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        return []
    seed_q = None if seed is None else np.asarray(seed, dtype=float)
    out: list[IkSolution] = []
    for q, singular in _base_solutions(kin, t, seed_q):
        base = _into_range(kin, q)
        variants = _turn_variants(kin, base) if with_turns else [base]
        for v in variants:
            ok = kin.within_limits(v)
            if within_limits and not ok:
                continue
            out.append(IkSolution(v, configuration_of(v, kin), singular, ok))
    return out


def nearest(kin: ArmGeometry, pose: np.ndarray, seed_q: ArrayLike,
            config: ArmConfiguration | None = None) -> np.ndarray | None:
    """The in-limits solution closest to ``seed_q`` (Euclidean in joint space), optionally only of
    ``config`` (flip, up, top *and* turn numbers must match). None when there is none."""
    seed = np.asarray(seed_q, dtype=float)[:6]
    best, best_d = None, math.inf
    for s in solve(kin, pose, with_turns=True, within_limits=True, seed=seed):
        if config is not None and s.config != config:
            continue
        d = float(np.sum((s.q_model_rad - seed) ** 2))
        if d < best_d:
            best, best_d = s.q_model_rad, d
    return None if best is None else best.copy()


def _base_solutions(kin: ArmGeometry, t: np.ndarray, seed: np.ndarray | None
                    ) -> list[tuple[np.ndarray, bool]]:
    rot = t[:3, :3]
    c = t[:3, 3] - kin.d6 * rot[:, 2]  # wrist centre
    rho = math.hypot(c[0], c[1])
    shoulder_singular = rho < SINGULAR_TOL
    q1_front = (float(seed[0]) if seed is not None else 0.0) if rho < _DEGENERATE else math.atan2(c[1], c[0])
    length = math.hypot(kin.a3, kin.d4)  # J3 -> wrist centre
    psi = math.atan2(kin.a3, kin.d4)
    out = []
    for top in (True, False):
        q1 = q1_front if top else q1_front + math.pi
        # Wrist centre in the J2 frame of the arm plane (x forward, z up).
        x = (rho if top else -rho) - kin.a1
        z = float(c[2])
        k = (x * x + z * z - kin.a2 ** 2 - length ** 2) / (2.0 * kin.a2 * length)
        if abs(k) > 1.0 + _REACH_TOL:
            continue
        k = min(1.0, max(-1.0, k))
        theta = math.asin(k)
        elbow_singular = math.cos(theta) < SINGULAR_TOL
        for up in (True, False):
            if not up and math.cos(theta) < _DEGENERATE:
                continue  # stretched or folded: both elbow branches coincide
            q3 = theta - psi if up else math.pi - theta - psi
            c3, s3 = math.cos(q3), math.sin(q3)
            q2 = math.atan2(x, z) - math.atan2(kin.d4 * c3 - kin.a3 * s3, kin.a2 + kin.a3 * c3 + kin.d4 * s3)
            for wrist, wrist_singular in _wrist_solutions(q1, q2, q3, rot, seed):
                q = np.array([q1, q2, q3, *wrist])
                out.append((q, shoulder_singular or elbow_singular or wrist_singular))
    return out


def _wrist_solutions(q1: float, q2: float, q3: float, rot: np.ndarray, seed: np.ndarray | None
                     ) -> list[tuple[tuple[float, float, float], bool]]:
    """(q4, q5, q6) with Rx(-q4) Ry(-q5) Rx(-q6) = (Rz(q1) Ry(q2 - q3))^T R R0^T."""
    c1, s1, cf, sf = math.cos(q1), math.sin(q1), math.cos(q2 - q3), math.sin(q2 - q3)
    arm = np.array([[c1 * cf, -s1, c1 * sf], [s1 * cf, c1, s1 * sf], [-sf, 0.0, cf]])
    m = arm.T @ rot @ FLANGE_ROTATION.T
    sb = math.hypot(m[1, 0], m[2, 0])
    singular = sb < SINGULAR_TOL
    if sb < _DEGENERATE:
        # Only a sum (or difference) of J4 and J6 is defined: keep the seed's J4.
        beta = 0.0 if m[0, 0] > 0 else math.pi
        alpha = -(float(seed[3]) if seed is not None else 0.0)
        # Rx(gamma) = Ry(beta)^T Rx(alpha)^T M
        ca, sa, cb, sbb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
        rx_t = np.array([[1.0, 0.0, 0.0], [0.0, ca, sa], [0.0, -sa, ca]])
        ry_t = np.array([[cb, 0.0, -sbb], [0.0, 1.0, 0.0], [sbb, 0.0, cb]])
        n = ry_t @ rx_t @ m
        gamma = math.atan2(n[2, 1], n[1, 1])
        return [((-alpha, -beta, -gamma), True)]
    beta = math.atan2(sb, m[0, 0])
    alpha = math.atan2(m[1, 0], -m[2, 0])
    gamma = math.atan2(m[0, 1], m[0, 2])
    # q = -angle: the first has J5 <= 0 (No-flip), the second (alpha + pi, -beta, gamma + pi) Flip.
    return [((-alpha, -beta, -gamma), singular),
            ((-(alpha + math.pi), beta, -(gamma + math.pi)), singular)]


def _into_range(kin: ArmGeometry, q: np.ndarray) -> np.ndarray:
    """Wrap every joint to (-pi, pi]; J2, J3, J5 (no turn number) move by 2 pi if that enters their range."""
    out = np.array([wrap_pi(float(v)) for v in q])
    for i in (1, 2, 4):
        if not _fits(kin, i, out[i]):
            for shifted in (out[i] + _TWO_PI, out[i] - _TWO_PI):
                if _fits(kin, i, shifted):
                    out[i] = shifted
                    break
    return out


def _turn_variants(kin: ArmGeometry, q: np.ndarray) -> list[np.ndarray]:
    """``q`` plus every combination of 360-degree copies that fit the joint ranges."""
    options = []
    for i in range(6):
        vals = [q[i]]
        for k in (-2, -1, 1, 2):
            v = q[i] + k * _TWO_PI
            if _fits(kin, i, v):
                vals.append(v)
        options.append(vals)
    return [np.array(combo) for combo in itertools.product(*options)]


def _fits(kin: ArmGeometry, i: int, v: float) -> bool:
    # Same slack as ArmGeometry.within_limits: a limit of exactly 190 deg must admit -190 from 170 - 360.
    return kin.q_min[i] - _LIMIT_TOL <= v <= kin.q_max[i] + _LIMIT_TOL
