"""Differential IK of the servo cycle: the live command -> this cycle's joint increment request.

One ``DifferentialIK.step`` per interval (8 or 4 ms), pure (no I/O, no clock). Joints are in the
model convention, radians; the jerk-limited shaper downstream turns the request into the positions
actually sent, so the request must already be deliverable:

1. **Desired motion** from the command: a TCP twist (base or tool frame, rotating about the TCP), a
   pose target (P-control clipped by its speed caps and a braking profile: no overshoot), a joint jog
   or a joint target (straight joint-space line, synchronised, braking profile). No command: stop.
2. **mink problem**: a ``FrameTask`` on the TCP site (target = reference pose advanced by the twist;
   the reference integrates what was achieved, so a held twist of zero never drifts, and slides along
   the line to where the TCP is, so the pull-back only corrects across it), a low-weight
   ``PostureTask`` toward the start posture, damping; limits ``ConfigurationLimit``,
   ``VelocityLimit`` and ours (:mod:`servo_app.motion.ik_limits`): joint rates in the FANUC
   convention with an acceleration bound, braking distance to every joint bound, the arm
   configuration, optionally collisions. mink's QP (fixed row layout), but assembled here each
   cycle straight from MuJoCo into arrays allocated once (the same numbers the tasks'
   ``compute_qp_objective`` and the limits' ``compute_qp_inequalities`` give; those stay for
   comparisons and ``mink.solve_ik``): building the objects was most of the cycle's cost.
3. **On the line**: ``d`` = the unconstrained optimum of that objective (the increment the command
   asks for). All limits are linear in the increment, so the scalars ``s`` with ``G (s d) <= h``
   form an interval: we take the ``s`` nearest 1 in it and send ``s d``. The WHOLE increment is
   scaled, so the TCP keeps its direction (no joint is clipped alone). Acceleration rows make this a
   ramp along the path; a reversal decelerates along the same line (``s < 0``); no command brakes
   along the last line (``s -> 0``). Braking rows here brake the whole path together
   (:class:`~servo_app.motion.ik_limits.PathBraking`), so a stop before a bound stays on the line;
   a Cartesian line whose braking rows outrun its acceleration (the shaper's late deceleration)
   brakes as hard as it may and starts each joint's own stop up to 20 ms late, rather than leave
   the line (``_line_past_braking``).
4. **Blend** (a commanded change of direction the acceleration limit cannot follow at once): a
   straight line in joint-velocity space from last cycle's increment toward the command scaled to
   the position and velocity limits, as far as every row allows: first order a ramp between the two
   TCP velocities, again without clipping joints one by one. Flagged ``PATH_BLEND``.
5. **QP** (persistent OSQP or DAQP, :mod:`servo_app.motion.qp`) when neither fits: the best tracking
   within every limit (each joint braking on its own), flagged ``QP_FALLBACK``; if a joint is already
   past its own braking curve (the line's late braking), its row raised to the hardest brake the
   acceleration allows (``_within_reach``). If the solver fails even so:
   the whole motion brakes with one factor at the acceleration limit of the joint that needs the
   longest, the joints in proportion (each joint on its own only where that keeps a row the common
   factor would break), flagged ``SOLVER_FAILED``. Never NaN.

Singularities: the condition number of the flange Jacobian (linear rows divided by the arm's reach,
so both halves are comparable) is probed one small step along the commanded direction. Between
``singularity_slow`` and ``singularity_stop`` a command that *increases* it is slowed smoothly (to
zero at ``singularity_stop``); a command that decreases it, or keeps it, runs at full speed, so the
arm never freezes in a singular pose (a known failure of halting servo stacks).
"""

from __future__ import annotations

import enum
import itertools
import math
import types
from dataclasses import dataclass, field
from typing import NamedTuple

import mink
import mujoco
import numpy as np

from servo_app.motion import ik_kernels as kernels
from servo_app.motion.commands import Command, JointJog, JointTarget, PoseTarget, Twist
from servo_app.motion.ik_limits import (
    AccelerationLimit,
    BrakingLimit,
    CollisionLimit,
    ConfigurationGuard,
    ConfigurationMargins,
    PathBraking,
    braking_speed,
    braking_speed_scalar,
    default_collision_pairs,
    fanuc_rate_matrix,
    jacobian_tree,
)
from servo_app.motion.mujoco_c import address_table
from servo_app.motion.qp import PersistentQP, QpSettings, SolverName
from servo_app.robots.configuration import ArmConfiguration
from servo_app.robots.conventions import ArrayLike, fanuc_deg_to_model_rad, model_rad_to_fanuc_deg, xyzwpr_to_matrix
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.model import FLANGE_SITE, JOINT_NAMES, TCP_SITE, load_model, set_model_tool
from servo_app.robots.profile import RobotProfile

N = 6


def _solve(p: np.ndarray, rhs: np.ndarray) -> None:
    """``rhs <- p^-1 rhs`` in place (columns) for the positive definite objective Hessian ``p``."""
    if not kernels.cholesky_solve(p, rhs):
        raise np.linalg.LinAlgError("the IK objective's Hessian is not positive definite")


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


# The flags as plain ints for the cycle: IntFlag's operators run Python code (several us each here).
_B = types.SimpleNamespace(**{f.name: int(f) for f in IkFlag if f.name})
_VELOCITY_LIMIT_BIT, _ACCEL_LIMIT_BIT = int(IkFlag.VELOCITY_LIMIT), int(IkFlag.ACCEL_LIMIT)

# How late a Cartesian line braking for a joint bound may start each joint's own stop (DifferentialIK.
# _line_past_braking): 20 ms of the ~0.15 s the braking rows allow for the shaper's lag.
LINE_BRAKE_LATE_S = 0.02

_ZERO3 = (0.0, 0.0, 0.0)  # cartesian_step's twist when there is none

_FLAG_OF: dict[int, IkFlag] = {}  # IkFlag(bits) by bits: the enum's constructor costs microseconds


def _ik_flag(bits: int) -> IkFlag:
    flag = _FLAG_OF.get(bits)
    if flag is None:
        flag = _FLAG_OF[bits] = IkFlag(bits)
    return flag


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
    # The share of the acceleration a pose target's line may take for its turn in joint space (the rest:
    # the pull-back and the shaper's jerk-limited lag); 0.3 still ran a 1.5 m tool at 2.3 x its speed.
    line_turn_fraction: float = 0.1
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


class IkResult(NamedTuple):
    """One step's result, immutable. A named tuple rather than a frozen dataclass: made every cycle, and
    a frozen dataclass sets each of its eight fields through ``object.__setattr__`` (~3 us a result
    here in a loop, ~1 as a tuple)."""

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
        # A pose target's line direction last cycle (FANUC axes; zeros: none) and the buffer for this one's.
        self._line_prev, self._line_spare = np.zeros(N), np.zeros(N)
        self._turn_lim = self.acc * (st.line_turn_fraction * dt * dt)
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
        self.frame_target: np.ndarray | None = None  # the last Cartesian cycle's frame target (wxyz_xyz)
        self._layout()
        # What the last step() started from, for step_again().
        self._before: tuple[np.ndarray, np.ndarray | None, np.ndarray | None, str, np.ndarray] | None = None

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
        self._line_prev[:] = 0.0
        self._started = True
        self._before = None
        if self.qp is not None:
            self.qp.reset()

    def set_tool(self, tool_xyzwpr: ArrayLike | None) -> None:
        """Another tool (TCP offset from the flange, FANUC units; None: the flange). Call it at rest
        (the caller's to ensure: :meth:`ServoCycle.set_tool` refuses otherwise): it starts from rest.

        The ``tcp`` site moves in the compiled model (``site_pos``/``site_quat``: the same numbers a
        model compiled with that tool has) and the analytic kinematics take the new tool matrix, so
        the frame task, tool-frame twists (rotation about the TCP, the TCP's axes), pose targets and
        their finish follow at the next step, with nothing rebuilt (the QP layout, the limits and
        the persistent solver stay). The Cartesian reference is dropped: it was a pose of the old TCP."""
        if self.site != TCP_SITE:
            raise ValueError(f"this IK's model has no {TCP_SITE!r} site: its tool is the flange")
        set_model_tool(self.model, tool_xyzwpr)
        self.kin.set_tool(tool_xyzwpr)
        self._dq_prev = np.zeros(N)
        self._ref = None
        self._last_xi = None
        self._mode = ""
        self.frame_target = None
        self._before = None

    def step(self, q_model_rad: ArrayLike, command: Command | None, *, dq_prev: ArrayLike | None = None
             ) -> IkResult:
        """One cycle from the commanded joints ``q`` (model rad). ``command=None``: no live command,
        stop along the current motion. ``dq_prev`` overrides last cycle's increment (e.g. what the
        shaper actually delivered); by default the IK's own last output."""
        q = self._checked(q_model_rad, "q_model_rad")
        return self.step_owned(q, command, None if dq_prev is None else self._checked(dq_prev, "dq_prev"))

    def step_owned(self, q: np.ndarray, command: Command | None, dq_prev: np.ndarray | None = None) -> IkResult:
        """:meth:`step` for arrays the caller made for this call and hands over (the servo cycle's
        start, converted from the shaper's state by a kernel): float64, shape (6,), finite, never
        changed afterwards by the caller. They are neither copied nor checked again (the IK may keep
        them: ``step_again`` starts from them)."""
        if not self._started:
            self.reset(q)
        # Everything step() changes (the rows and targets it sets are rebuilt by every step).
        self._before = (self._dq_prev, self._ref, self._last_xi, self._mode, self._line_prev)
        if dq_prev is not None:
            self._dq_prev = dq_prev
        # (set_previous without its copy: the IK's dq_prev is never changed in place, only replaced)
        self.accel_limit.dq_prev = self._dq_prev
        is_twist = isinstance(command, Twist)  # (the jog's command: one check, not a union's)
        if is_twist or (command is None and self._last_xi is not None):
            # The common Cartesian step (a twist, or braking along its line) in one kernel; the rest
            # (singularity slow-down, blend, QP) is the code below, from the same state.
            done = self._cartesian_step(q, command)
            if done is not None:
                return done
        st, dt = self.settings, self.dt
        data = self.configuration.data
        self._kinematics(q)
        kappa = self._condition(data)
        flags = _B.NEAR_SINGULARITY if kappa > st.singularity_slow else 0  # int bits: IntFlag | costs us
        s_sing = 1.0
        xi: np.ndarray | None = None  # base-frame twist the frame task follows (Cartesian modes)
        arrived = False
        moving = kernels.any_nonzero(self._dq_prev)
        cartesian_stop = command is None and self._last_xi is not None and moving
        target: np.ndarray | None = None  # the frame task's target pose (Cartesian modes)
        joint_goal = q  # the joint task's target (joint modes)

        if is_twist or isinstance(command, PoseTarget) or cartesian_stop:
            tcp = self._tcp_pose()
            if is_twist:
                mode = "twist"
                xi, xi_moves = self._twist_base(command, tcp)  # type: ignore[arg-type]
            elif isinstance(command, PoseTarget):
                mode = "pose"
                xi, arrived = self._pose_twist(command, tcp)
                xi_moves = kernels.any_nonzero(xi)
            else:
                mode, xi, xi_moves = "stop", np.zeros(6), False
                flags |= _B.NO_COMMAND
            cartesian_mode = mode if mode != "stop" else self._mode
            if (self._mode != cartesian_mode or self._ref is None
                    or not kernels.poses_near(self._ref, tcp, st.reference_tolerance_m, self._reach)):
                self._ref = tcp
            elif cartesian_mode == "twist" and self._last_xi is not None:
                self._ref = self._along_track(self._ref, tcp, self._last_xi)
            elif mode == "pose":
                # As for a twist: the reference integrated what was asked, the shaper delivered it
                # later, and pulling the TCP up to it ran a 40 mm/s target at 64 mm/s. It slides on
                # its line to the goal (translation and rotation each on their own, so neither pushes
                # the other's speed), and the pull-back never turns the TCP away from the goal.
                ref = np.empty(7)
                if kernels.along_track_to(ref, self._ref, tcp, self._pose_goal):
                    self._ref = ref
            if xi_moves:
                asks_motion = True
                if kappa > st.singularity_slow:  # (below, the factor is 1)
                    s_sing = self._singularity_factor(q, xi, kappa)
                if s_sing < 1.0:  # (xi is this step's own array: scaled only when slowed, x * 1.0 being x)
                    flags |= _B.SINGULARITY_SLOWDOWN
                    xi = xi * s_sing
                    asks_motion = kernels.any_nonzero(xi)
                s_goal = 1.0
                self._last_xi = xi
            elif self._last_xi is not None and moving:
                xi, s_goal = self._last_xi, 0.0  # brake along the last commanded Cartesian line
                asks_motion = kernels.any_nonzero(xi)
            else:
                s_goal, self._last_xi = 0.0, None
                asks_motion = False  # (xi is zero)
            target = _advance(self._ref, xi, 1.0, dt)
            self.frame_target = target
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
                flags |= _B.NO_COMMAND
            else:
                raise TypeError(f"command={command!r} is not a motion command")
            joint_goal = q + d_des
            asks_motion = kernels.any_nonzero(d_des)
            s_goal = 1.0 if asks_motion else 0.0
            state_mode = mode
        if arrived:
            flags |= _B.ARRIVED
        self._mode = state_mode  # a Cartesian stop keeps its mode: the reference pose stays valid

        # d: the increment the command asks for (P is positive definite). Part of d only pulls the TCP
        # back onto the integrated reference (drift, linearisation): d_corr, the optimum for the
        # reference itself. It is added unscaled so that scaling the command (even below 0 while
        # reversing) never turns the correction into a push away from the line.
        if target is not None:
            # With a reference: the optimum toward it too (only the frame task's linear term depends
            # on its target); d = the line plus this cycle's share of the pull-back d_corr.
            # (Arrived: nothing is left to pull back. The pull-back's posture share alone, no longer
            # held by a reference ahead of the TCP, moved it 0.07 um off the goal as it stopped.)
            with_ref = xi is not None and asks_motion and self._ref is not None and not arrived
            p, c = self._cartesian_objective(target, self._ref if with_ref else None)
            d, d_corr = self._d  # views of the optimum: read (never written) until the next objective
        else:
            p, c = self._joint_objective(q, joint_goal)
            rhs = self._rhs
            rhs[:, 0] = -c
            rhs[:, 1] = 0.0
            _solve(p, rhs)
            d, d_corr = rhs[:, 0].copy(), np.zeros(N)
        # Keep the direction: the commanded one (s -> 1), or while braking the current line (s -> 0).
        direction = d - d_corr if asks_motion else self._dq_prev
        self.path_braking.set_direction(direction)
        g, h, h_path = self._rows()

        solver_status = ""
        dq: np.ndarray | None = None
        if state_mode == "pose" and asks_motion:
            # Not faster than the line's turn in joint space lets the arm follow it (kernels.turn_cap).
            prev, out = self._line_prev, self._line_spare
            if self._before[3] != "pose":
                prev[:] = 0.0  # (nothing to compare with)
            s_goal = min(s_goal, kernels.turn_cap(prev, direction, self.c, self._dq_prev, self._turn_lim, out))
            self._line_prev, self._line_spare = out, prev  # (swapped, not copied: undo_step restores prev)
        s = _path_scale(direction, s_goal, g, h_path, d_corr)
        if s is None and kernels.any_nonzero(d_corr):
            d_corr = np.zeros(N)  # the correction does not fit this cycle: the line alone
            s = _path_scale(direction, s_goal, g, h_path)
        if s is None and xi is not None:  # (a Cartesian line into a joint's braking distance)
            s = self._line_past_braking(direction, s_goal, g, h, h_path)
            if s is not None:
                flags |= self._braking_flags(s * direction, g, h_path)
        if s is not None:  # 1. on the line
            dq = np.empty(N)
            kernels.line_point(s, direction, d_corr, dq)  # s * direction + d_corr
            if xi is not None and self._ref is not None and asks_motion:
                self._ref = _advance(self._ref, xi, s, dt)  # the reference follows what was achieved
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
                    flags |= _B.PATH_BLEND
        if dq is None:  # 3. the QP's best tracking within every limit; 4. brake
            sol = self._qp_solve(p, c, g, h)
            solver_status = sol.status
            if not sol.ok:  # a row already out of the acceleration's reach: as near it as the arm can
                assert self._accel_rows is not None
                sol = self._qp_solve(p, c, g, _within_reach(g, h, self._accel_rows, self.c_inv,
                                                            st.binding_tol))
                solver_status = f"{solver_status}; within reach: {sol.status}"
                assert self.qp is not None
                self.qp.reset()  # (a corner of other rows: no warm start for the next cycle's problem)
            if sol.ok:
                dq = sol.x
                flags |= _B.QP_FALLBACK
            else:
                dq = self._decelerate(g, h)
                flags |= _B.SOLVER_FAILED
        # In one kernel call: the share of the command delivered, the flags of the rows dq binds (within
        # binding_tol + 1e-6 |h|; inactive rows, h = inf, never bind; an acceleration row whose bound is
        # the velocity one raises VELOCITY_LIMIT, and ACCEL_LIMIT stays only if a row bound by
        # acceleration binds), and the rows of out: the copy of dq kept as the next cycle's start,
        # q + dq, dq / dt.
        out = np.empty((3, N))
        scale, bits, finite = kernels.step_result(
            dq, d, s_goal, s_sing, q, dt, g, h, self._row_flags, self._accel_lo, self._accel_hi,
            self.accel_limit.velocity_bound, st.binding_tol, _VELOCITY_LIMIT_BIT, _ACCEL_LIMIT_BIT, out)
        flags |= bits
        if not finite:  # defensive: every branch above is finite by construction
            dq = np.zeros(N)
            flags |= _B.SOLVER_FAILED
            kernels.step_outputs(dq, q, dt, out)
        self._dq_prev, q_next, velocity = out
        return IkResult(dq=dq, q_next=q_next, velocity=velocity, scale=scale, flags=_ik_flag(flags),
                        condition=kappa, mode=mode, solver_status=solver_status)

    def _cartesian_step(self, q: np.ndarray, command: Twist | None) -> IkResult | None:
        """:meth:`step_owned` for a twist (``command``) or a stop braking along the last Cartesian line
        (``None``) in one kernel call (:func:`~servo_app.motion.ik_kernels.cartesian_step`: the same
        operations as the code of step_owned, MuJoCo's through its C functions, so the same bits).
        None when the step is not the kernel's (a collision limit with cached pairs, not yet set up;
        a stop off any line; the singularity slow-down; off the line: blend or QP): nothing the IK
        keeps has changed then, and step_owned's code does the step.

        Why: the step as Python around ~20 kernel and MuJoCo calls cost ~190-230 us per status when
        the caches are cold (8 ms between steps, bench/servo_loop.py's IK ahead); in one call ~100-110
        (62 -> 18 us in a tight loop)."""
        table = self._row_table()
        if table is None:
            return None
        reference = self.config_guard.reference
        assert reference is not None
        posture_goal = self._posture_goal_now()
        ref, last_xi = self._ref, self._last_xi
        state = kernels.STATE_TOP if reference.top else 0
        if ref is not None:
            state |= kernels.STATE_HAS_REF
        else:
            ref = self._no_pose
        if last_xi is not None:
            state |= kernels.STATE_HAS_LAST_XI
        else:
            last_xi = self._zero
        if command is not None:
            kind = kernels.TWIST_TOOL if command.frame == "tool" else kernels.TWIST_BASE
            linear, angular = command.linear, command.angular
            state |= kernels.STATE_TWIST_MODE if self._mode == "twist" else (kernels.STATE_TWIST_MODE
                                                                             | kernels.STATE_MODE_CHANGED)
        else:
            kind, linear, angular = kernels.CARTESIAN_STOP, _ZERO3, _ZERO3
            if self._mode == "twist":
                state |= kernels.STATE_TWIST_MODE
        # Each output its own array (kept: the result's, the next reference, the next start), made by
        # np.empty rather than as the rows of one array taken apart: one kind of numpy call, cheaper
        # with caches cold after the wait for the status than the views an unpacking makes.
        new_ref, target, xi = np.empty(7), np.empty(7), np.empty(6)
        dq, dq_next, q_next, velocity = np.empty(N), np.empty(N), np.empty(N), np.empty(N)
        status, bits, kappa, scale, rate = kernels.cartesian_step(
            kind, linear, angular, q, self._dq_prev, ref, last_xi, posture_goal, self.braking_limit.bounds,
            state, table, new_ref, target, xi, dq, dq_next, q_next, velocity)
        if status < 0:  # (the kernel's scratch, rows and path direction are all set again by that code)
            return None
        path = self.path_braking
        if math.isinf(rate):  # PathBraking.set_direction's outcome, its direction copied by the kernel
            path.u, path.rate = None, math.inf
        else:
            path.u, path.rate = path.direction_buffer, rate
        self._ref, self.frame_target = new_ref, target
        code = status & 3
        if code == kernels.LAST_XI_NEW:
            self._last_xi = xi
        elif code == kernels.LAST_XI_CLEARED:
            self._last_xi = None
        if command is not None:
            mode = self._mode = "twist"
        else:
            mode = "stop"  # (a Cartesian stop keeps its mode: the reference pose stays valid)
        self._dq_prev = dq_next
        if not status & kernels.STEP_FINITE:  # defensive: the line's increment is finite by construction
            dq = np.zeros(N)
            bits |= _B.SOLVER_FAILED
            kernels.step_outputs_into(dq, q, self.dt, dq_next, q_next, velocity)
        return IkResult(dq=dq, q_next=q_next, velocity=velocity, scale=scale, flags=_ik_flag(bits),
                        condition=kappa, mode=mode, solver_status="")

    def _cartesian_step_table(self) -> np.ndarray | None:
        """:func:`~servo_app.motion.ik_kernels.cartesian_step`'s table of the arrays that stay
        (``CARTESIAN_ARRAYS``: constants, the MjData's arrays, scratch, the row arrays; they are kept
        in ``self._fast_arrays`` as long as the table), made once. Empty when the collision limit keeps
        a cache (pairs the screen cannot decide: their narrow phases are Python's), None while its first
        fill has not set it up."""
        col = self.collision_limit
        if col is not None and col.cached_pairs:
            return np.zeros((0, 3), dtype=np.int64)
        if col is not None and col._q_refresh is None:
            return None
        st, view, model = self.settings, self._view, self.model
        data = self.configuration.data
        accel, brk, guard, path = self.accel_limit, self.braking_limit, self.config_guard, self.path_braking
        vmax, da = accel.bounds(self.dt)
        collide = col is not None and bool(col.max_num_contacts)
        _, acc2, brake, cols, _ = brk.row_data()
        arrays = dict(
            consts=np.array([self.dt, self._reach, st.singularity_slow, st.reference_tolerance_m, st.damping,
                             self._correction_gain, self._frame_gain, self._posture_gain, st.binding_tol,
                             self._cfg_gain, brk.lag_s, path.floor, guard.margins.shoulder_m,
                             guard.margins.shoulder_brake_acc, guard.lag_s]),
            ints=np.array([model._address, data._address, self._flange_id, self._site_id, self._site_body,
                           self._accel_lo, self._accel_hi, self._neq, int(collide), _VELOCITY_LIMIT_BIT,
                           _ACCEL_LIMIT_BIT, _B.NEAR_SINGULARITY, _B.NO_COMMAND], dtype=np.int64),
            track_weights=self._track_weights, qpos=view.qpos, cdof=view.cdof, subtree_com=view.subtree_com,
            site_xmat=view.site_xmat, site_xpos=view.site_xpos, geom_xpos=data.geom_xpos, geom_xmat=data.geom_xmat,
            tree=self._tree, dof_parentid=self._dof_parentid, jac_flange=self._jac_flange, cond_work=self._cond_work,
            jac_world=self._jac_world, frame_cost=self._frame_cost, posture_cost=self._posture_cost, p=self._p,
            c=self._c, c_frame=self._c_frame, wjac=self._weighted_jac, d=self._d, rate_c=accel.c,
            path_brake=path.brake, path_u=path.direction_buffer, cfg_upper=self._cfg_upper, cfg_lower=self._cfg_lower,
            cfg_qpos=self._cfg_qpos, vmax=vmax, da=da, velocity_bound=accel.velocity_bound, brake_acc2=acc2,
            brake=brake, cols=cols, arm=guard._arm, guard_cols=guard._guard_cols, g_guard=self._g_guard,
            starts=self._row_starts, g=self._g, h=self._h, h_path=self._hp, row_flags=self._row_flags)
        if collide:
            assert col is not None
            arrays.update(
                shape=col._geom_shape, radius=col._geom_radius, half=col._geom_half, rbound=col._geom_rbound,
                g1=col._pair_g1_arr, g2=col._pair_g2_arr, exact=col._exact, body1=col._pair_b1_arr,
                body2=col._pair_b2_arr, lower_bound=col._lower_bound, candidates=col._candidates,
                row_pairs=col._row_pairs, dists=col._dists, fromtos=col._fromtos, jac1=col._jac1, jac2=col._jac2,
                col_params=col.fill_params(self.dt),
                g_col=self._g_col, h_col=self._h_col, h_path_col=self._hp_col)
        kinds = {"f": np.float64, "i": np.int64, "b": np.bool_}
        for name, kind, ndim in kernels.CARTESIAN_ARRAYS:
            if name not in arrays:  # (no collision rows: empty arrays, never read)
                arrays[name] = np.zeros((0,) * ndim, dtype=kinds[kind])
        table = address_table(kernels.CARTESIAN_ARRAYS, arrays)
        self._fast_arrays = list(arrays.values())  # the table's arrays, alive as long as it is
        return table

    def step_again(self, q_model_rad: ArrayLike, command: Command | None, *, dq_prev: ArrayLike | None = None
                   ) -> IkResult:
        """The last cycle once more, from the state it started from, with another command: what
        :meth:`step` would have returned had ``command`` been given in the first place (the servo
        process uses it for an input that arrived while the cycle was being solved)."""
        if self._before is None:
            raise RuntimeError("step_again() needs a step() since the last reset()")
        self._restore()
        return self.step(q_model_rad, command, dq_prev=dq_prev)

    def undo_step(self) -> None:
        """Forget the last step(): the next one starts from where it started (the servo cycle solves
        a command ahead, and drops that solve when the command it needs is no longer the same)."""
        if self._before is not None:
            self._restore()

    def _restore(self) -> None:
        assert self._before is not None
        self._dq_prev, self._ref, self._last_xi, self._mode, line = self._before
        if line is not self._line_prev:  # (the step swapped the buffers: swap them back)
            self._line_prev, self._line_spare = line, self._line_prev

    def objective(self, tasks: list[mink.Task]) -> tuple[np.ndarray, np.ndarray]:
        """mink's QP objective (P, c) for ``tasks`` at the current configuration, with our damping
        (built by the tasks themselves: for comparisons; step() assembles its own)."""
        objs = [task.compute_qp_objective(self.configuration) for task in tasks]
        p = objs[0].H.copy()
        c = objs[0].c.copy()
        for obj in objs[1:]:
            p += obj.H
            c += obj.c
        p.flat[:: N + 1] += self.settings.damping
        return p, c

    def qp_problem(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(P, c, G, h)`` of the Cartesian cycle at the current configuration, as step() builds it:
        the frame task toward the pose ``target`` (wxyz_xyz) plus the posture task, and every limit
        row (G and h are the in-place arrays: valid until the next build)."""
        target = np.ascontiguousarray(target, dtype=float)
        table = self._row_table()
        if table is not None:  # objective and rows in one kernel
            path, reference = self.path_braking, self.config_guard.reference
            assert reference is not None
            if not kernels.table_problem(target, self._posture_goal_now(), self.accel_limit.dq_prev,
                                         self.braking_limit.bounds, reference.top, path.u is not None, path.rate,
                                         table):
                raise np.linalg.LinAlgError("the IK objective's Hessian is not positive definite")
            return self._p, self._c, self._g, self._h
        p, c = self._cartesian_objective(target, None)
        g, h, _ = self._rows()
        return p, c, g, h

    def inequalities(self) -> tuple[np.ndarray, np.ndarray]:
        """All limits stacked as ``G dq <= h`` (fixed row layout) at the current configuration: the
        rows the limits' ``compute_qp_inequalities`` give, assembled in place (copies returned)."""
        g, h, _ = self._rows()
        return g.copy(), h.copy()

    # ------------------------------------------------------------------------- QP assembly
    # The cycle's QP is assembled here from MuJoCo directly, into arrays allocated once: the same
    # numbers mink's FrameTask / PostureTask and the limits' compute_qp_inequalities give (the
    # reference, tests/diffik_reference.py; tests/test_diffik_equivalence.py), without building task,
    # SE3 and Constraint objects or stacking rows every cycle (that was most of the cycle's cost).

    def _layout(self) -> None:
        """The fixed row layout: constant coefficients written once, the flag each row raises."""
        model = self.model
        if not all(int(t) == int(mujoco.mjtJoint.mjJNT_HINGE) for t in model.jnt_type):
            raise ValueError("the diff-IK expects an arm of hinge joints")
        # Model order (JOINT_NAMES) is dof order is qpos order: increments and QP columns are the same.
        if list(self._qadr) != list(range(N)) or list(self._cols) != list(range(N)):
            raise ValueError("the diff-IK expects the arm's joints in JOINT_NAMES order")
        cfg_lim, vel_lim = self.limits[0], self.limits[1]
        assert isinstance(cfg_lim, mink.ConfigurationLimit) and isinstance(vel_lim, mink.VelocityLimit)
        qpos_of_dof = np.zeros(model.nv, dtype=int)
        for j in range(model.njnt):
            qpos_of_dof[model.jnt_dofadr[j]] = model.jnt_qposadr[j]
        n_cfg = 0 if cfg_lim.projection_matrix is None else len(cfg_lim.indices)
        n_vel = 0 if vel_lim.projection_matrix is None else len(vel_lim.indices)
        n_col = 0 if self.collision_limit is None else self.collision_limit.max_num_contacts
        counts = [2 * n_cfg, 2 * n_vel, 12, 12, 1] + ([n_col] if self.collision_limit is not None else [])
        m = sum(counts)
        starts = np.concatenate([[0], np.cumsum(counts)]).astype(int)
        sl = [slice(int(a), int(b)) for a, b in itertools.pairwise(starts)]
        g = np.zeros((m, model.nv))
        h = np.full(m, np.inf)
        self._cfg_qpos, self._cfg_gain = np.zeros(0, dtype=np.int64), 0.0  # no rows: the kernel writes none
        self._cfg_upper = self._cfg_lower = np.zeros(0)
        if n_cfg:
            g[sl[0]] = np.vstack([cfg_lim.projection_matrix, -cfg_lim.projection_matrix])
            idx = qpos_of_dof[cfg_lim.indices]
            self._cfg_qpos = np.ascontiguousarray(idx, dtype=np.int64)
            self._cfg_gain = float(cfg_lim.gain)
            self._cfg_upper = np.ascontiguousarray(cfg_lim.upper[idx], dtype=float)
            self._cfg_lower = np.ascontiguousarray(cfg_lim.lower[idx], dtype=float)
        if n_vel:
            g[sl[1]] = np.vstack([vel_lim.projection_matrix, -vel_lim.projection_matrix])
            h[sl[1]] = np.hstack([self.dt * vel_lim.limit, self.dt * vel_lim.limit])  # constant
        g[sl[2]] = self.accel_limit._g
        g[sl[3]] = self.braking_limit._g
        self._g, self._h, self._hp = g, h, h.copy()
        self._sl = sl
        self._row_counts = counts
        self._accel_rows, self._braking_rows = sl[2], sl[3]
        self._accel_lo, self._accel_hi = sl[2].start, sl[2].stop  # (the binding kernel's ints)
        flags = np.zeros(m, dtype=np.int64)
        flags[sl[0]] = int(IkFlag.JOINT_LIMIT)
        flags[sl[1]] = int(IkFlag.VELOCITY_LIMIT)
        flags[sl[2]] = int(IkFlag.ACCEL_LIMIT)
        flags[sl[3]] = int(IkFlag.JOINT_LIMIT)  # joint ranges, or the configuration's joint intervals
        flags[sl[4]] = int(IkFlag.CONFIGURATION)
        if n_col:
            flags[sl[5]] = int(IkFlag.COLLISION)
        self._row_flags = flags
        self._mark_configuration_rows()
        # Scratch of the cycle (no allocation there): the TCP's world Jacobian, the flange's (and views
        # of its linear and angular rows for mj_jacSite), the objective and its optimum.
        self._jac_world = np.zeros((6, model.nv))
        # The configuration's MjData arrays the kernels read, as views made once (each attribute read
        # of an MjData makes a new array object), and the tree its Jacobians walk (mj_jac's).
        data = self.configuration.data
        self._view = types.SimpleNamespace(qpos=data.qpos, site_xmat=data.site_xmat, site_xpos=data.site_xpos,
                                           cdof=data.cdof, subtree_com=data.subtree_com)
        self._neq = int(model.neq)  # (a tool change moves a site: the model keeps its equality constraints)
        self._tree, self._dof_parentid = jacobian_tree(model)
        self._site_body = int(model.site_bodyid[self._site_id])  # (a tool change moves the site, not its body)
        # The TCP site's rows of those arrays, as views made once (for its pose each Cartesian cycle).
        self._tcp_xmat, self._tcp_xpos = data.site_xmat[self._site_id], data.site_xpos[self._site_id]
        self._jac_flange = np.zeros((6, model.nv))
        self._jac_flange_lin, self._jac_flange_ang = self._jac_flange[:3], self._jac_flange[3:]
        self._cond_work = np.zeros((6, model.nv))
        if self.frame_task.lm_damping != 0.0 or self.posture_task.lm_damping != 0.0:
            raise ValueError("the assembled objective has no Levenberg-Marquardt damping (tasks' lm_damping = 0)")
        self._frame_cost = np.asarray(self.frame_task.cost, dtype=float).copy()
        self._frame_gain = float(self.frame_task.gain)
        self._posture_cost = np.asarray(self.posture_task.cost, dtype=float).copy()
        self._posture_gain = float(self.posture_task.gain)
        self._posture_goal = np.zeros(N)  # the posture task's target in model order ...
        self._posture_src: np.ndarray | None = None  # ... taken from this array of the task's
        self._p = np.zeros((N, N))
        self._c = np.zeros(N)
        self._c_frame = np.zeros(N)
        self._weighted_jac = np.zeros((6, N))
        self._d = np.zeros((2, N))  # the optimum toward the target, and the pull-back (see step)
        self._rhs = np.zeros((N, 2))
        self._zero = np.zeros(N)
        self._no_pose = np.zeros(7)  # cartesian_step's reference when there is none
        self._pose_goal = np.zeros(7)  # the pose target's pose (wxyz_xyz) ...
        self._pose_goal_of: tuple[float, ...] | None = None  # ... of this xyzwpr
        self._fast_table: np.ndarray | None = None  # cartesian_step's arrays that stay, made at its first call
        self._fast_arrays: list[np.ndarray] = []
        # Where the row blocks start, for the kernel that fills them (limit_rows: the same path for the
        # braking rows and the configuration guard's row), and the guard's row of G.
        if self.braking_limit.path is not self.path_braking or self.config_guard.path is not self.path_braking:
            raise ValueError("the braking limit and the configuration guard must brake along the IK's path")
        self._row_starts = np.array([sl[2].start, sl[3].start, sl[4].start], dtype=np.int64)
        self._g_guard = g[sl[4].start]
        if n_col:
            self._g_col, self._h_col, self._hp_col = g[sl[5]], h[sl[5]], self._hp[sl[5]]

    def _rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(G, h, h_path)`` at the current configuration, in the arrays allocated by ``_layout``.

        ``h_path``: ``h`` with the braking rows of the limits that brake the whole path together
        (their ``h_path``). Reads the same state the limits' own rows read (the configuration's qpos,
        ``accel_limit.dq_prev``, ``path_braking``), so both stay interchangeable."""
        g, h, hp, dt = self._g, self._h, self._hp, self.dt
        table = self._row_table()
        if table is not None:  # one kernel (the same ones as below, narrow phases inside)
            path, reference = self.path_braking, self.config_guard.reference
            assert reference is not None
            kernels.table_rows(self.accel_limit.dq_prev, self.braking_limit.bounds, reference.top, path.u is not None,
                               path.rate, table)
            return g, h, hp
        data = self.configuration.data
        qpos = self._view.qpos  # model order is qpos order (checked by _layout)
        accel, path = self.accel_limit, self.path_braking
        with_path = path.u is not None
        # One kernel for the rows the limits' own fill() give (mink's ConfigurationLimit: gain * (upper
        # - q), gain * (q - lower); acceleration; braking; the configuration guard): calling them one
        # by one, with their Python between, cost three times as much.
        kernels.limit_rows(qpos, dt, self._cfg_gain, self._cfg_upper, self._cfg_lower, self._cfg_qpos,
                           accel.c, accel.dq_prev, *accel.bounds(dt), accel.velocity_bound,
                           *self.braking_limit.row_data(), with_path, path.u if path.u is not None else qpos,
                           path.rate if with_path else 0.0, path.floor, *self.config_guard.row_data(qpos),
                           self._g_guard, self._row_starts, h, hp)
        if self.collision_limit is not None:
            self.collision_limit.fill(data, qpos, dt, self._g_col, self._h_col, self._hp_col)
        return g, h, hp

    def _kinematics(self, q: np.ndarray) -> None:
        """The configuration at ``q``: what ``Configuration.update`` does, without copying qpos."""
        data = self.configuration.data
        self._view.qpos[:] = q  # the arm's joints are the whole qpos, in model order (checked by _layout)
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_comPos(self.model, data)
        if self._neq > 0:
            mujoco.mj_makeConstraint(self.model, data)

    def _posture_terms(self, task: mink.PostureTask, cost: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """A posture task's linear term toward the joints ``goal`` (model order); its Hessian is
        ``diag(cost**2)``. Hinge joints: mj_differentiatePos is ``q - goal``."""
        error = self.configuration.data.qpos[self._qadr] - goal
        weighted_error = cost * (-task.gain * error)
        return -weighted_error * cost

    def _cartesian_objective(self, target: np.ndarray, ref: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(P, c) of mink's frame task toward ``target`` plus the posture task, with our damping, at
        the current configuration, in one kernel; its optimum is left in ``self._d`` (row 0), and
        with a reference pose ``ref`` the pull-back toward it (row 1; see ``step``)."""
        view = self._view
        sid = self._site_id
        posture_goal = self._posture_goal_now()
        ok = kernels.site_objective(
            view.cdof, view.subtree_com, self._tree, self._dof_parentid, self._site_body, view.site_xmat,
            view.site_xpos, sid, self._jac_world, target, ref if ref is not None else target, ref is not None,
            self._frame_cost, self._frame_gain, self._posture_cost, self._posture_gain, posture_goal, view.qpos,
            self.settings.damping, self._correction_gain, self._p, self._c, self._c_frame, self._weighted_jac, self._d)
        if not ok:
            raise np.linalg.LinAlgError("the IK objective's Hessian is not positive definite")
        return self._p, self._c

    def _posture_goal_now(self) -> np.ndarray:
        """The posture task's target in model order (taken again when ``set_target`` stored a new array)."""
        pt = self.posture_task
        if pt.target_q is not self._posture_src:  # set_target stores a new array: model order, once
            assert pt.target_q is not None
            self._posture_src = pt.target_q
            self._posture_goal = np.ascontiguousarray(pt.target_q, dtype=float)  # qpos order is model order
        return self._posture_goal

    def _row_table(self) -> np.ndarray | None:
        """cartesian_step's table when the rows can be made from it (:func:`~servo_app.motion.ik_kernels.
        table_rows`: the path's direction, if any, is its own array, the configuration latched), else
        None (``_rows``' code)."""
        table = self._fast_table
        if table is None:
            table = self._fast_table = self._cartesian_step_table()
            if table is None:
                return None
        path = self.path_braking
        foreign_direction = path.u is not None and path.u is not path.direction_buffer
        if not len(table) or self.config_guard.reference is None or foreign_direction:
            return None
        return table

    def _joint_objective(self, q: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P, c) of the joint task toward ``goal`` (cost 1, gain 1), with our damping."""
        jt = self.joint_task
        p = np.diag(np.asarray(jt.cost, dtype=float) ** 2)
        c = self._posture_terms(jt, np.asarray(jt.cost, dtype=float), goal)
        p.flat[:: N + 1] += self.settings.damping
        return p, c

    def _line_past_braking(self, direction: np.ndarray, s_goal: float, g: np.ndarray, h: np.ndarray,
                           h_path: np.ndarray) -> float | None:
        """A Cartesian line whose braking rows for a joint bound ask for a harder brake than its
        acceleration rows allow: the ``s`` nearest the braking rows' interval within every other row,
        each joint's own braking row widened by ``LINE_BRAKE_LATE_S`` of its acceleration (its stop
        starting that much later), so the line brakes as hard as it may. None if that leaves none.

        The path's rows count on 0.8 of the acceleration, but the acceleration rows start from what the
        shaper delivers, whose deceleration builds up at its jerk limit: at 4 ms a pose target into J5's
        limit found them a hair (0.004 of its speed) below what J2 could shed in a cycle, and J5's own
        row then up to 0.9 cycle's acceleration (3.7 toward the reach at 359 mm/s). The blend and the QP
        then kept every row and let the orientation go: a pure translation turned the TCP at 5.6 deg/s
        for 5 (up to 3.4 x its angular speed). The joint ranges' own rows (ConfigurationLimit) still
        hold, and the servo cycle's guard still keeps a stop in range."""
        rows = self._braking_rows
        assert rows is not None
        _, da = self.accel_limit.bounds(self.dt)
        h_other = h_path.copy()
        h_other[rows] = h[rows] + np.tile(da, 2) * (LINE_BRAKE_LATE_S / self.dt)
        other = _scale_interval(direction, g, h_other)
        braking = _scale_interval(direction, g[rows], h_path[rows])
        if other is None or braking is None:
            return None
        return min(max(min(max(s_goal, braking[0]), braking[1]), other[0]), other[1])

    def _braking_flags(self, dq: np.ndarray, g: np.ndarray, h_path: np.ndarray) -> int:
        """The flags (JOINT_LIMIT, CONFIGURATION) of the path's braking rows ``dq`` binds: what holds the
        motion back (the flags of the step are read from each joint's own rows, looser than these)."""
        rows = self._braking_rows
        assert rows is not None and self._row_flags is not None
        bind = g[rows] @ dq >= h_path[rows] - self.settings.binding_tol
        return int(np.bitwise_or.reduce(self._row_flags[rows][bind])) if bind.any() else 0

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
        interval = _scale_interval(target - base, g, h, base)
        if interval is None:
            return None
        lo, hi = max(interval[0], 0.0), min(interval[1], 1.0)
        if lo > hi + 1e-9:  # rounding: a bound met exactly at t = 0 may read -1e-13
            return None
        return base + max(hi, lo) * (target - base)

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
    def _twist_base(self, cmd: Twist, tcp: np.ndarray) -> tuple[np.ndarray, bool]:
        """The twist in the base frame, m/s and rad/s, and whether it is not zero (``xi.any()``)."""
        xi = np.empty(6)
        moves = kernels.twist_si(cmd.linear, cmd.angular, xi)  # numpy's operations in one call
        if cmd.frame == "tool":
            for part in (xi[:3], xi[3:]):
                mujoco.mju_rotVecQuat(part, part.copy(), tcp[:4])
            moves = kernels.any_nonzero(xi)
        return xi, moves

    def _pose_twist(self, cmd: PoseTarget, tcp: np.ndarray) -> tuple[np.ndarray, bool]:
        """Straight-line P-control: one rate for translation and rotation (they arrive together),
        capped by the speed caps and by the speed from which the target can still be reached
        braking at the target accelerations."""
        st, dt = self.settings, self.dt
        goal = self._pose_goal
        if cmd.xyzwpr != self._pose_goal_of:  # (once per target, not every cycle: pays for the along-track)
            goal = self._pose_goal = _pose_of_matrix(xyzwpr_to_matrix(cmd.xyzwpr))
            self._pose_goal_of = cmd.xyzwpr
            self._line_prev[:] = 0.0  # another line: nothing to compare with (kernels.turn_cap)
        dp = goal[4:] - tcp[4:]
        dth = _rotation_between(goal, tcp)
        lin, ang = float(np.linalg.norm(dp)), float(np.linalg.norm(dth))
        if lin * 1000.0 < st.arrive_mm and math.degrees(ang) < st.arrive_deg:
            return np.zeros(6), True
        rate = st.pose_gain
        for dist, cap, acc in ((lin, cmd.linear_speed / 1000.0, st.target_linear_acc / 1000.0),
                               (ang, math.radians(cmd.angular_speed), math.radians(st.target_angular_acc))):
            if dist > 0.0:
                rate = min(rate, cap / dist, braking_speed_scalar(dist, acc, dt + self.follow_lag) / dist)
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
        mujoco.mj_jacSite(self.model, data, self._jac_flange_lin, self._jac_flange_ang, self._flange_id)
        return kernels.condition_number(self._jac_flange, self._reach, self._cond_work)

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

    def _mark_configuration_rows(self) -> None:
        """Braking rows whose bound is a configuration interval raise CONFIGURATION, not JOINT_LIMIT."""
        if self._row_flags is not None and self._braking_rows is not None:
            self._row_flags[self._braking_rows] = np.where(self.braking_limit.restricted, int(IkFlag.CONFIGURATION),
                                                           int(IkFlag.JOINT_LIMIT))

    def _tcp_pose(self) -> np.ndarray:
        """The TCP site's pose as mink stores an SE3: quaternion (w x y z), then position (read through
        the views of the configuration's arrays made once)."""
        pose = np.empty(7)
        mujoco.mju_mat2Quat(pose[:4], self._tcp_xmat)
        pose[4:] = self._tcp_xpos
        return pose

    def _along_track(self, ref: np.ndarray, tcp: np.ndarray, xi: np.ndarray) -> np.ndarray:
        """The reference moved along the line ``xi`` to where the TCP actually is along it.

        The reference advances by what each cycle asked for; the jerk-limited shaper delivers it a
        little later. Pulling the TCP forward to the reference then overshot the commanded speed
        (+20 %) and swung back: only the error across the line is the IK's to correct."""
        out = np.empty(7)
        return out if kernels.along_track(out, ref, tcp, xi, self._track_weights) else ref

    def _full_q(self, q: np.ndarray) -> np.ndarray:
        full = self.configuration.data.qpos.copy()
        full[self._qadr] = q
        return full

    @staticmethod
    def _checked(v: ArrayLike, name: str) -> np.ndarray:
        a = np.array(v, dtype=float)  # a copy
        if a.shape != (N,):
            raise ValueError(f"{name} has shape {a.shape}, expected ({N},)")
        if not kernels.all_finite(a):
            i = int(np.flatnonzero(~np.isfinite(a))[0])
            raise ValueError(f"{name}[{i}]={a[i]} is not a finite number")
        return a


# ------------------------------------------------------------------------------ pure functions
def _scale_interval(direction: np.ndarray, g: np.ndarray, h: np.ndarray, shift: np.ndarray | None = None
                    ) -> tuple[float, float] | None:
    """The interval of ``s`` with ``g @ (s * direction + shift) <= h`` (the rows are linear), or None."""
    if shift is None:
        lo, hi = kernels.scale_interval(direction, g, h, direction, 0.0)
    else:
        lo, hi = kernels.scale_interval(direction, g, h, shift, 1.0)
    return None if math.isnan(lo) else (lo, hi)


def _within_reach(g: np.ndarray, h: np.ndarray, accel_rows: slice, c_inv: np.ndarray, margin: float
                  ) -> np.ndarray:
    """``h`` with each row raised, if need be, to the least ``g dq`` the acceleration rows (``C dq`` in a
    box, FANUC axes) reach, plus ``margin``: a row the state has already outrun (a joint past its own
    braking curve) then asks for the hardest brake there is.

    Why: the line's late braking (``_line_past_braking``) can leave a joint past its own braking curve;
    its row then made the QP infeasible and the last resort braked joint by joint. A pose target past
    J1's axis (J1 braking for its range, J1 and J6 counter-rotating) turned the TCP at up to 6 x its
    angular speed; the QP within reach keeps the tracking (the orientation) while J1 brakes."""
    box = h[accel_rows]
    n = len(box) // 2
    hi, lo = box[:n], -box[n:]
    a = g @ c_inv
    out = np.maximum(h, np.where(a > 0.0, a * lo, a * hi).sum(axis=1) + margin)
    out[accel_rows] = box
    return out


def _path_scale(direction: np.ndarray, s_goal: float, g: np.ndarray, h: np.ndarray,
                shift: np.ndarray | None = None) -> float | None:
    """The ``s`` nearest ``s_goal`` with ``g @ (s * direction + shift) <= h``, or None if there is none."""
    if shift is None:  # (_scale_interval's kernel call, without its call: this runs every Cartesian cycle)
        lo, hi = kernels.scale_interval(direction, g, h, direction, 0.0)
    else:
        lo, hi = kernels.scale_interval(direction, g, h, shift, 1.0)
    if math.isnan(lo):
        return None
    s = min(max(s_goal, lo), hi)
    return s if math.isfinite(s) else None


# Poses are 7-vectors as mink's SE3 stores them: unit quaternion (w x y z), then position (m).
def _pose_of_matrix(t: np.ndarray) -> np.ndarray:
    pose = np.empty(7)
    mujoco.mju_mat2Quat(pose[:4], np.ascontiguousarray(t[:3, :3]).reshape(9))
    pose[4:] = t[:3, 3]
    return pose


def _advance(pose: np.ndarray, xi: np.ndarray, s: float, dt: float) -> np.ndarray:
    """Pose moved by the base-frame displacement ``s * xi * dt`` (translation of the TCP, rotation
    about the TCP): a new array (poses are kept by step_again, never changed in place)."""
    out = np.empty(7)
    kernels.advance(out, pose, xi, s, dt)
    return out


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Base-frame rotation vector taking pose ``b``'s orientation to ``a``'s (the shorter way)."""
    w = np.empty(3)
    kernels.rotation_between(w, a, b)
    return w
