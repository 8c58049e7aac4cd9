"""The diff-IK as it was before issue 15 (commit f31c1c5), kept verbatim as the reference the fast
implementation in :mod:`servo_app.motion.diffik` is compared with (tests/test_diffik_equivalence.py),
but for later changes of behaviour made to both: a pose target's reference slides along its line
to the goal (``_along_track_to``), and there is no pull-back once it has arrived; and a pose target's
line runs no faster than its turn in joint space lets the arm follow it (``_turn_cap``); and an
infeasible QP is solved again with its rows within the acceleration's reach (``_within_reach``), a
failed one brakes the joints in proportion (``_decelerate``).

It assembles its QP from mink task and limit objects every cycle (``compute_qp_objective`` /
``compute_qp_inequalities``); the limits in :mod:`servo_app.motion.ik_limits` keep that contract.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import mink
import mujoco
import numpy as np

from servo_app.motion.commands import Command, JointJog, JointTarget, PoseTarget, Twist
from servo_app.motion.diffik import _within_reach
from servo_app.motion.ik_limits import (
    AccelerationLimit,
    BrakingLimit,
    CollisionLimit,
    ConfigurationGuard,
    ConfigurationMargins,
    PathBraking,
    braking_speed,
    default_collision_pairs,
    fanuc_rate_matrix,
)
from servo_app.motion.qp import PersistentQP, QpSettings, SolverName
from servo_app.robots.configuration import ArmConfiguration
from servo_app.robots.conventions import ArrayLike, fanuc_deg_to_model_rad, model_rad_to_fanuc_deg, xyzwpr_to_matrix
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.model import FLANGE_SITE, JOINT_NAMES, TCP_SITE, load_model
from servo_app.robots.profile import RobotProfile

N = 6


class IkFlag(enum.IntFlag):
    NONE = 0
    JOINT_LIMIT = enum.auto()  # a joint range / braking-distance row binds
    VELOCITY_LIMIT = enum.auto()
    ACCEL_LIMIT = enum.auto()  # ramping: the change of velocity is at its bound
    NEAR_SINGULARITY = enum.auto()  # condition number above singularity_slow
    SINGULARITY_SLOWDOWN = enum.auto()  # approach toward a singularity slowed
    COLLISION = enum.auto()  # a collision row binds
    CONFIGURATION = enum.auto()  # a configuration-keeping row binds (flip/up/top/turns)
    PATH_BLEND = enum.auto()  # direction change the acceleration cannot follow at once: straight velocity blend
    QP_FALLBACK = enum.auto()  # neither line nor blend fits the limits: the QP's best tracking
    SOLVER_FAILED = enum.auto()  # QP failed: the motion brakes at the acceleration limit (_decelerate)
    NO_COMMAND = enum.auto()  # no live command: stopping along the current motion
    ARRIVED = enum.auto()  # pose / joint target reached


LIMIT_FLAGS = IkFlag.JOINT_LIMIT | IkFlag.VELOCITY_LIMIT | IkFlag.ACCEL_LIMIT

# What holds a Cartesian motion back, in an operator's words (the flags that explain a slow-down).
HOLDING_BACK = {IkFlag.JOINT_LIMIT: "joint limit", IkFlag.VELOCITY_LIMIT: "joint speed limit",
                IkFlag.SINGULARITY_SLOWDOWN: "singularity", IkFlag.COLLISION: "collision guard",
                IkFlag.CONFIGURATION: "configuration boundary"}


def holding_back(flags: int) -> list[str]:
    """The reasons in ``flags`` that hold a Cartesian motion back, most specific first."""
    return [word for flag, word in HOLDING_BACK.items() if flags & flag]


@dataclass(frozen=True)
class IkSettings:
    """Tuning of the diff-IK; units in the names. Fractions are of the profile's limits."""

    vel_fraction: float = 0.9  # joint speed the IK may request
    acc_fraction: float = 0.5  # joint acceleration: headroom for the shaper's jerk limit
    brake_fraction: float = 0.8  # of the IK acceleration, used for braking-distance rows
    joint_margin_deg: float = 0.5  # keep this far inside the joint ranges
    margins: ConfigurationMargins = field(default_factory=ConfigurationMargins)
    position_cost: float = 1.0  # 1/m
    orientation_cost: float = 0.3  # 1/rad: 1 rad ~ 0.3 m
    posture_cost: float = 1e-3  # 1/rad: a regulariser, far below the frame task
    posture_gain: float = 0.1
    damping: float = 1e-8
    singularity_slow: float = 40.0  # condition number where approaching motion starts to slow
    singularity_stop: float = 150.0  # ... and where it stops (J5 ~ 2-3 deg on an LR Mate)
    singularity_rate: float = 1.0  # relative growth of the condition number per rad counted as "approaching"
    pose_gain: float = 10.0  # 1/s, P-gain of pose and joint targets (gain * dt must stay < 1)
    target_linear_acc: float = 2000.0  # mm/s^2, braking profile toward a pose target
    target_angular_acc: float = 720.0  # deg/s^2
    line_turn_fraction: float = 0.1  # a pose line's share of the acceleration for its turn in joint space
    arrive_mm: float = 0.01
    arrive_deg: float = 0.01
    reference_tolerance_m: float = 1e-3  # re-latch the integrated TCP reference beyond this drift
    binding_tol: float = 1e-9  # rad per cycle: a row counts as binding within this of its bound
    # The jerk-limited shaper builds a deceleration at its jerk limit: braking distances allow for the
    # time that takes (None: the largest acc/jerk ratio of the profile's axes).
    follow_lag_s: float | None = None
    # Time constant of the pull-back onto the commanded line (None: all of it in one cycle). The shaper
    # follows the IK a little late: pulled back in one cycle, a Cartesian jog swung 2-5 mm off its
    # line; at 30 ms it stays within 0.3 mm (LR Mate, 100-230 mm/s, 4 and 8 ms).
    correction_s: float | None = 0.03

    def __post_init__(self) -> None:
        for name in ("vel_fraction", "acc_fraction", "brake_fraction"):
            v = getattr(self, name)
            if not 0.0 < v <= 1.0:
                raise ValueError(f"{name}={v} must be in (0, 1]")
        if not 0.0 < self.singularity_slow < self.singularity_stop:
            raise ValueError(f"singularity_slow={self.singularity_slow} must be in (0, singularity_stop="
                             f"{self.singularity_stop})")


@dataclass(frozen=True)
class IkResult:
    dq: np.ndarray  # increment this cycle, model convention, rad
    q_next: np.ndarray  # q + dq
    velocity: np.ndarray  # dq / dt, rad/s
    scale: float  # share of the commanded motion delivered this cycle, [0, 1]
    flags: IkFlag
    condition: float  # condition number of the normalised flange Jacobian at q
    mode: str  # "twist", "pose", "joint_jog", "joint_target", "stop"
    solver_status: str  # "" when the QP solution was not needed

    @property
    def limit_binding(self) -> bool:
        return bool(self.flags & LIMIT_FLAGS)

    @property
    def near_singularity(self) -> bool:
        return bool(self.flags & (IkFlag.NEAR_SINGULARITY | IkFlag.SINGULARITY_SLOWDOWN))

    @property
    def collision_guard(self) -> bool:
        return bool(self.flags & IkFlag.COLLISION)

    @property
    def configuration_guard(self) -> bool:
        return bool(self.flags & IkFlag.CONFIGURATION)

    @property
    def arrived(self) -> bool:
        return bool(self.flags & IkFlag.ARRIVED)


class DifferentialIK:
    """Per-cycle diff-IK of one arm; see the module docstring.

    ``collision=True`` adds the collision limit over ``collision_pairs`` (default:
    :func:`~servo_app.motion.ik_limits.default_collision_pairs`: the arm against the floor and any
    world geom, and against itself). A cell with walls or fixtures passes its own ``model`` (built
    with :func:`servo_app.robots.model.load_spec`, geoms added to the world body).
    """

    def __init__(self, profile: RobotProfile, dt: float, tool_xyzwpr: ArrayLike | None = None,
                 solver: SolverName = "osqp", *, settings: IkSettings | None = None, collision: bool = False,
                 collision_pairs: list | None = None, model: mujoco.MjModel | None = None,
                 qp_settings: QpSettings | None = None) -> None:
        if not (isinstance(dt, int | float) and math.isfinite(dt) and 0.0 < dt <= 0.1):
            raise ValueError(f"dt={dt!r} must be a cycle time in (0, 0.1] s")
        self.profile = profile
        self.dt = float(dt)
        self.settings = st = settings or IkSettings()
        self.model = model if model is not None else load_model(profile, tool_xyzwpr)
        self.kin = ArmKinematics(profile, tool_xyzwpr)
        self.configuration = mink.Configuration(self.model)
        self._probe = mujoco.MjData(self.model)
        self._qadr = np.array([self.model.jnt_qposadr[self.model.joint(n).id] for n in JOINT_NAMES])
        self._cols = np.array([self.model.jnt_dofadr[self.model.joint(n).id] for n in JOINT_NAMES])
        if self.model.nv != N or self.model.nq != N:
            raise ValueError(f"model has nq={self.model.nq}, nv={self.model.nv}; the diff-IK expects a 6-joint arm")
        self.site = TCP_SITE if mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, TCP_SITE) >= 0 else FLANGE_SITE
        self._site_id = self.model.site(self.site).id
        self._flange_id = self.model.site(FLANGE_SITE).id
        d = profile.dims
        self._reach = d.a2 + d.d4  # m: scales the Jacobian's linear rows for the condition number

        # Limits in rad, FANUC axes for rates; the braking deceleration of the model's q3 must leave
        # the FANUC J3 enough acceleration while q2 brakes too (q3 = J3 + j23 * q2).
        self.c = fanuc_rate_matrix(profile.j23_factor)
        self.c_inv = np.linalg.inv(self.c)
        self.vel = np.radians(profile.vel_limit) * st.vel_fraction
        self.acc = np.radians(profile.acc_limit) * st.acc_fraction
        self._line_prev, self._line_goal_of = np.zeros(N), None
        brake = self.acc * st.brake_fraction
        brake[2] = min(brake[2], self.acc[2] - abs(profile.j23_factor) * brake[1])
        if brake[2] <= 0.0:
            brake[2] = 0.5 * self.acc[2] * st.brake_fraction
        self.brake_acc = brake
        margin = math.radians(st.joint_margin_deg)
        lo = np.radians(profile.joint_min_deg) + margin
        hi = np.radians(profile.joint_max_deg) - margin

        self.frame_task = mink.FrameTask(self.site, "site", position_cost=st.position_cost,
                                         orientation_cost=st.orientation_cost, gain=1.0)
        self.posture_task = mink.PostureTask(self.model, cost=st.posture_cost, gain=st.posture_gain)
        self.joint_task = mink.PostureTask(self.model, cost=1.0, gain=1.0)
        uncoupled = {n: np.array([self.vel[i]]) for i, n in enumerate(JOINT_NAMES)
                     if not (i == 2 and profile.j23_factor != 0.0)}
        self.accel_limit = AccelerationLimit(self.model, self.vel, self.acc, profile.j23_factor)
        self.path_braking = PathBraking(self.c, self.acc * st.brake_fraction)
        self.braking_limit = BrakingLimit(self.model, lo, hi, brake, self.path_braking)
        self.config_guard = ConfigurationGuard(self.model, self.kin, self.braking_limit, st.margins,
                                               path=self.path_braking)
        self.limits: list[mink.Limit] = [
            mink.ConfigurationLimit(self.model, gain=0.95),
            mink.VelocityLimit(self.model, uncoupled),
            self.accel_limit,
            self.braking_limit,
            self.config_guard,
        ]
        self.collision_limit: CollisionLimit | None = None
        if collision:
            pairs = collision_pairs if collision_pairs is not None else default_collision_pairs(self.model)
            self.collision_limit = CollisionLimit(self.model, pairs, path=self.path_braking)
            self.limits.append(self.collision_limit)
        self._correction_gain = 1.0 if st.correction_s is None else min(1.0, self.dt / st.correction_s)
        self._track_weights = np.array([st.position_cost] * 3 + [st.orientation_cost] * 3) ** 2  # frame task's
        self.follow_lag = (st.follow_lag_s if st.follow_lag_s is not None
                           else float(np.max(np.asarray(profile.acc_limit) / np.asarray(profile.jerk_limit))))
        for limit in (self.braking_limit, self.config_guard, self.collision_limit):
            if limit is not None:
                limit.lag_s = self.follow_lag
        self._row_flags: np.ndarray | None = None  # IkFlag per QP row, built on the first problem
        self._row_counts: list[int] = []
        self._accel_rows: slice | None = None
        self._braking_rows: slice | None = None
        self.qp: PersistentQP | None = None
        self._solver: SolverName = solver
        self._qp_settings = qp_settings
        if solver not in ("osqp", "daqp"):
            raise ValueError(f"solver={solver!r} must be 'osqp' or 'daqp'")

        self._dq_prev = np.zeros(N)
        self._started = False
        self._ref: np.ndarray | None = None  # integrated TCP reference pose (wxyz_xyz), Cartesian modes
        self._last_xi: np.ndarray | None = None  # last commanded twist: the line to brake along
        self._mode = ""
        # What the last step() started from, for step_again().
        self._before: tuple[np.ndarray, np.ndarray | None, np.ndarray | None, str] | None = None

    # ---------------------------------------------------------------------------------- public
    @property
    def reference_configuration(self) -> ArmConfiguration | None:
        return self.config_guard.reference

    @property
    def previous_increment(self) -> np.ndarray:
        return self._dq_prev.copy()

    def reset(self, q_model_rad: ArrayLike, dq_prev: ArrayLike | None = None) -> None:
        """Start streaming from ``q`` (at rest unless ``dq_prev`` is given): latches the configuration
        to keep and the posture to stay near."""
        q = self._checked(q_model_rad, "q_model_rad")
        self.configuration.update(self._full_q(q))
        self.config_guard.reset(q)
        self._mark_configuration_rows()
        self.posture_task.set_target(self._full_q(q))
        self._dq_prev = np.zeros(N) if dq_prev is None else self._checked(dq_prev, "dq_prev")
        self._ref = None
        self._last_xi = None
        self._mode = ""
        self._line_prev = np.zeros(N)
        self._started = True
        self._before = None
        if self.qp is not None:
            self.qp.reset()

    def step(self, q_model_rad: ArrayLike, command: Command | None, *, dq_prev: ArrayLike | None = None
             ) -> IkResult:
        """One cycle from the commanded joints ``q`` (model rad). ``command=None``: no live command,
        stop along the current motion. ``dq_prev`` overrides last cycle's increment (e.g. what the
        shaper actually delivered); by default the IK's own last output."""
        q = self._checked(q_model_rad, "q_model_rad")
        if not self._started:
            self.reset(q)
        # Everything step() changes (the rows and targets it sets are rebuilt by every step).
        self._before = (self._dq_prev, self._ref, self._last_xi, self._mode)
        if dq_prev is not None:
            self._dq_prev = self._checked(dq_prev, "dq_prev")
        st, dt = self.settings, self.dt
        cfg = self.configuration
        cfg.update(self._full_q(q))
        self.accel_limit.set_previous(self._dq_prev)
        kappa = self._condition(cfg.data)
        flags = IkFlag.NEAR_SINGULARITY if kappa > st.singularity_slow else IkFlag.NONE
        s_sing = 1.0
        xi: np.ndarray | None = None  # base-frame twist the frame task follows (Cartesian modes)
        arrived = False
        moving = bool(self._dq_prev.any())
        cartesian_stop = command is None and self._last_xi is not None and moving

        if isinstance(command, Twist | PoseTarget) or cartesian_stop:
            tcp = self._site_pose(cfg.data, self._site_id)
            if isinstance(command, Twist):
                mode, xi = "twist", self._twist_base(command, tcp)
            elif isinstance(command, PoseTarget):
                mode = "pose"
                xi, arrived = self._pose_twist(command, tcp)
            else:
                mode, xi = "stop", np.zeros(6)
                flags |= IkFlag.NO_COMMAND
            cartesian_mode = mode if mode != "stop" else self._mode
            if self._mode != cartesian_mode or self._ref is None or not self._near(self._ref, tcp):
                self._ref = tcp
            elif cartesian_mode == "twist" and self._last_xi is not None:
                self._ref = self._along_track(self._ref, tcp, self._last_xi)
            elif mode == "pose":
                assert isinstance(command, PoseTarget)
                self._ref = self._along_track_to(self._ref, tcp, _pose_of_matrix(xyzwpr_to_matrix(command.xyzwpr)))
            if xi.any():
                s_sing = self._singularity_factor(q, xi, kappa)
                if s_sing < 1.0:
                    flags |= IkFlag.SINGULARITY_SLOWDOWN
                xi = xi * s_sing
                s_goal = 1.0
                self._last_xi = xi
            elif self._last_xi is not None and moving:
                xi, s_goal = self._last_xi, 0.0  # brake along the last commanded Cartesian line
            else:
                s_goal, self._last_xi = 0.0, None
            target = mink.SE3(_advance(self._ref, xi * dt))
            self.frame_task.set_target(target)
            tasks: list[mink.Task] = [self.frame_task, self.posture_task]
            asks_motion = bool(xi.any())
            state_mode = cartesian_mode
        else:
            self._ref = None
            self._last_xi = None
            if isinstance(command, JointJog):
                mode, d_des = "joint_jog", self._jog_increment(command)
            elif isinstance(command, JointTarget):
                mode = "joint_target"
                d_des, arrived = self._target_increment(command, q)
            elif command is None:
                mode, d_des = "stop", np.zeros(N)
                flags |= IkFlag.NO_COMMAND
            else:
                raise TypeError(f"command={command!r} is not a motion command")
            self.joint_task.set_target(self._full_q(q + d_des))
            tasks = [self.joint_task]
            asks_motion = bool(d_des.any())
            s_goal = 1.0 if asks_motion else 0.0
            state_mode = mode
        if arrived:
            flags |= IkFlag.ARRIVED
        self._mode = state_mode  # a Cartesian stop keeps its mode: the reference pose stays valid

        # d: the increment the command asks for (P is positive definite). Part of d only pulls the TCP
        # back onto the integrated reference (drift, linearisation): d_corr, the optimum for the
        # reference itself. It is added unscaled so that scaling the command (even below 0 while
        # reversing) never turns the correction into a push away from the line.
        p, c, task_c = self._objective_terms(tasks)
        if xi is not None and asks_motion and self._ref is not None and not arrived:
            # Only the frame task's linear term depends on its target: swap that term alone.
            self.frame_task.set_target(mink.SE3(self._ref))
            c_ref = c - task_c[0] + self.frame_task.compute_qp_objective(cfg).c
            self.frame_task.set_target(target)
            d, d_corr = np.linalg.solve(p, -np.column_stack([c, c_ref])).T
            d = d - d_corr * (1.0 - self._correction_gain)  # the line, plus this cycle's share of the pull-back
            d_corr = d_corr * self._correction_gain
        else:
            d, d_corr = np.linalg.solve(p, -c), np.zeros(N)
        # Keep the direction: the commanded one (s -> 1), or while braking the current line (s -> 0).
        direction = d - d_corr if asks_motion else self._dq_prev
        self.path_braking.set_direction(direction)
        g, h = self.inequalities()
        h_path = self._path_rows(h)

        solver_status = ""
        dq: np.ndarray | None = None
        if state_mode == "pose" and asks_motion:
            if self._before[3] != "pose":
                self._line_prev = np.zeros(N)
            s_goal = min(s_goal, self._turn_cap(direction))
        s = _path_scale(direction, s_goal, g, h_path - g @ d_corr)
        if s is None and d_corr.any():
            d_corr = np.zeros(N)  # the correction does not fit this cycle: the line alone
            s = _path_scale(direction, s_goal, g, h_path)
        if s is None and xi is not None:  # a Cartesian line into a joint's braking distance
            s = self._line_past_braking(direction, s_goal, g, h, h_path)
            if s is not None:
                flags |= self._braking_flags(s * direction, g, h_path)
        if s is not None:  # 1. on the line
            dq = s * direction + d_corr
            if xi is not None and self._ref is not None and asks_motion:
                self._ref = _advance(self._ref, s * xi * dt)  # the reference follows what was achieved
            if s_goal == 0.0 and s == 0.0:
                self._last_xi = None  # at rest
        else:
            self._ref = None  # off the line for a while: re-latch the reference when back on it
            if asks_motion or moving:  # 2. straight blend in velocity space toward the limited command
                goal = d if s_goal == 1.0 else np.zeros(N)
                # Braking rows for the whole path first; if the state already needs more than they
                # allow (after a direction change), each joint's own braking rows.
                dq = self._blend(goal, g, h_path)
                if dq is None:
                    dq = self._blend(goal, g, h)
                if dq is not None:
                    flags |= IkFlag.PATH_BLEND
        if dq is None:  # 3. the QP's best tracking within every limit; 4. brake
            sol = self._qp_solve(p, c, g, h)
            solver_status = sol.status
            if not sol.ok:
                assert self._accel_rows is not None
                sol = self._qp_solve(p, c, g, _within_reach(g, h, self._accel_rows, self.c_inv,
                                                            self.settings.binding_tol))
                solver_status = f"{solver_status}; within reach: {sol.status}"
                assert self.qp is not None
                self.qp.reset()  # (a corner of other rows: no warm start for the next cycle's problem)
            if sol.ok:
                dq = sol.x
                flags |= IkFlag.QP_FALLBACK
            else:
                dq = self._decelerate(g, h)
                flags |= IkFlag.SOLVER_FAILED
        dd = float(d @ d)
        scale = min(max(float(dq @ d) / dd, 0.0), 1.0) * s_sing if s_goal == 1.0 and dd > 0.0 else 0.0
        flags |= self._binding_flags(g, h, dq)
        if not np.isfinite(dq).all():  # defensive: every branch above is finite by construction
            dq = np.zeros(N)
            flags |= IkFlag.SOLVER_FAILED
        self._dq_prev = dq.copy()
        return IkResult(dq=dq, q_next=q + dq, velocity=dq / dt, scale=float(scale), flags=flags,
                        condition=kappa, mode=mode, solver_status=solver_status)

    def step_again(self, q_model_rad: ArrayLike, command: Command | None, *, dq_prev: ArrayLike | None = None
                   ) -> IkResult:
        """The last cycle once more, from the state it started from, with another command: what
        :meth:`step` would have returned had ``command`` been given in the first place (the servo
        process uses it for an input that arrived while the cycle was being solved)."""
        if self._before is None:
            raise RuntimeError("step_again() needs a step() since the last reset()")
        self._dq_prev, self._ref, self._last_xi, self._mode = self._before
        return self.step(q_model_rad, command, dq_prev=dq_prev)

    def objective(self, tasks: list[mink.Task]) -> tuple[np.ndarray, np.ndarray]:
        """mink's QP objective (P, c) for ``tasks`` at the current configuration, with our damping."""
        p, c, _ = self._objective_terms(tasks)
        return p, c

    def _objective_terms(self, tasks: list[mink.Task]) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """(P, c) and each task's own linear term."""
        objs = [task.compute_qp_objective(self.configuration) for task in tasks]
        p = objs[0].H.copy()
        c = objs[0].c.copy()
        for obj in objs[1:]:
            p += obj.H
            c += obj.c
        p.flat[:: N + 1] += self.settings.damping
        return p, c, [obj.c for obj in objs]

    def inequalities(self) -> tuple[np.ndarray, np.ndarray]:
        """All limits stacked as ``G dq <= h`` (fixed row layout) at the current configuration."""
        cfg, dt = self.configuration, self.dt
        rows = [limit.compute_qp_inequalities(cfg, dt) for limit in self.limits]
        g = np.vstack([r.G for r in rows if r.G is not None])
        h = np.concatenate([r.h for r in rows if r.h is not None])
        self._ensure_rows(g.shape[0])
        return g, h

    def _blend(self, d: np.ndarray, g: np.ndarray, h: np.ndarray) -> np.ndarray | None:
        """From last cycle's increment straight toward ``sigma * d`` (``sigma``: the share of the
        command the position and velocity rows allow; 0 brakes), as far as all rows allow. A straight
        line in joint-velocity space is one in TCP-velocity space to first order: a ramp between the
        old and the new direction with no joint clipped on its own."""
        assert self._accel_rows is not None
        h_vel = h.copy()
        h_vel[self._accel_rows] = self.accel_limit.h_velocity
        sigma = _path_scale(d, 1.0, g, h_vel) if d.any() else None
        target = d * min(max(sigma, 0.0), 1.0) if sigma is not None else np.zeros(N)
        base = self._dq_prev
        interval = _scale_interval(target - base, g, h - g @ base)
        if interval is None:
            return None
        lo, hi = max(interval[0], 0.0), min(interval[1], 1.0)
        if lo > hi + 1e-9:  # rounding: a bound met exactly at t = 0 may read -1e-13
            return None
        return base + max(hi, lo) * (target - base)

    def _line_past_braking(self, direction: np.ndarray, s_goal: float, g: np.ndarray, h: np.ndarray,
                           h_path: np.ndarray) -> float | None:
        """The path braking rows ask for a harder brake than the acceleration rows allow: the ``s``
        nearest their interval within the other rows, each joint's own braking row widened by 20 ms
        of its acceleration."""
        rows = self._braking_rows
        h_other = h_path.copy()
        h_other[rows] = h[rows] + np.tile(self.acc * self.dt * 0.02, 2)  # (20 ms of each joint's acceleration)
        other = _scale_interval(direction, g, h_other)
        braking = _scale_interval(direction, g[rows], h_path[rows])
        if other is None or braking is None:
            return None
        return min(max(min(max(s_goal, braking[0]), braking[1]), other[0]), other[1])

    def _braking_flags(self, dq: np.ndarray, g: np.ndarray, h_path: np.ndarray) -> IkFlag:
        rows = self._braking_rows
        bind = g[rows] @ dq >= h_path[rows] - self.settings.binding_tol
        return IkFlag(int(np.bitwise_or.reduce(self._row_flags[rows][bind]))) if bind.any() else IkFlag.NONE

    def _path_rows(self, h: np.ndarray) -> np.ndarray:
        """``h`` with the braking rows of the limits that brake the whole path together."""
        out = h.copy()
        start = 0
        for limit, k in zip(self.limits, self._row_counts, strict=True):
            hp = getattr(limit, "h_path", None)
            if hp is not None:
                out[start:start + k] = hp
            start += k
        return out

    def to_fanuc_deg(self, q_model_rad: ArrayLike) -> np.ndarray:
        """Model joints (rad) -> FANUC joints (deg), for the shaper."""
        return model_rad_to_fanuc_deg(np.asarray(q_model_rad, dtype=float), self.profile.j23_factor)

    def velocity_fanuc_deg_s(self, velocity_model_rad_s: ArrayLike) -> np.ndarray:
        return np.degrees(self.c @ np.asarray(velocity_model_rad_s, dtype=float))

    def condition_number(self, q_model_rad: ArrayLike) -> float:
        """Condition number of the normalised flange Jacobian at ``q`` (the singularity measure)."""
        q = self._checked(q_model_rad, "q_model_rad")
        return self._condition_at(q)

    # -------------------------------------------------------------------------- desired motion
    def _twist_base(self, cmd: Twist, tcp: np.ndarray) -> np.ndarray:
        v = np.array(cmd.linear) / 1000.0
        w = np.radians(cmd.angular)
        xi = np.concatenate([v, w])
        if cmd.frame == "tool":
            for part in (xi[:3], xi[3:]):
                mujoco.mju_rotVecQuat(part, part.copy(), tcp[:4])
        return xi

    def _turn_cap(self, direction: np.ndarray) -> float:
        """The share of the line at which its turn in joint space (per unit of path, FANUC axes) needs
        no more than ``line_turn_fraction`` of the acceleration; inf with nothing to compare."""
        u, prev = self.c @ direction, self._line_prev
        self._line_prev = u
        nu, npv = float(np.linalg.norm(u)), float(np.linalg.norm(prev))
        if nu == 0.0 or npv == 0.0:
            return math.inf
        share = float(np.linalg.norm(self.c @ self._dq_prev)) / npv
        if share < 0.01:
            return math.inf
        turn = np.abs(u - prev * (nu / npv)) / share
        lim = self.acc * (self.settings.line_turn_fraction * self.dt * self.dt)
        caps = [math.sqrt(li / t) for li, t in zip(lim, turn, strict=True) if t > 0.0]
        return min(caps, default=math.inf)

    def _pose_twist(self, cmd: PoseTarget, tcp: np.ndarray) -> tuple[np.ndarray, bool]:
        """Straight-line P-control: one rate for translation and rotation (they arrive together),
        capped by the speed caps and by the speed from which the target can still be reached
        braking at the target accelerations."""
        st, dt = self.settings, self.dt
        goal = _pose_of_matrix(xyzwpr_to_matrix(cmd.xyzwpr))
        if cmd.xyzwpr != self._line_goal_of:
            self._line_goal_of, self._line_prev = cmd.xyzwpr, np.zeros(N)
        dp = goal[4:] - tcp[4:]
        dth = _rotation_between(goal, tcp)
        lin, ang = float(np.linalg.norm(dp)), float(np.linalg.norm(dth))
        if lin * 1000.0 < st.arrive_mm and math.degrees(ang) < st.arrive_deg:
            return np.zeros(6), True
        rate = st.pose_gain
        for dist, cap, acc in ((lin, cmd.linear_speed / 1000.0, st.target_linear_acc / 1000.0),
                               (ang, math.radians(cmd.angular_speed), math.radians(st.target_angular_acc))):
            if dist > 0.0:
                rate = min(rate, cap / dist, float(braking_speed(dist, acc, dt + self.follow_lag)) / dist)
        return rate * np.concatenate([dp, dth]), False

    def _jog_increment(self, cmd: JointJog) -> np.ndarray:
        return self.c_inv @ np.radians(cmd.velocity) * self.dt

    def _target_increment(self, cmd: JointTarget, q: np.ndarray) -> tuple[np.ndarray, bool]:
        """Straight joint-space line (FANUC axes, all joints arriving together) at the speed scale,
        braking so that it arrives without overshoot."""
        goal = fanuc_deg_to_model_rad(cmd.position, self.profile.j23_factor)
        err_f = self.c @ (goal - q)
        dist = np.abs(err_f)
        if float(np.max(np.degrees(dist))) < self.settings.arrive_deg * 0.1:
            return np.zeros(N), True
        rate = self.settings.pose_gain
        moving = dist > 0.0
        vmax = self.vel[moving] * cmd.speed_scale
        vbrake = braking_speed(dist[moving], self.brake_acc[moving], self.dt + self.follow_lag)
        rate = min(rate, float(np.min(np.minimum(vmax, vbrake) / dist[moving])))
        return self.c_inv @ (rate * err_f) * self.dt, False

    # ---------------------------------------------------------------------------- singularity
    def _condition(self, data: mujoco.MjData) -> float:
        jac = np.empty((6, N))
        mujoco.mj_jacSite(self.model, data, jac[:3], jac[3:], self._flange_id)
        jac[:3] /= self._reach
        sv = np.linalg.svd(jac, compute_uv=False)
        return float(sv[0] / sv[-1]) if sv[-1] > 1e-12 * sv[0] else 1e12

    def _condition_at(self, q: np.ndarray) -> float:
        self._probe.qpos[:] = self._full_q(q)
        mujoco.mj_kinematics(self.model, self._probe)
        mujoco.mj_comPos(self.model, self._probe)
        return self._condition(self._probe)

    def _singularity_factor(self, q: np.ndarray, xi: np.ndarray, kappa: float) -> float:
        """1 away from singularities or when the command leaves them; slows an approach smoothly
        to 0 between the two thresholds."""
        st = self.settings
        if kappa <= st.singularity_slow or not xi.any():
            return 1.0
        # Joint direction of the command: damped least squares on the TCP Jacobian (world frame).
        jac = np.empty((6, N))
        mujoco.mj_jacSite(self.model, self.configuration.data, jac[:3], jac[3:], self._site_id)
        jac[:3] /= self._reach
        xn = xi.copy()
        xn[:3] /= self._reach
        lam2 = 1e-4
        dq = jac.T @ np.linalg.solve(jac @ jac.T + lam2 * np.eye(6), xn)
        norm = float(np.linalg.norm(dq))
        if norm == 0.0:
            return 1.0
        eps = 1e-3  # rad along the command
        k1 = self._condition_at(q + dq * (eps / norm))
        approach = min(max((k1 - kappa) / (kappa * eps * st.singularity_rate), 0.0), 1.0)
        x = min(max((kappa - st.singularity_slow) / (st.singularity_stop - st.singularity_slow), 0.0), 1.0)
        weight = x * x * (3.0 - 2.0 * x)  # smoothstep: no kink at either threshold
        return 1.0 - weight * approach

    # -------------------------------------------------------------------------------- helpers
    def _qp_solve(self, p: np.ndarray, c: np.ndarray, g: np.ndarray, h: np.ndarray):
        if self.qp is None:
            self.qp = PersistentQP(N, g.shape[0], self._solver, var_scale=self.dt, settings=self._qp_settings)
        return self.qp.solve(p, c, g, h)

    def _decelerate(self, g: np.ndarray, h: np.ndarray) -> np.ndarray:
        """Last resort: the whole motion brakes with one factor, as fast as the joint that needs the
        longest may (FANUC axes), so it stops when that joint would on its own and the joints keep their
        proportion: the TCP's twist shrinks along itself. Each joint at its own limit instead (the path
        bends) only where that keeps a row ``G dq <= h`` the common factor would break.

        Why: braked joint by joint, motions that cancel at the TCP fell out of step. A pose target past
        J1's axis (J1 and J6 counter-rotating at 230 deg/s, J1 braking for its range) stopped J6 (5000
        deg/s^2) twice as fast as J1 (2250): the TCP turned at 49 deg/s for 5."""
        p = self.c @ self._dq_prev
        da = self.acc * self.dt * self.dt
        own = self.c_inv @ (np.sign(p) * np.maximum(np.abs(p) - da, 0.0))
        cycles = float(np.max(np.abs(p) / da))  # to a stop, for the joint that needs the longest
        together = self._dq_prev * max(0.0, 1.0 - 1.0 / cycles) if cycles > 1.0 else np.zeros(N)
        tol = self.settings.binding_tol
        return together if bool(np.all((g @ together <= h + tol) | (g @ own > h + tol))) else own

    def _ensure_rows(self, m: int) -> None:
        """Map each QP row to the flag it raises when binding (the limits' row counts are fixed)."""
        if self._row_flags is not None and len(self._row_flags) == m:
            return
        cfg = self.configuration
        flags: list[int] = []
        self._row_counts = []
        for limit in self.limits:
            rows = limit.compute_qp_inequalities(cfg, self.dt)
            k = 0 if rows.G is None else rows.G.shape[0]
            self._row_counts.append(k)
            if limit is self.accel_limit:
                self._accel_rows = slice(len(flags), len(flags) + k)
                flag = IkFlag.ACCEL_LIMIT
            elif isinstance(limit, mink.VelocityLimit):
                flag = IkFlag.VELOCITY_LIMIT
            elif limit is self.braking_limit:  # joint ranges, or the configuration's joint intervals
                self._braking_rows = slice(len(flags), len(flags) + k)
                flag = IkFlag.JOINT_LIMIT
            elif isinstance(limit, mink.ConfigurationLimit):
                flag = IkFlag.JOINT_LIMIT
            elif limit is self.config_guard:
                flag = IkFlag.CONFIGURATION
            else:
                flag = IkFlag.COLLISION
            flags.extend([int(flag)] * k)
        if len(flags) != m:
            raise RuntimeError(f"limit rows changed size ({len(flags)} != {m}); a persistent QP needs fixed rows")
        self._row_flags = np.array(flags)
        self._mark_configuration_rows()
        self.qp = None

    def _mark_configuration_rows(self) -> None:
        """Braking rows whose bound is a configuration interval raise CONFIGURATION, not JOINT_LIMIT."""
        if self._row_flags is not None and self._braking_rows is not None:
            self._row_flags[self._braking_rows] = np.where(self.braking_limit.restricted, int(IkFlag.CONFIGURATION),
                                                           int(IkFlag.JOINT_LIMIT))

    def _binding_flags(self, g: np.ndarray, h: np.ndarray, dq: np.ndarray) -> IkFlag:
        assert self._row_flags is not None
        slack = h - g @ dq
        tol = self.settings.binding_tol + 1e-6 * np.abs(h)
        binding = np.isfinite(h) & (slack <= tol)
        out = IkFlag(int(np.bitwise_or.reduce(self._row_flags[binding]))) if binding.any() else IkFlag.NONE
        if self._accel_rows is not None:
            vel_rows = self.accel_limit.velocity_bound & binding[self._accel_rows]
            if vel_rows.any():
                out |= IkFlag.VELOCITY_LIMIT
            if not (binding[self._accel_rows] & ~self.accel_limit.velocity_bound).any():
                out &= ~IkFlag.ACCEL_LIMIT
        return out

    def _site_pose(self, data: mujoco.MjData, site_id: int) -> np.ndarray:
        """The site's pose as mink stores an SE3: quaternion (w x y z), then position."""
        pose = np.empty(7)
        mujoco.mju_mat2Quat(pose[:4], data.site_xmat[site_id])
        pose[4:] = data.site_xpos[site_id]
        return pose

    def _along_track(self, ref: np.ndarray, tcp: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """The reference moved along the line ``xi`` to where the TCP actually is along it.

        The reference advances by what each cycle asked for; the jerk-limited shaper delivers it a
        little later. Pulling the TCP forward to the reference then overshot the commanded speed
        (+20 %) and swung back: only the error across the line is the IK's to correct."""
        w = self._track_weights
        err = np.concatenate([tcp[4:] - ref[4:], _rotation_between(tcp, ref)])
        norm = float(xi @ (w * xi))
        if norm <= 0.0:
            return ref
        return _advance(ref, (float(err @ (w * xi)) / norm) * xi)

    @staticmethod
    def _along_track_to(ref: np.ndarray, tcp: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """A pose target's :meth:`_along_track`: the reference moved on its line to ``goal`` to where
        the TCP is along it, translation and rotation each on their own (the fast implementation's
        ``along_track_to``, added since that commit)."""
        step = np.concatenate([goal[4:] - ref[4:], _rotation_between(goal, ref)])
        err = np.concatenate([tcp[4:] - ref[4:], _rotation_between(tcp, ref)])
        norms = [float(step[p] @ step[p]) for p in (slice(0, 3), slice(3, 6))]
        if max(norms) <= 0.0:
            return ref
        for p, norm in zip((slice(0, 3), slice(3, 6)), norms, strict=True):
            step[p] *= float(err[p] @ step[p]) / norm if norm > 0.0 else 0.0
        return _advance(ref, step)

    def _near(self, a: np.ndarray, b: np.ndarray) -> bool:
        tol = self.settings.reference_tolerance_m
        if float(np.linalg.norm(a[4:] - b[4:])) > tol:
            return False
        return float(np.linalg.norm(_rotation_between(a, b))) * self._reach <= tol

    def _full_q(self, q: np.ndarray) -> np.ndarray:
        full = self.configuration.data.qpos.copy()
        full[self._qadr] = q
        return full

    @staticmethod
    def _checked(v: ArrayLike, name: str) -> np.ndarray:
        a = np.asarray(v, dtype=float)
        if a.shape != (N,):
            raise ValueError(f"{name} has shape {a.shape}, expected ({N},)")
        if not np.isfinite(a).all():
            i = int(np.flatnonzero(~np.isfinite(a))[0])
            raise ValueError(f"{name}[{i}]={a[i]} is not a finite number")
        return a.copy()


# ------------------------------------------------------------------------------ pure functions
def _scale_interval(direction: np.ndarray, g: np.ndarray, h: np.ndarray) -> tuple[float, float] | None:
    """The interval of ``s`` with ``g @ (s * direction) <= h`` (the rows are linear), or None."""
    a = g @ direction
    tiny = 1e-15
    pos, neg, zero = a > tiny, a < -tiny, np.abs(a) <= tiny
    if (h[zero] < -1e-12).any():
        return None
    s_hi = float(np.min(h[pos] / a[pos])) if pos.any() else math.inf
    s_lo = float(np.max(h[neg] / a[neg])) if neg.any() else -math.inf
    return (s_lo, s_hi) if s_lo <= s_hi else None


def _path_scale(direction: np.ndarray, s_goal: float, g: np.ndarray, h: np.ndarray) -> float | None:
    """The ``s`` nearest ``s_goal`` with ``g @ (s * direction) <= h``, or None if there is none."""
    interval = _scale_interval(direction, g, h)
    if interval is None:
        return None
    s = min(max(s_goal, interval[0]), interval[1])
    return s if math.isfinite(s) else None


# Poses are 7-vectors as mink's SE3 stores them: unit quaternion (w x y z), then position (m).
def _pose_of_matrix(t: np.ndarray) -> np.ndarray:
    pose = np.empty(7)
    mujoco.mju_mat2Quat(pose[:4], np.ascontiguousarray(t[:3, :3]).reshape(9))
    pose[4:] = t[:3, 3]
    return pose


def _advance(pose: np.ndarray, xi_dt: np.ndarray) -> np.ndarray:
    """Pose moved by a base-frame displacement (translation of the TCP, rotation about the TCP)."""
    turn = np.array([1.0, 0.0, 0.0, 0.0])
    mujoco.mju_quatIntegrate(turn, xi_dt[3:], 1.0)  # exp of the rotation vector
    out = np.empty(7)
    mujoco.mju_mulQuat(out[:4], turn, pose[:4])  # base frame: applied on the left
    out[4:] = pose[4:] + xi_dt[:3]
    return out


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Base-frame rotation vector taking pose ``b``'s orientation to ``a``'s (the shorter way)."""
    b_inv = np.empty(4)
    mujoco.mju_negQuat(b_inv, b[:4])
    diff = np.empty(4)
    mujoco.mju_mulQuat(diff, a[:4], b_inv)
    w = np.empty(3)
    mujoco.mju_quat2Vel(w, diff, 1.0)
    return w
