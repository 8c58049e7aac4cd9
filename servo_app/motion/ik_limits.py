"""Our own mink limits: joint rates in the controller's convention, braking distance, arm
configuration and a unit-consistent collision limit.

Each class follows mink's ``Limit`` contract: ``compute_qp_inequalities(configuration, dt)`` returns
``Constraint(G, h)`` with ``G @ dq <= h`` for the per-cycle increment ``dq`` (model convention, rad).
Every limit here returns the SAME number of rows every cycle (inactive rows get ``h = +inf``), so a
persistent QP can keep one sparsity pattern.

Why not just mink's limits:

- mink has no acceleration limit; the controller alarms on acceleration, and the jerk-limited shaper
  after the IK can only follow increments whose change per cycle is bounded (``AccelerationLimit``);
- mink's ``ConfigurationLimit`` lets a joint run at full speed until the last cycle before its limit;
  ``BrakingLimit`` keeps every joint able to stop (at its braking deceleration) before its bound;
- the controller's limits apply to the FANUC J3 (from the horizontal), not to the model's q3;
- FANUC alarms when the configuration (flip, up, top, turns) changes (``ConfigurationGuard``);
- mink's ``CollisionAvoidanceLimit`` divides the distance by ``dt`` although ``dq`` is a displacement,
  so at dt = 8 ms it allows 1/dt times the remaining gap per step; ``CollisionLimit`` fixes the units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from mink import Configuration
from mink.limits import CollisionAvoidanceLimit, Constraint, Limit

from servo_app.motion import ik_kernels as kernels
from servo_app.robots.configuration import ArmConfiguration, ConfigurationRegion
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.model import JOINT_NAMES


def fanuc_rate_matrix(j23_factor: float, n: int = 6) -> np.ndarray:
    """``C`` with ``dq_fanuc = C @ dq_model`` (both rad): only J3 couples, J3 = q3 - j23 * q2."""
    c = np.eye(n)
    c[2, 1] = -j23_factor
    return c


def braking_speed(distance: np.ndarray | float, acc: np.ndarray | float, dt: float) -> np.ndarray:
    """Largest speed ``v`` for which one more cycle at ``v`` and then braking at ``acc`` stays within
    ``distance``: ``v * dt + v**2 / (2 acc) <= distance``. Non-positive distances give 0.

    Callers pass ``dt`` plus their limit's ``lag_s``: the jerk-limited shaper downstream needs that
    long to build up the deceleration, and travels on meanwhile.

    Recursively feasible with the acceleration limit: from ``v_k`` at this bound, ``v_k - acc * dt``
    is within next cycle's bound, so a joint that obeys it every cycle can always stop in time.
    """
    d = np.maximum(np.asarray(distance, dtype=float), 0.0)
    a = np.asarray(acc, dtype=float)
    return a * (np.sqrt(dt * dt + 2.0 * d / a) - dt)


def braking_speed_scalar(distance: float, acc: float, dt: float) -> float:
    """:func:`braking_speed` of one value in float arithmetic (same operations, same rounding)."""
    d = distance if distance > 0.0 else 0.0
    return acc * (math.sqrt(dt * dt + 2.0 * d / acc) - dt)


def _dof_columns(model: mujoco.MjModel) -> np.ndarray:
    return np.array([model.jnt_dofadr[model.joint(name).id] for name in JOINT_NAMES])


def _qpos_indices(model: mujoco.MjModel) -> np.ndarray:
    return np.array([model.jnt_qposadr[model.joint(name).id] for name in JOINT_NAMES])


class PathBraking:
    """Deceleration available when the WHOLE motion brakes together along one joint direction ``u``.

    Braking every joint at its own limit would bend the path; braking with one common factor
    ``s(t)`` (``dq = s u``) is limited by the joint that needs the most: ``s'' <= rate`` with
    ``rate = min_i brake_i / |(C u)_i|`` (FANUC axes). A bound whose distance changes at
    ``grad . u`` per unit of ``s`` then closes at most at ``rate * |grad . u|``: that is the
    deceleration its braking row may count on, so stopping along the path is always possible
    (recursively, for a steady direction). Rows the path does not approach get ``floor`` times
    their own cap, so they stay usable when the direction changes.
    """

    def __init__(self, c: np.ndarray, brake_fanuc: Sequence[float], floor: float = 0.05) -> None:
        self.c = np.asarray(c, dtype=float)
        self.brake = np.asarray(brake_fanuc, dtype=float)
        self.floor = floor
        self.u: np.ndarray | None = None
        self.rate = math.inf
        # u's storage: set_direction, and the IK's one-call step, write the direction into it (no allocation).
        self.direction_buffer = np.zeros(len(self.brake))

    def set_direction(self, u: np.ndarray | None) -> None:
        """The joint-space direction (model convention, any scale) the arm moves or will move along."""
        if u is None:
            self.u, self.rate = None, math.inf
            return
        rate = kernels.path_rate(self.c, self.brake, np.ascontiguousarray(u, dtype=float), self.direction_buffer)
        if math.isinf(rate):  # the direction moves no joint
            self.u, self.rate = None, math.inf
            return
        self.u, self.rate = self.direction_buffer, rate

    def decel(self, grad_dot_u: np.ndarray, caps: np.ndarray | float) -> np.ndarray:
        """Deceleration for rows whose closing rate along ``u`` is ``grad_dot_u`` (per unit of s)."""
        caps = np.asarray(caps, dtype=float)
        if self.u is None:
            return np.broadcast_to(caps, np.shape(grad_dot_u)).copy()
        return np.minimum(caps, np.maximum(self.rate * np.abs(grad_dot_u), self.floor * caps))

    def decel_scalar(self, grad_dot_u: float, cap: float) -> float:
        """:meth:`decel` of one row in float arithmetic (a numpy call costs more than the row)."""
        if self.u is None:
            return cap
        return min(cap, max(self.rate * abs(grad_dot_u), self.floor * cap))


class AccelerationLimit(Limit):
    """Velocity and acceleration of the six arm joints in the FANUC convention, per cycle:

        |C dq| <= vel * dt                  (controller velocity check)
        |C (dq - dq_prev)| <= acc * dt**2   (controller acceleration check; the shaper can follow)

    ``set_previous(dq_prev)`` must be called with last cycle's increment (model convention) before
    each solve. If the previous velocity is above ``vel`` (limits lowered), the box allows braking at
    ``acc`` instead of becoming empty. 12 rows: upper bounds, then lower bounds.
    """

    def __init__(self, model: mujoco.MjModel, vel: Sequence[float], acc: Sequence[float],
                 j23_factor: float) -> None:
        self.vel = np.asarray(vel, dtype=float)
        self.acc = np.asarray(acc, dtype=float)
        self.c = fanuc_rate_matrix(j23_factor)
        cols = _dof_columns(model)
        g = np.zeros((12, model.nv))
        g[:6, cols] = self.c
        g[6:, cols] = -self.c
        self._g = g
        self.dq_prev = np.zeros(6)
        self.velocity_bound = np.zeros(12, dtype=bool)  # rows whose bound came from vel (else acc)
        self.h_velocity = np.full(12, np.inf)  # the same rows with the velocity bound only
        # fill()'s per-cycle bounds (set per dt).
        self._dt = math.nan
        self._vmax = np.zeros(6)
        self._da = np.zeros(6)

    def set_previous(self, dq_prev: np.ndarray) -> None:
        self.dq_prev = np.array(dq_prev, dtype=float)  # a copy

    def compute_qp_inequalities(self, configuration: Configuration, dt: float) -> Constraint:
        del configuration
        p = self.c @ self.dq_prev
        vmax = self.vel * dt
        da = self.acc * dt * dt
        upper = np.minimum(np.maximum(vmax, p - da), p + da)
        lower = np.maximum(np.minimum(-vmax, p + da), p - da)
        self.velocity_bound[:6] = upper < p + da
        self.velocity_bound[6:] = lower > p - da
        self.h_velocity = np.concatenate([vmax, vmax])
        return Constraint(G=self._g, h=np.concatenate([upper, -lower]))

    def fill(self, dt: float, h: np.ndarray) -> None:
        """``compute_qp_inequalities``' rows written into ``h`` (12), with no Constraint built: one
        kernel, the same operations in the same order as the reference's numpy ones.

        The lower bounds negated are the upper bounds of ``-p``: ``-max(min(-v, p + a), p - a) ==
        min(max(v, -p - a), -p + a)`` (negation is exact)."""
        vmax, da = self.bounds(dt)
        kernels.acceleration_rows(self.c, self.dq_prev, vmax, da, h, self.velocity_bound)

    def bounds(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(vel * dt, acc * dt**2)`` as the reference rounds them, computed when ``dt`` changes (and
        ``h_velocity`` with them): the per-cycle inputs of the rows' kernel."""
        if self._dt != dt:
            self._dt = dt
            self._vmax = self.vel * dt
            self._da = self.acc * dt * dt  # as the reference rounds it
            self.h_velocity = np.concatenate([self._vmax, self._vmax])
        return self._vmax, self._da


class BrakingLimit(Limit):
    """Each joint stays within ``[lower, upper]`` (model convention, rad) and can always stop before
    it: ``dq_i <= dt * braking_speed(upper_i - q_i, brake_i, dt + lag_s)`` and the mirror image. A joint
    already beyond a bound may only move back. 12 rows: upper bounds, then lower bounds.

    ``restrict`` narrows the joint ranges further (the :class:`ConfigurationGuard`'s intervals): one
    row per bound either way, and ``restricted`` tells which rows the restriction set.

    The returned rows brake each joint on its own: always recursively feasible, whatever the
    direction does. With a :class:`PathBraking`, ``h_path`` also holds the stricter rows for braking
    the whole motion together along the path (for the path-keeping scale).
    """

    lag_s: float = 0.0  # s: how long the shaper downstream takes to build up a deceleration

    def __init__(self, model: mujoco.MjModel, lower: Sequence[float], upper: Sequence[float],
                 brake_acc: Sequence[float], path: PathBraking | None = None) -> None:
        self.range_lower = np.asarray(lower, dtype=float)
        self.range_upper = np.asarray(upper, dtype=float)
        self.brake_acc = np.asarray(brake_acc, dtype=float)
        self._acc = np.concatenate([self.brake_acc, self.brake_acc])
        self.path = path
        self.h_path = np.full(12, np.inf)  # rows with path-synchronised braking (see PathBraking)
        self._qadr = _qpos_indices(model)
        cols = _dof_columns(model)
        self._cols = cols
        g = np.zeros((12, model.nv))
        g[np.arange(6), cols] = 1.0
        g[6 + np.arange(6), cols] = -1.0
        self._g = g
        self.bounds = np.concatenate([self.range_upper, -self.range_lower])  # row i: g_i @ q <= bounds[i]
        self.restricted = np.zeros(12, dtype=bool)
        self._cols_i64 = np.ascontiguousarray(cols, dtype=np.int64)

    @property
    def lower(self) -> np.ndarray:
        return -self.bounds[6:]

    @property
    def upper(self) -> np.ndarray:
        return self.bounds[:6].copy()

    def restrict(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Keep the joints within ``[lower, upper]`` as well as within their ranges."""
        lo = np.maximum(self.range_lower, lower)
        hi = np.minimum(self.range_upper, upper)
        self.restricted = np.concatenate([hi < self.range_upper, lo > self.range_lower])
        self.bounds = np.concatenate([hi, -lo])

    def compute_qp_inequalities(self, configuration: Configuration, dt: float) -> Constraint:
        q = configuration.data.qpos[self._qadr]
        distance = self.bounds - np.concatenate([q, -q])  # to each bound, >= 0 inside (inf: none)
        horizon = dt + self.lag_s
        h = dt * braking_speed(distance, self._acc, horizon)
        self.h_path = h
        if self.path is not None and self.path.u is not None:
            acc = self.path.decel(self.path.u[self._cols], self.brake_acc)
            self.h_path = dt * braking_speed(distance, np.concatenate([acc, acc]), horizon)
        return Constraint(G=self._g, h=h)

    def fill(self, q: np.ndarray, dt: float, h: np.ndarray, h_path: np.ndarray) -> None:
        """``compute_qp_inequalities``' rows and ``h_path`` for the joints ``q`` (model order), written
        into ``h`` and ``h_path`` (12 each) with no Constraint built: one kernel, the reference's
        operations in its order (``dt * braking_speed(...)``)."""
        path = self.path
        with_path = path is not None and path.u is not None
        u = path.u if with_path and path is not None and path.u is not None else q
        rate = path.rate if with_path and path is not None else 0.0
        floor = path.floor if path is not None else 0.0
        kernels.braking_rows(self.bounds, self._acc, self.brake_acc, self._cols_i64, q, dt, self.lag_s, with_path,
                             u, rate, floor, h, h_path)

    def row_data(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
        """What :func:`~servo_app.motion.ik_kernels.braking_rows` takes from this limit: the bounds
        (upper, then lower negated), the deceleration per row and per joint, the dof columns, ``lag_s``."""
        return self.bounds, self._acc, self.brake_acc, self._cols_i64, self.lag_s


@dataclass(frozen=True)
class ConfigurationMargins:
    flip_deg: float = 1.0  # |J5| stays this far from 0 (and from +-180)
    elbow_deg: float = 1.0  # q3 stays this far from the stretched-arm angle
    turn_deg: float = 1.0  # J1, J4, J6 stay this far inside their 360-degree turn
    shoulder_m: float = 0.01  # wrist centre stays this far from the J1 axis
    shoulder_brake_acc: float = 2.0  # m/s^2, braking of the wrist centre toward the J1 axis


def wrist_centre_gradient(q: np.ndarray, kin: ArmKinematics) -> tuple[float, np.ndarray]:
    """:func:`~servo_app.robots.configuration.wrist_centre_offset` (m, > 0: Top) and its gradient
    with respect to the six model joints."""
    q2, q3 = float(q[1]), float(q[2])
    phi = q2 - q3
    cphi, sphi = math.cos(phi), math.sin(phi)
    x = kin.a1 + kin.a2 * math.sin(q2) + kin.d4 * cphi + kin.a3 * sphi
    dphi = -kin.d4 * sphi + kin.a3 * cphi
    grad = np.zeros(6)
    grad[1] = kin.a2 * math.cos(q2) + dphi
    grad[2] = -dphi
    return x, grad


class ConfigurationGuard(Limit):
    """Keeps the arm configuration it was reset with (FANUC MOTN-156 in Cartesian format; we keep it
    in joint format too).

    Flip, up/down and the turn numbers are joint intervals
    (:class:`~servo_app.robots.configuration.ConfigurationRegion`, shrunk by the margins): ``reset``
    hands them to the ``joints`` :class:`BrakingLimit`, which brakes before them as before a joint
    range. This limit's one row is the boundary that is not a joint interval: the wrist centre stays
    on its side of the J1 axis, linearised, braking at ``margins.shoulder_brake_acc``.
    """

    lag_s: float = 0.0  # s: how long the shaper downstream takes to build up a deceleration

    def __init__(self, model: mujoco.MjModel, kin: ArmKinematics, joints: BrakingLimit,
                 margins: ConfigurationMargins | None = None, q_ref: np.ndarray | None = None,
                 path: PathBraking | None = None) -> None:
        self.kin = kin
        self.joints = joints
        self.margins = margins or ConfigurationMargins()
        self.path = path
        self._qadr = _qpos_indices(model)
        self._cols = _dof_columns(model)
        self._g = np.zeros((1, model.nv))
        self.h_path = np.full(1, np.inf)
        self._arm = np.array([kin.a1, kin.a2, kin.a3, kin.d4], dtype=float)  # the arm's (a tool moves only the TCP)
        self._guard_cols = np.ascontiguousarray(self._cols[1:3], dtype=np.int64)
        self.reference: ArmConfiguration | None = None
        if q_ref is not None:
            self.reset(q_ref)

    def reset(self, q_model_rad: np.ndarray) -> ArmConfiguration:
        """Latch the configuration to keep (call when streaming starts)."""
        m = self.margins
        flip, elbow, turn = (math.radians(v) for v in (m.flip_deg, m.elbow_deg, m.turn_deg))
        region = ConfigurationRegion.around(q_model_rad, self.kin, [flip, elbow, 0.0, turn, turn, turn])
        self.joints.restrict(region.lower, region.upper)
        self.reference = region.reference
        return region.reference

    def compute_qp_inequalities(self, configuration: Configuration, dt: float) -> Constraint:
        if self.reference is None:
            self.reset(configuration.data.qpos[self._qadr])
        assert self.reference is not None
        x, grad = wrist_centre_gradient(configuration.data.qpos[self._qadr], self.kin)
        sign = 1.0 if self.reference.top else -1.0
        distance = sign * x - self.margins.shoulder_m
        # Moving toward the axis decreases sign * x: -sign * grad . dq <= braking allowance.
        self._g[0, self._cols] = -sign * grad
        acc = self.margins.shoulder_brake_acc
        horizon = dt + self.lag_s
        h = np.array([dt * float(braking_speed(distance, acc, horizon))])
        self.h_path = h
        if self.path is not None and self.path.u is not None:
            acc = float(self.path.decel(np.array([grad @ self.path.u[self._cols]]), acc)[0])
            self.h_path = np.array([dt * float(braking_speed(distance, acc, horizon))])
        return Constraint(G=self._g, h=h)

    def fill(self, q: np.ndarray, dt: float, g: np.ndarray) -> tuple[float, float]:
        """``compute_qp_inequalities``' row for the joints ``q`` (model order): its coefficients written
        into ``g`` (one row, dof columns), its bound and path bound returned. Float arithmetic: the row
        is a handful of scalars: one kernel, the reference's operations in its order."""
        if self.reference is None:
            self.reset(q)
        assert self.reference is not None
        kin, acc = self.kin, self.margins.shoulder_brake_acc
        h, distance, g1, g2 = kernels.shoulder_row(q, kin.a1, kin.a2, kin.a3, kin.d4, self.margins.shoulder_m, acc,
                                                   self.reference.top, dt, self.lag_s, int(self._cols[1]),
                                                   int(self._cols[2]), g)
        h_path = h
        if self.path is not None and self.path.u is not None:
            u = self.path.u
            acc = self.path.decel_scalar(g1 * float(u[self._cols[1]]) + g2 * float(u[self._cols[2]]), acc)
            h_path = dt * braking_speed_scalar(distance, acc, dt + self.lag_s)
        return h, h_path

    def row_data(self, q: np.ndarray) -> tuple[np.ndarray, float, float, bool, float, np.ndarray]:
        """What :func:`~servo_app.motion.ik_kernels.shoulder_row` takes from this limit at the joints
        ``q`` (latched as the reference if none is): the arm's a1, a2, a3, d4, the shoulder margin, its
        braking deceleration, the side (Top), ``lag_s``, the dof columns of q2 and q3."""
        if self.reference is None:
            self.reset(q)
        assert self.reference is not None
        return (self._arm, self.margins.shoulder_m, self.margins.shoulder_brake_acc, self.reference.top, self.lag_s,
                self._guard_cols)


class CollisionLimit(CollisionAvoidanceLimit):
    """mink's collision avoidance with the per-step units fixed and a braking allowance.

    mink returns ``h = gain * (d - d_min) / dt``, a velocity, for a displacement ``dq``; evaluated with
    dt = 1 the same code gives the displacement ``gain * (d - d_min)``. We further cap it so the two
    geoms can always stop before ``d_min`` at ``brake_acc`` (m/s^2); ``h_path`` as in
    :class:`BrakingLimit`. One row per geom pair; pairs out
    of detection range give ``G = 0, h = inf``. Keep ``collision_detection_distance`` above the
    braking distance at full speed (``v**2 / (2 brake_acc)``), or a fast approach is seen too late.
    """

    lag_s: float = 0.0  # s: how long the shaper downstream takes to build up a deceleration

    def __init__(self, model: mujoco.MjModel, geom_pairs: Sequence, *, brake_acc: float = 3.0,
                 gain: float = 0.85, minimum_distance_from_collisions: float = 0.01,
                 collision_detection_distance: float = 0.2, path: PathBraking | None = None,
                 cache_margin: float = 0.3) -> None:
        super().__init__(model, geom_pairs, gain=gain,
                         minimum_distance_from_collisions=minimum_distance_from_collisions,
                         collision_detection_distance=collision_detection_distance)
        self.brake_acc = brake_acc
        self.path = path
        self.h_path = np.full(self.max_num_contacts, np.inf)
        self._init_near_cache(model, cache_margin)

    def compute_qp_inequalities(self, configuration: Configuration, dt: float) -> Constraint:
        c = super().compute_qp_inequalities(configuration, 1.0)
        h = c.h
        assert h is not None
        active = np.isfinite(h)
        gap = (h[active] - self.bound_relaxation) / self.gain
        relax = self.bound_relaxation
        self.h_path = h.copy()
        if self.path is not None and self.path.u is not None and c.G is not None:
            acc = self.path.decel(c.G[active] @ self.path.u, self.brake_acc)
            self.h_path[active] = np.minimum(h[active], dt * braking_speed(gap, acc, dt + self.lag_s) + relax)
        h[active] = np.minimum(h[active], dt * braking_speed(gap, self.brake_acc, dt + self.lag_s) + relax)
        return Constraint(G=c.G, h=h)

    # ------------------------------------------------------------------ fast rows (the servo cycle)
    # compute_qp_inequalities() runs the narrow phase (mj_geomDistance) on every pair that survives a
    # bounding-sphere test, each cycle. fill() gives the same rows from far fewer narrow phases:
    #
    # - Pairs whose distance is known in closed form (spheres and capsules are segments swept by a
    #   radius, a plane is a half-space: the arm models' geoms) are screened each cycle by one kernel
    #   (kernels.collision_screen, ~2 us for all pairs): only those within detection distance (less an
    #   allowance for the narrow phase's own error) get the reference's narrow phase, which then
    #   gives the row. No state is kept, so a jump across the workspace costs nothing more.
    # - Other pairs (boxes, meshes of a cell) are screened by a cache. A pair's distance changes by at
    #   most sum_j w_j |dq_j| when the joints move by dq (w_j: how far joint j's axis is from the geom
    #   it turns, 0 for joints upstream of both geoms, which turn the pair together; see
    #   _geom_joint_bounds). So a pair known to be at distance d at joints q0 cannot be within
    #   detection distance while d - sum_j w_j |q_j - q0_j| exceeds it, and needs no narrow phase: its
    #   row is inactive, as the reference's narrow phase would find. A refresh classifies those pairs
    #   (near: within detection distance + cache_margin, measured again whenever they could be within
    #   detection distance; far: a lower bound kept) and is due when a far pair could come near.

    # The narrow phase agrees with the closed forms to 1e-15 m here (MuJoCo's own capsule and plane
    # functions); a convex solver would stop within ccd_tolerance (1e-6 m by default): screen with
    # ten times that.
    screen_tolerance = 1e-5  # m

    def _init_near_cache(self, model: mujoco.MjModel, margin: float) -> None:
        pairs = np.array(self.geom_id_pairs, dtype=np.int64).reshape(-1, 2)
        self._pair_g1: list[int] = [int(g) for g in pairs[:, 0]]
        self._pair_g2: list[int] = [int(g) for g in pairs[:, 1]]
        self._pair_b1: list[int] = [int(model.geom_bodyid[g]) for g in self._pair_g1]
        self._pair_b2: list[int] = [int(model.geom_bodyid[g]) for g in self._pair_g2]
        # The screen kernel's inputs: each geom's shape, segment radius and half length, rbound.
        self._pair_g1_arr = np.ascontiguousarray(pairs[:, 0])
        self._pair_g2_arr = np.ascontiguousarray(pairs[:, 1])
        self._geom_shape, self._geom_radius, self._geom_half = _geom_shapes(model)
        self._geom_rbound = np.ascontiguousarray(model.geom_rbound, dtype=float)
        # Pairs the screen knows exactly: two segments, or a plane and a segment.
        shape = self._geom_shape
        self._exact = np.array([sorted((int(shape[a]), int(shape[b]))) in _EXACT_KINDS for a, b in pairs], dtype=bool)
        self._lower_bound = np.zeros(len(pairs))
        self._candidates = np.zeros(len(pairs), dtype=np.int64)
        # The cache covers the pairs the screen cannot decide (indices into the pairs).
        self.cached_pairs: list[int] = [int(i) for i in np.flatnonzero(~self._exact)]
        # Per cached pair and joint: how fast the pair's distance can change with that joint. A joint
        # upstream of both geoms turns them together (no change): only the joints between them count.
        per_joint = _geom_joint_bounds(model)
        weights = np.zeros((len(pairs), model.nv))
        for i in self.cached_pairs:
            r1, r2 = per_joint[pairs[i, 0]], per_joint[pairs[i, 1]]
            both = (r1 > 0.0) & (r2 > 0.0)
            weights[i] = np.where(both, 0.0, r1 + r2)
        self._pair_weights = weights
        # Unbounded geoms (rbound 0 on a moving body, e.g. a height field carried by the arm) cannot be
        # bounded: then every cached pair is checked every cycle (margin 0: refresh each call).
        self._cache_ok = bool(np.all(np.isfinite(weights))) and margin > 0.0
        self.cache_margin = margin
        self._q_refresh: list[float] | None = None
        self._q_refresh_arr = np.zeros(0)
        self._near_weights = self._far_weights = np.zeros((0, model.nv))
        self._far_slack = np.zeros(0)
        self._drift = np.zeros(0)
        self._near: list[int] = []  # cached pairs within detection distance + margin at the last refresh
        self._near_dist: list[float] = []  # ... and their distance then
        self._near_q = np.zeros((0, model.nv))
        # fill()'s narrow phase results (per pair with a row): the pair, its distance, its closest points.
        self._row_pairs = np.zeros(len(pairs), dtype=np.int64)
        self._dists = np.zeros(len(pairs))
        self._fromtos = np.zeros((len(pairs), 6))
        self._fromto_rows = list(self._fromtos)  # its rows as views made once, for mj_geomDistance
        self._pair_b1_arr = np.array(self._pair_b1, dtype=np.int64)
        self._pair_b2_arr = np.array(self._pair_b2, dtype=np.int64)
        self._no_direction = np.zeros(model.nv)  # the row kernel's path direction when there is none
        self._tree, self._dof_parentid = jacobian_tree(model)  # for the row kernel's point Jacobians
        self._fill_params: np.ndarray | None = None  # fill_params()'s array
        self._views: tuple[mujoco.MjData | None, tuple[np.ndarray, ...]] = (None, ())
        self.refreshes = 0

    def _refresh_near(self, data: mujoco.MjData, q: np.ndarray) -> None:
        """Classify every cached pair at the joints ``q``: near (within detection distance + margin: its
        narrow phase runs each cycle, unless it is still provably beyond detection distance) or far,
        with a lower bound on its distance (bounding spheres from the screen, or the narrow phase's
        cap). The next refresh is due when the joints have moved enough for the closest far pair to
        reach detection distance. ``self._lower_bound`` must be this cycle's screen."""
        model = self.model
        detect = self.collision_detection_distance
        distmax = detect + (self.cache_margin if self._cache_ok else 0.0)
        fromto = self._fromto
        bound = self._lower_bound
        near: list[int] = []
        near_dist: list[float] = []
        far: list[int] = []
        far_lb: list[float] = []
        for idx in self.cached_pairs:
            lb = float(bound[idx])
            if lb <= distmax:
                dist = mujoco.mj_geomDistance(model, data, self._pair_g1[idx], self._pair_g2[idx], distmax, fromto)
                if abs(dist - distmax) >= 1e-12:
                    near.append(idx)
                    near_dist.append(dist)
                    continue
                lb = distmax
            far.append(idx)
            far_lb.append(lb)
        self._near, self._near_dist = near, near_dist
        self._near_q = np.tile(np.asarray(q, dtype=float), (len(near), 1))  # joints when each was measured
        self._near_weights = np.ascontiguousarray(self._pair_weights[near])
        self._far_weights = np.ascontiguousarray(self._pair_weights[far])
        self._far_slack = np.array(far_lb, dtype=float) - detect  # how far each far pair may drift before it matters
        self._drift = np.zeros(len(near))  # each near pair's drift since its last measurement (fill())
        self._q_refresh = list(q)
        self._q_refresh_arr = np.array(q, dtype=float)
        self.refreshes += 1

    def fill(self, data: mujoco.MjData, q: np.ndarray, dt: float, g: np.ndarray, h: np.ndarray,
             h_path: np.ndarray) -> None:
        """``compute_qp_inequalities``' rows and ``h_path`` written into ``g`` (pairs x nv), ``h`` and
        ``h_path`` (``data`` at the joints ``q``: ``mj_kinematics`` and ``mj_comPos`` current).

        The screen resets every row and names the exactly known pairs within reach; the narrow phase
        runs on those (and on the cached pairs the cache cannot rule out); the pairs it finds within
        detection distance get their rows from one kernel."""
        if not self.max_num_contacts:
            return
        model = self.model
        distmax = self.collision_detection_distance
        if self._views[0] is not data:  # data's arrays as views made once (an attribute read makes a new one)
            self._views = (data, (data.geom_xpos, data.geom_xmat, data.cdof, data.subtree_com))
        geom_xpos, geom_xmat, cdof, subtree_com = self._views[1]
        if not self.cached_pairs and self._q_refresh is not None:  # every pair exact: one kernel, narrow phases in it
            path = self.path
            with_path = path is not None and path.u is not None
            params = self.fill_params(dt)
            kernels.collision_fill(
                model._address, data._address, geom_xpos, geom_xmat, cdof, subtree_com, self._tree,
                self._dof_parentid, self._geom_shape, self._geom_radius, self._geom_half, self._geom_rbound,
                self._pair_g1_arr, self._pair_g2_arr, self._exact, self._pair_b1_arr, self._pair_b2_arr,
                self._lower_bound, self._candidates, self._row_pairs, self._dists, self._fromtos, self._jac1,
                self._jac2, params, with_path,
                path.u if path is not None and path.u is not None else self._no_direction,
                path.rate if path is not None and with_path else 0.0, path.floor if path is not None else 0.0,
                g, h, h_path)
            return
        count = kernels.collision_screen(self._geom_shape, self._geom_radius, self._geom_half, self._geom_rbound,
                                         self._pair_g1_arr, self._pair_g2_arr, self._exact, geom_xpos, geom_xmat,
                                         self.screen_tolerance, distmax, self._lower_bound, self._candidates, g, h,
                                         h_path)
        rows = 0  # pairs with a row: their index, distance and closest points (the reference's call)
        row_pairs, dists, fromto_of = self._row_pairs, self._dists, self._fromto_rows
        for idx in self._candidates[:count].tolist() if count else ():
            dist = mujoco.mj_geomDistance(model, data, self._pair_g1[idx], self._pair_g2[idx], distmax,
                                          fromto_of[rows])
            if abs(dist - distmax) >= 1e-12:
                row_pairs[rows], dists[rows] = idx, dist
                rows += 1
        if self.cached_pairs or self._q_refresh is None:  # the first fill sets the cache up, even an empty one
            rows = self._cached_rows(data, q, rows)
        if rows:
            path = self.path
            with_path = path is not None and path.u is not None
            kernels.collision_rows(
                rows, row_pairs, dists, self._fromtos, cdof, subtree_com, self._tree, self._dof_parentid,
                self._pair_b1_arr, self._pair_b2_arr, self._jac1, self._jac2, self.gain,
                self.minimum_distance_from_collisions, self.bound_relaxation, self.brake_acc, dt, dt + self.lag_s,
                with_path, path.u if path is not None and path.u is not None else self._no_direction,
                path.rate if path is not None and with_path else 0.0, path.floor if path is not None else 0.0,
                g, h, h_path)

    def fill_params(self, dt: float) -> np.ndarray:
        """collision_fill's scalars, in its order: screen tolerance, detection distance, gain, minimum
        distance, relaxation, braking deceleration, ``dt``, ``lag_s`` (one array, kept: also the IK's
        one-call step reads it through its table)."""
        params = self._fill_params
        if params is None:
            params = self._fill_params = np.zeros(8)
        params[:] = (self.screen_tolerance, self.collision_detection_distance, self.gain,
                     self.minimum_distance_from_collisions, self.bound_relaxation, self.brake_acc, dt, self.lag_s)
        return params

    def _cached_rows(self, data: mujoco.MjData, q: np.ndarray, rows: int) -> int:
        """The cached pairs' narrow phases: the pairs found within detection distance appended to the
        rows (from ``rows`` on); the new count returned. Per pair, a bound on how much its distance can
        have changed since q_refresh: the joints between its two geoms, each turned by
        ``|q - q_refresh|`` (weights: _geom_joint_bounds); a far pair that could be within detection
        distance now calls for a refresh."""
        model = self.model
        distmax = self.collision_detection_distance
        qr = self._q_refresh
        refresh = qr is None or len(qr) != len(q) or not self._cache_ok
        qa = np.array(q, dtype=float)
        drift = self._drift
        if not refresh:
            refresh = kernels.collision_drift(qa, self._q_refresh_arr, self._far_weights, self._near_q,
                                              self._near_weights, self._far_slack, drift)
        if refresh:
            self._refresh_near(data, q)
            drift = [0.0] * len(self._near)
        else:
            drift = drift.tolist()  # floats: read once per near pair below
        near_dist, near_q = self._near_dist, self._near_q
        row_pairs, dists, fromto_of = self._row_pairs, self._dists, self._fromto_rows
        wide = distmax + (self.cache_margin if self._cache_ok else 0.0)
        for k, idx in enumerate(self._near):
            # The pair was at near_dist[k] at the joints near_q[k]: it has changed by at most drift[k].
            if near_dist[k] - drift[k] > distmax:
                continue  # still beyond detection distance: no row, as the narrow phase would find
            g1, g2 = self._pair_g1[idx], self._pair_g2[idx]
            fromto = fromto_of[rows]
            dist = mujoco.mj_geomDistance(model, data, g1, g2, wide, fromto)
            if dist >= distmax:  # no row; remember how far it is, to skip it while it cannot be near
                near_dist[k] = dist
                near_q[k] = qa
                continue
            if wide != distmax:  # the row from the reference's own call (the cut-off may matter to it)
                dist = mujoco.mj_geomDistance(model, data, g1, g2, distmax, fromto)
                if abs(dist - distmax) < 1e-12:
                    continue
            row_pairs[rows], dists[rows] = idx, dist
            rows += 1
        return rows


_EXACT_KINDS = ([kernels.SHAPE_SEGMENT, kernels.SHAPE_SEGMENT], [kernels.SHAPE_SEGMENT, kernels.SHAPE_PLANE])


def _geom_shapes(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per geom, for :func:`~servo_app.motion.ik_kernels.collision_screen`: its shape (spheres and
    capsules are segments, planes half-spaces, anything else ``SHAPE_OTHER``), the segment's radius and
    half length (MuJoCo's ``geom_size``: a capsule's half length along its z axis, 0 for a sphere)."""
    shape = np.full(model.ngeom, kernels.SHAPE_OTHER, dtype=np.int64)
    radius = np.zeros(model.ngeom)
    half = np.zeros(model.ngeom)
    for k in range(model.ngeom):
        kind = int(model.geom_type[k])
        if kind in (int(mujoco.mjtGeom.mjGEOM_SPHERE), int(mujoco.mjtGeom.mjGEOM_CAPSULE)):
            shape[k] = kernels.SHAPE_SEGMENT
            radius[k] = float(model.geom_size[k, 0])
            half[k] = float(model.geom_size[k, 1]) if kind == int(mujoco.mjtGeom.mjGEOM_CAPSULE) else 0.0
        elif kind == int(mujoco.mjtGeom.mjGEOM_PLANE):
            shape[k] = kernels.SHAPE_PLANE
    return shape, radius, half


def jacobian_tree(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """The kinematic tree as :func:`~servo_app.motion.ik_kernels.point_jacobian` walks it (``mj_jac``'s
    walk): rows ``body_rootid``, ``body_dofnum``, ``body_dofadr``, ``body_parentid``; and ``dof_parentid``."""
    tree = np.vstack([model.body_rootid, model.body_dofnum, model.body_dofadr, model.body_parentid])
    return np.ascontiguousarray(tree, dtype=np.int64), np.ascontiguousarray(model.dof_parentid, dtype=np.int64)


def _geom_joint_bounds(model: mujoco.MjModel) -> np.ndarray:
    """``r[k, dof]``: a bound on the distance from joint ``dof``'s axis to any point of geom ``k`` (so
    its points move at most ``r * |dq|`` when that joint turns by ``dq``); 0 for joints not upstream
    of the geom, inf for an unbounded geom (rbound 0) that moves. Configuration-independent: the
    joint anchor's offset, the body offsets along the chain, the geom's offset and bounding radius."""
    out = np.zeros((model.ngeom, model.nv))
    for k in range(model.ngeom):
        body = int(model.geom_bodyid[k])
        tail = float(np.linalg.norm(model.geom_pos[k])) + float(model.geom_rbound[k])  # body origin -> geom
        unbounded = float(model.geom_rbound[k]) <= 0.0
        while body > 0:
            for j in range(int(model.body_jntadr[body]), int(model.body_jntadr[body]) + int(model.body_jntnum[body])):
                dof = int(model.jnt_dofadr[j])
                out[k, dof] = math.inf if unbounded else float(np.linalg.norm(model.jnt_pos[j])) + tail
            tail += float(np.linalg.norm(model.body_pos[body]))  # this body's origin from its parent's
            body = int(model.body_parentid[body])
    return out


def default_collision_pairs(model: mujoco.MjModel) -> list[tuple[list[str], list[str]]]:
    """Geom pairs worth checking on an arm model: every arm geom against every geom fixed to the world
    (floor, walls, fixtures added to the cell's spec), and arm geoms against each other except pairs
    the MJCF excludes (``<contact><exclude>``: housings that overlap by design). mink drops pairs on
    the same body, on parent and child bodies, and pairs that fail contype/conaffinity."""
    excluded = set(int(s) for s in model.exclude_signature)
    world = [g for g in range(model.ngeom) if model.body_weldid[model.geom_bodyid[g]] == 0]
    arm = [g for g in range(model.ngeom) if model.body_weldid[model.geom_bodyid[g]] != 0]

    def name(g: int) -> str:
        n = model.geom(g).name
        if not n:
            raise ValueError(f"geom {g} has no name; name it to use it in collision pairs")
        return n

    def is_excluded(g1: int, g2: int) -> bool:
        b1, b2 = int(model.geom_bodyid[g1]), int(model.geom_bodyid[g2])
        return (b1 << 16) + b2 in excluded or (b2 << 16) + b1 in excluded  # MuJoCo's signature

    pairs: list[tuple[list[str], list[str]]] = []
    for w in world:
        for a in arm:
            pairs.append(([name(w)], [name(a)]))
    for i, g1 in enumerate(arm):
        for g2 in arm[i + 1:]:
            if model.geom_bodyid[g1] != model.geom_bodyid[g2] and not is_excluded(g1, g2):
                pairs.append(([name(g1)], [name(g2)]))
    return pairs
