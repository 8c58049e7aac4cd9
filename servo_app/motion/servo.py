"""The servo cycle's motion stage: live command -> jerk-limited next joint position.

Pure: no sockets, no threads, no clock (time advances by the fixed interval per command). It keeps
the *commanded* joint state (FANUC convention, degrees) and never reads the servo position after the
start. Commands arrive from the runner (which got them from the API process):

- joint target (absolute, FANUC deg) with a speed scale;
- joint jog (deg/s per axis); hold-to-run is the supervisor's (it calls ``stop`` when the hold runs out);
- Cartesian: a TCP twist (base or tool frame) or a pose target, through the differential IK, whose
  per-cycle joint velocity the shaper then tracks jerk-limited;
- stop (soft: resumable, and along the current Cartesian path where there is one; fast: shortest
  stop) and resume;
- trajectory replay: positions planned and checked beforehand (:mod:`servo_app.motion.trajectory`),
  one per cycle through the shaper's float32 guard (:meth:`JointShaper.follow`); a soft stop pauses
  along the path and resume continues it, a fast stop or any other command leaves it.

A flange-speed guard keeps joint-space motion under the speed cap at which the controller's
acceleration and jerk tables were evaluated (Appendix B: above it the controller's limits fall).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from servo_app.errors import CommandRejected
from servo_app.motion import cycle_kernels
from servo_app.motion.commands import PoseTarget, Twist, check_speed_scale
from servo_app.motion.diffik import DifferentialIK, IkResult
from servo_app.motion.limit_tables import LimitTables, default_tables
from servo_app.motion.shaper import JointShaper, ShaperLimits, to_f32
from servo_app.motion.stops import ease_out
from servo_app.motion.trajectory import DONE, PAUSED, ReplayPlayer
from servo_app.robots.configuration import ArmConfiguration, ConfigurationRegion, boundary_distances
from servo_app.robots.conventions import fanuc_deg_to_model_rad, model_rad_to_fanuc_deg, xyzwpr_to_matrix
from servo_app.robots.kernels import flange_distance_mm, pack_dims
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import RobotProfile

if TYPE_CHECKING:
    from ruckig import Trajectory

CREEP_DEG_S = 1e-3  # joint speed below which a Cartesian motion is held still (~10 um/s at the flange)


class _Ahead(NamedTuple):
    """The IK of the next command, solved ahead (:meth:`ServoCycle.solve_ahead`): its result, the
    command it was solved for, the shaper step it starts after, and the start it was solved from. (A
    named tuple: one is made every status, and a dataclass's __init__ is a Python call.)"""

    result: IkResult
    command: Twist | None
    steps: int
    q_f: np.ndarray
    v_f: np.ndarray
    q_m: np.ndarray
    dq_prev: np.ndarray


class _Ease(NamedTuple):
    """A twist's soft stop: the twist, scaled by ``share`` (a jerk-limited fall to 0, its velocity), from
    the shaper step ``step`` on; ``scaled``: the last scaled twist made and its step (one per cycle)."""

    twist: Twist
    share: Trajectory
    step: int
    scaled: list[tuple[int, Twist | None]]


# A twist's soft stop eases the twist out at this share of the acceleration and jerk its fastest joint
# may use for the twist's speed (the IK's acceleration, the shaper's jerk). Measured on 400 random slow
# moves turning fast about a 200 mm tool (the wrist speeding up left out): 0.5 ran 2 of them over their
# released speed by +62 % and +175 % (the IK's acceleration rows bound, it fell behind the path and its
# pull-back moved the TCP as the twist's share ran out), 0.35 one (+97 %), 0.25 none; 0.8 and 1.0 ran
# over by up to +91 % and +98 % (the shaper lagging the faster fall). The stop takes longer: 0.23 s on
# average (0.15 s braking on the line), 0.65 s at most (0.40).
EASE_SHARE = 0.25


def _same_motion(a: Twist | PoseTarget | None, b: Twist | PoseTarget | None) -> bool:
    """Would the IK solve ``a`` and ``b`` alike? (A renewal of a twist is a new object with a new stamp.)"""
    if a is b:
        return True
    return (isinstance(a, Twist) and isinstance(b, Twist) and a.linear == b.linear and a.angular == b.angular
            and a.frame == b.frame)


@dataclass
class ServoSettings:
    limit_fraction: float = 0.9  # share of the controller's limits the shaper may use
    flange_speed_cap: float | None = None  # mm/s; None: the profile's $MAX_SPD
    payload_kg: float | None = None  # None: the controller assumes max payload (Appendix B)
    joint_margin_deg: float = 0.5  # keep this far inside the joint ranges
    flange_speed_margin: float = 0.8  # joint motion slows down above this share of the cap
    ik_solver: str = "daqp"  # "daqp" or "osqp" (persistent workspaces either way)
    tool_xyzwpr: tuple[float, ...] | None = None  # TCP offset from the flange, mm / deg
    collision: bool = True  # self-collision and floor checks in the IK
    config_margin_deg: float = 1.0  # joint motion keeps this far from any configuration boundary
    # A pose target held still finishes its last millimetres as a joint move (see _finish_pose).
    finish_mm: float = 2.0
    finish_deg: float = 1.0
    finish_after_s: float = 0.1  # the target must have stayed the same this long


def _deg(v: float) -> str:
    """An angle for a message: to the thousandth, but a wild value (1e300, sent as metres or radians
    times a million) in a few characters rather than 300 digits."""
    return f"{v:.3f}" if abs(v) < 1e6 else f"{v:.4g}"

class ServoCycle:
    def __init__(self, profile: RobotProfile, dt: float, settings: ServoSettings | None = None) -> None:
        self.profile = profile
        self.dt = dt
        self.settings = settings or ServoSettings()
        self.shaper: JointShaper | None = None
        self.limits: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.stopped = False
        self._target: tuple[np.ndarray, float] | None = None  # resumed after a soft stop
        self._jog: np.ndarray | None = None
        self._horizon = 0.0
        self.tables_source = "profile"
        self._profile_tables: LimitTables | None = None  # default_tables(profile), built once
        self._tables: LimitTables | None = None  # the tables of the stream that began last
        self._limits_for: tuple[object, ...] | None = None  # (tables, cap, payload) self.limits were built for
        lo = np.asarray(profile.joint_min_deg) + self.settings.joint_margin_deg
        hi = np.asarray(profile.joint_max_deg) - self.settings.joint_margin_deg
        self._range_model_deg = (lo, hi)
        self.kin = ArmKinematics(profile)
        k = self.kin
        self._dims = pack_dims(k.a1, k.a2, k.a3, k.d4, k.d6)  # for the flange-speed kernels
        self._j23 = float(profile.j23_factor)
        self._region_packed = np.empty(0)  # self._region for the kernels (set by begin)
        # Scratch for the kernels: the cycle allocates nothing for them.
        self._scratch = np.empty(profile.dof)
        self._jog_goal = np.empty(profile.dof)
        self._ik_velocity = np.empty(profile.dof)  # _guard_ik_velocity's output, handed to the shaper
        # The shaper's soft limits as the guards use them, for the limits they were derived from.
        self._soft_for: ShaperLimits | None = None
        self._soft_vel = self._brake = np.empty(0)
        self._stop_lag = 0.0
        self.ik = DifferentialIK(profile, dt, self.settings.tool_xyzwpr, self.settings.ik_solver,  # type: ignore[arg-type]
                                 collision=self.settings.collision)
        self._pending = False  # a joint motion waits for rest after a change of direction
        self._cart: Twist | PoseTarget | None = None
        self._cart_active = False  # the IK drives the shaper (also while braking along the path)
        self._pose_held_s = 0.0  # how long the current pose target has stayed the same
        self._finishing: PoseTarget | None = None  # the pose target whose last millimetres run as a joint move
        self.last_ik: IkResult | None = None
        self._speed_scale = 1.0  # flange-speed guard's current reduction of joint motion
        self.flange_speed = 0.0  # mm/s, from the last two commanded positions
        self.limit_scale = 1.0  # share of the IK's velocity the stopping-point guard let through
        self.configuration: ArmConfiguration | None = None  # held from the start of streaming
        self._region: ConfigurationRegion | None = None  # joint ranges and that configuration, with margins
        self._q_prev: np.ndarray | None = None
        self.cap = 0.0
        # Called after each IK solve: it may apply a newer command (twist or pose target), which this
        # cycle then solves again from the same start (see _steer_ik); it must stop doing so in time.
        self.late_command: Callable[[], None] | None = None
        self.late_inputs = 0  # solves again for a command that arrived during the solve
        self._ahead: _Ahead | None = None  # the next command's IK, solved ahead (solve_ahead)
        self._steps = 0  # shaper steps taken: an ahead solve is good for the step after the one it followed
        self.ahead_used = self.ahead_dropped = 0  # ahead solves a command used / solved again
        self._replay: ReplayPlayer | None = None  # a trajectory being replayed (kept when done: its progress)
        self.replay_error = ""  # why the last replay was left before its end

    # ------------------------------------------------------------ MotionSource
    def begin(self, q_start: np.ndarray, tables: LimitTables | None) -> None:
        """Set up the motion of a stream that starts at ``q_start``: it runs between the stream's first
        command and its second, so what does not change from one stream to the next is kept."""
        if tables is None:
            if self._profile_tables is None:
                self._profile_tables = default_tables(self.profile)
            tables = self._profile_tables
            self.tables_source = "profile"
        else:
            self.tables_source = "controller"
        self._tables = tables
        vel, acc, jerk = self._limits_of(tables)
        self.shaper = JointShaper(ShaperLimits(vel, acc, jerk, fraction=self.settings.limit_fraction),
                                  self.dt, np.asarray(q_start[: self.profile.dof], dtype=float))
        # A jog target runs this far ahead: always beyond the braking distance at full speed.
        self._horizon = float(np.max(2.0 * (vel / acc + acc / jerk))) + 0.1
        self.stopped = False
        self._target = None
        self._finishing = None
        self._jog = None
        self._cart, self._cart_active = None, False
        self._ease: _Ease | None = None
        self._pending = False
        self._speed_scale = 1.0
        self._cap_scale = 1.0  # the joint target's speed share that keeps the flange under the cap
        self._jog_cap = 1.0  # the same for the joint jog
        self._jog_caps = np.full(self.profile.dof, np.inf)  # deg/s: each joint's asked jog speed (inf: not jogged)
        self._q_prev = None
        self._replay, self.replay_error = None, ""
        q_model = fanuc_deg_to_model_rad(np.asarray(q_start[: self.profile.dof], float), self.profile.j23_factor)
        self._ahead = None
        self.ik.reset(q_model)
        # A stream may begin closer than the margin to a boundary: keep at least what it had there.
        start = boundary_distances(q_model, self.kin)
        margins = np.minimum(np.radians(self.settings.config_margin_deg), start * 0.999)
        lo, hi = self._range_model_deg  # widened by a rounding step: clipped targets land on the bound
        region = ConfigurationRegion.around(q_model, self.kin, margins)
        self._region = region.within(np.radians(lo - 1e-9), np.radians(hi + 1e-9))
        self._region_packed = self._region.packed
        self.configuration = self._region.reference

    def _limits_of(self, tables: LimitTables) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The (vel, acc, jerk) limits of ``tables`` at the cap and the payload (Appendix B), built
        again only when one of them changed (``self.limits``, which the runner publishes)."""
        cap = tables.cap(self.settings.flange_speed_cap)  # (the controller's $MAX_SPD if lower)
        self.cap = cap
        key = (tables, cap, self.settings.payload_kg)
        if self._limits_for is None or any(a is not b for a, b in zip(self._limits_for, key, strict=True)):
            self.limits = tuple(x[: self.profile.dof] for x in tables.for_cap(cap, self.settings.payload_kg))  # type: ignore[assignment]
            self._limits_for = key
        assert self.limits is not None
        return self.limits

    def set_tool(self, tool_xyzwpr: tuple[float, ...] | None, payload_kg: float | None, streaming: bool = True
                 ) -> None:
        """Another tool: the TCP the IK, pose targets and tool-frame twists use, and the payload of the
        limit tables (Appendix B). While a stream is alive (``streaming``), only at rest with no motion
        held (a jog against a limit, a twist, a pose target): CommandRejected otherwise, and nothing
        changes; the shaper's limits are then rebuilt for the payload (at rest its state fits any
        limits). Without a stream the next one's ``begin`` builds them. A target interrupted by a soft
        stop is dropped (a pose target was a pose of the old TCP), and so is a paused trajectory (planned
        for the old TCP and payload): resume has nothing to continue."""
        moving = (not self.at_rest() or self._cart_active or self._jog is not None or self._pending)
        if streaming and moving:
            raise CommandRejected("tool change refused: the arm is moving; wait until it is at rest "
                                  "(GET /api/state shows at_rest and settled), then change the tool")
        tool = None if tool_xyzwpr is None else tuple(float(v) for v in tool_xyzwpr)
        self.ik.set_tool(tool)
        self.settings.tool_xyzwpr = tool
        self.settings.payload_kg = payload_kg
        self._target, self._cart, self._finishing = None, None, None
        self._jog, self._cart_active, self._pending = None, False, False
        self._leave_replay("ended by a tool change while it was paused: it was planned for the old tool and "
                           "payload; plan it again for the new one")
        if self._tables is None:
            return  # no stream yet: its begin builds the limits
        vel, acc, jerk = self._limits_of(self._tables)  # published at once, streaming or not
        if self.shaper is not None and streaming:
            self.shaper.set_limits(ShaperLimits(vel, acc, jerk, fraction=self.settings.limit_fraction))
            self._horizon = float(np.max(2.0 * (vel / acc + acc / jerk))) + 0.1

    def next_command(self, status: object) -> np.ndarray:
        """The next commanded joint position; ``status`` (the controller's latest status) is not read:
        the cycle advances by the fixed interval."""
        shaper = self.shaper
        if shaper is None:
            shaper = self._require()  # (raises)
        ahead, self._ahead = self._ahead, None
        if self._replay is not None and self._replay.active:
            self._drop(ahead)
            q = self._step_replay(shaper, self._replay)
            self._steps += 1
            self._guard_flange_speed(shaper, q)
            return q
        if self._pending and shaper.at_rest:  # at rest after a change of direction: start it now
            self._pending = False
            if self._target is not None:
                self._start_target(shaper)
        if self._cart_active:
            self._steer_ik(shaper, ahead)
        else:
            self._drop(ahead)
            if self._jog is not None and not self.stopped and not self._pending:
                self._steer_jog(shaper, self._jog)
        q = shaper.step()
        self._steps += 1
        self._guard_flange_speed(shaper, q)
        return q

    def solve_ahead(self) -> bool:
        """Solve the next command's IK now, between status packets, for a twist or a brake along its
        path (True if it did). ``next_command`` uses the result if the command is still the same
        motion and the shaper has not stepped since; otherwise it solves again from the same start
        (``DifferentialIK.step_again``): what it would have computed anyway. Nothing else is advanced:
        the shaper steps, and every guard runs, when the command is made.

        Why: at 8 ms the IK solved on the status packet's arrival took 370-410 us with caches cold after
        the wait (170 us in a loop), most of the 510-610 us from status to command (issue 15). A pose
        target is not solved ahead: whether its IK runs at all is decided when the command is made
        (``_finish_pose``)."""
        shaper = self.shaper
        cart = self._ik_command()
        if shaper is None or not self._cart_active or self._ahead is not None or isinstance(cart, PoseTarget):
            return False
        q_f, v_f = shaper.position_velocity()
        q_m, dq_prev = np.empty(len(q_f)), np.empty(len(q_f))
        cycle_kernels.ik_start(q_f, v_f, self._j23, self.dt, q_m, dq_prev)
        res = self.ik.step_owned(q_m, cart, dq_prev)  # (arrays made here for it)
        self._ahead = _Ahead(res, cart, self._steps, q_f, v_f, q_m, dq_prev)
        return True

    def _drop(self, ahead: _Ahead | None) -> None:
        """An ahead solve no command uses: the IK forgets it."""
        if ahead is not None:
            self.ik.undo_step()
            self.ahead_dropped += 1

    @property
    def ik_active(self) -> bool:
        """The differential IK drives the shaper (a twist or pose target, or braking along its path)."""
        return self._cart_active

    def request_rest(self) -> None:
        if self.shaper is not None and not self.shaper.at_rest:
            self.stop(fast=False)

    def at_rest(self) -> bool:
        return self.shaper is None or self.shaper.at_rest

    # --------------------------------------------------------------- commands
    def check_joint_target(self, q_fanuc_deg: np.ndarray) -> np.ndarray:
        """The target as an array if it is within the joint ranges (in the model convention) and, while a
        stream is alive, the straight joint line to it keeps the arm configuration; else CommandRejected."""
        q = self._checked_position(q_fanuc_deg)
        if self.shaper is not None:
            reach = self._config_keeping_reach(self.shaper.state[0], q)
            if reach < 1.0:
                raise CommandRejected(
                    f"joints={[round(float(v), 3) for v in q]} leave the arm configuration {self.configuration} "
                    f"held since the stream started (manual 61.5, MOTN-156): only {reach:.0%} of the way keeps it; "
                    f"send a target the arm reaches in that configuration")
        return q

    def set_joint_target(self, q_fanuc_deg: np.ndarray, speed_scale: float = 1.0) -> None:
        shaper = self._require()
        q = self.check_joint_target(q_fanuc_deg)
        speed_scale = check_speed_scale(speed_scale)
        self._leave_replay("a joint target took over")
        self._target, self._jog = (q, speed_scale), None
        self._finishing = None
        self._cart, self._cart_active = None, False
        self.stopped = False
        if self._redirects(shaper, q - shaper.state[0]):
            self._pending = True
            self._stop_shaper(shaper, "soft")
            return
        self._pending = False
        self._start_target(shaper)

    def _start_target(self, shaper: JointShaper) -> None:
        """Head for the joint target from where the arm is, at the speed share that keeps the flange
        under its cap the whole way (``_cap_share``); the cycle's guard only trims what is left."""
        assert self._target is not None
        q, speed_scale = self._target
        self._cap_scale = self._cap_share(shaper.state[0], q)
        shaper.set_target(q, speed_scale * self._speed_scale * self._cap_scale)

    def _cap_share(self, q0: np.ndarray, q1: np.ndarray, path_speed: float | None = None, samples: int = 24,
                   tcp_speeds: tuple[float, float] | None = None) -> float:
        """The share of the joint speed limits (of ``path_speed``, deg/s of the joint that moves most,
        for a jog) at which a straight joint move q0 -> q1 keeps the flange under
        ``flange_speed_margin`` of the cap everywhere along it.

        The guard alone (predicting four cycles ahead) came too late for a joint target from rest: the
        shaper reached 83 deg/s within ten cycles and the flange 451 mm/s under a 250 mm/s cap before
        its lowered target speed took hold. A synchronised move runs along the line at a path speed of
        at most min_j vmax_j / |d_j| (d: the unit direction), and the flange at |J(q) d| times that:
        the largest |J d| along the line (finite differences of the flange position) bounds it.
        ``tcp_speeds`` (mm/s, deg/s): the TCP's linear and angular speeds are kept under them too."""
        d = np.asarray(q1, dtype=float) - np.asarray(q0, dtype=float)
        length = float(np.max(np.abs(d)))
        if length < 1e-9 or self.limits is None:
            return 1.0
        d /= length  # the path parameter in deg of the joint that moves most
        if path_speed is None:
            vel = self.limits[0]
            moving = np.abs(d) > 1e-12
            path_speed = float(np.min(vel[moving] / np.abs(d[moving])))  # deg/s along the line at share 1
        eps = 1e-3
        gain = 0.0  # mm of flange travel per deg along the line, the largest on it
        lin_gain = ang_gain = 0.0  # the TCP's mm and deg per deg along the line, the largest on it
        kin, j23 = self.ik.kin, self.profile.j23_factor  # (the IK's kinematics: with the tool)
        for t in np.linspace(0.0, length, samples):
            q = q0 + d * t
            gain = max(gain, flange_distance_mm(q, q + d * eps, self._j23, self._dims) / eps)
            if tcp_speeds is not None:
                a, b = kin.fk_tcp(fanuc_deg_to_model_rad(q, j23)), kin.fk_tcp(fanuc_deg_to_model_rad(q + d * eps, j23))
                lin_gain = max(lin_gain, float(np.linalg.norm(b[:3, 3] - a[:3, 3])) * 1000.0 / eps)
                cos = (float(np.trace(b[:3, :3] @ a[:3, :3].T)) - 1.0) / 2.0
                ang_gain = max(ang_gain, math.degrees(math.acos(min(1.0, max(-1.0, cos)))) / eps)
        share = 1.0
        for g, limit in ((gain, self.cap * self.settings.flange_speed_margin),
                         *(zip((lin_gain, ang_gain), tcp_speeds, strict=True) if tcp_speeds is not None else ())):
            if g * path_speed > limit:
                share = min(share, limit / (g * path_speed))
        return max(1e-3, share)

    def jog_joints(self, v_deg_s: np.ndarray) -> None:
        """Jog at joint velocities (deg/s): a target kept ahead in the jog direction, clipped to the ranges,
        so the shaper brakes to rest at a joint limit instead of running into it."""
        v = np.ascontiguousarray(self._joint_values(v_deg_s))  # (the jog kernel takes contiguous arrays)
        shaper = self._require()
        self._leave_replay("a jog took over")
        renewal = self._jog is not None and np.array_equal(v, self._jog)  # the same button, still held
        redirect = not renewal and not self._pending and self._redirects(shaper, v)
        self._jog, self._target = v, None
        if not renewal:  # no jogged joint faster than asked, also where the shaper leaves the line (caps
            # 1e-9 of the fastest at least: ruckig takes no zero limit); joints not jogged run as the line asks
            floor = 1e-9 * float(np.max(np.abs(v)))
            self._jog_caps = np.where(v != 0.0, np.maximum(np.abs(v), floor), np.inf)
        # Each renewal too (cheap: 2 x 24 flange points), as the arm moves on along the line. Along the
        # clipped line and the jog's own: the target runs ahead by the horizon times the guard's share,
        # clipped only once that reaches a limit. (The clipped line alone took 0.42 for J3 -200, J6 200
        # deg/s, its J3 cut short, while the arm went along J3 = -J6 at 5.9 mm/deg: 324 mm/s under 323.)
        q0 = shaper.state[0]
        speed = float(np.max(np.abs(v)))
        self._jog_cap = 1.0 if speed < 1e-9 else min(
            self._cap_share(q0, self._clip_to_range(q0 + v * self._horizon), speed),
            self._cap_share(q0, q0 + v * self._horizon, speed))
        self._finishing = None
        self._cart, self._cart_active = None, False
        self.stopped = False
        if redirect:
            self._pending = True
            self._stop_shaper(shaper, "soft")

    def check_twist(self, cmd: Twist) -> None:
        """CommandRejected unless the flange stays within its speed cap at ``cmd``: the TCP's speed and
        the swing of a turn about a TCP away from the flange. Changes nothing."""
        linear = math.hypot(*cmd.linear)  # (not numpy's norm: ~5 us less each, on every twist request)
        self._check_flange_speed(linear, math.hypot(*cmd.angular), f"linear speed {linear:.1f} mm/s", cmd.angular)

    def check_pose_target(self, cmd: PoseTarget) -> None:
        """:meth:`check_twist` for a pose target's speed caps. Changes nothing."""
        self._check_flange_speed(cmd.linear_speed, cmd.angular_speed, f"linear_speed={cmd.linear_speed} mm/s",
                                 cmd.angular_speed)

    def _check_flange_speed(self, linear_mm_s: float, angular_deg_s: float, said: str,
                            angular: float | tuple[float, ...]) -> None:
        """CommandRejected, naming the request's speed as ``said`` (and the turn ``angular`` about the
        tool, if any), when the flange's bound at those speeds is above its cap."""
        limit = self.cap * self.settings.flange_speed_margin
        if self._flange_speed_bound(linear_mm_s, angular_deg_s) > limit:
            note = self._tool_note(angular)
            raise CommandRejected(f"{said}{note} is above the flange-speed cap {limit:.0f} mm/s; "
                                  + ("send a slower turn or linear speed" if note else "send it slower"))

    def twist(self, cmd: Twist) -> None:
        """Move the TCP at a twist (base or tool frame) until replaced, stopped or the hold runs out."""
        self._require()
        self.check_twist(cmd)
        self._leave_replay("a twist took over")
        self._cart, self._cart_active, self._ease = cmd, True, None
        self._jog, self._target, self._finishing = None, None, None
        self._pending = False  # (the IK takes the arm over as it moves: see pose_target)
        self.stopped = False

    def pose_target(self, cmd: PoseTarget) -> None:
        """Reach a TCP pose in a straight line at the command's speed caps (same configuration); the
        last millimetres of a target held still run as a joint move (:meth:`_finish_pose`)."""
        self._require()
        self.check_pose_target(cmd)

        def same(other: Twist | PoseTarget | None) -> bool:
            return (isinstance(other, PoseTarget) and other.xyzwpr == cmd.xyzwpr
                    and other.linear_speed == cmd.linear_speed and other.angular_speed == cmd.angular_speed)

        if same(self._finishing) and not self.stopped:
            return  # a stream repeating the target it is finishing (a tracker whose part stopped)
        self._leave_replay("a pose target took over")
        if not (same(self._cart) and self._cart_active):
            self._pose_held_s = 0.0
        self._finishing = None
        self._cart, self._cart_active, self._ease = cmd, True, None
        self._jog, self._target = None, None
        # The IK takes the arm over as it moves: a joint motion that was waiting for rest is replaced.
        # Left pending, a jog after this found it so, issued no stop and never steered: the shaper ran
        # on at the IK's last velocity (across the elbow boundary in test_servo_cycle_property seed 2).
        self._pending = False
        self.stopped = False

    def stop(self, fast: bool = False) -> None:
        shaper = self._require()
        self.stopped = True
        self._jog = None
        if self._replay is not None and self._replay.active:
            if not fast:  # pause along the path (the player's time-warp); resume continues it
                self._replay.pause()
                return
            self._leave_replay("a fast stop left the path")
        if self._cart_active and not fast:
            # A twist eases out along its own path (the IK follows it scaled down), else the IK brakes
            # along its line; the shaper follows. (A stop again while easing out changes nothing.)
            if isinstance(self._cart, Twist):
                self._ease = self._plan_ease(shaper, self._cart)
            elif self._cart is not None:
                self._ease = None
            self._cart = None
            return
        self._cart, self._cart_active = None, False
        self._pending = False
        self._stop_shaper(shaper, "fast" if fast else "soft")

    def resume(self) -> None:
        """Continue after a soft stop: towards the target that was interrupted, if any."""
        self.stopped = False
        if self._replay is not None and self._replay.active:
            self._replay.resume()
            return
        if self._target is not None and self.shaper is not None:
            self._start_target(self.shaper)

    # ---------------------------------------------------------------- replay
    def check_replay(self, samples: np.ndarray) -> np.ndarray:
        """The samples as a float32-valued (N, dof) array if the shape is right and every value finite;
        CommandRejected naming the first that is not.

        Only what costs next to nothing is checked here (the request is handled between two cycles:
        a 20 000-sample plan's full check took 10-25 ms, several 4 ms cycles). The planner checked
        every sample the way the servo does; as each is played the cycle checks it again: the float32
        guard, the joint ranges and held configuration, and the flange speed (``_step_replay``)."""
        self._require()
        q = np.asarray(samples)
        n = self.profile.dof
        if q.ndim != 2 or q.shape[1] != n or len(q) < 2:
            raise CommandRejected(f"joints has shape {q.shape}, expected (N >= 2, {n})")
        if q.dtype.kind not in "fiu":
            raise CommandRejected(f"joints are {q.dtype}, expected numbers (FANUC deg)")
        # Checked in float32, the plan's own type, with one pass and no float64 temporaries: 100 000
        # samples took 14 ms here through float64 (three 4.8 MB copies, their page faults and an
        # argwhere), several 4 ms cycles on a slower PC; this takes under 1 ms.
        with np.errstate(over="ignore"):  # a value past float32's range becomes inf, refused below
            q32 = q if q.dtype == np.float32 else q.astype(np.float32)
        if not np.isfinite(q32).all():
            i, a = (int(x) for x in np.argwhere(~np.isfinite(q32))[0])
            raise CommandRejected(f"joints[{i}][{a}]={q[i, a]} is not a finite number")
        return q32.astype(np.float64)

    def replay_start_mismatch(self, samples: np.ndarray) -> str:
        """Why ``samples`` cannot start now (empty if they can): the arm must be at rest at the first."""
        shaper = self._require()
        if not shaper.at_rest:
            return "the arm is moving: wait until it is at rest (GET /api/state at_rest), then send it again"
        if not np.array_equal(to_f32(samples[0]), shaper.commanded):
            return (f"the trajectory starts at {np.round(samples[0], 3).tolist()}, and the arm is at "
                    f"{np.round(shaper.commanded, 3).tolist()}: it moved since the plan; send it again")
        return ""

    def replay(self, samples: np.ndarray, ramp_steps: int) -> None:
        """Play ``samples`` (checked by :meth:`check_replay`, starting where the arm rests) one per cycle."""
        self._require()
        self._jog, self._target, self._finishing = None, None, None
        self._cart, self._cart_active = None, False
        self._pending = False
        self.stopped = False
        self.replay_error = ""
        self._replay = ReplayPlayer(samples, ramp_steps)

    @property
    def replay_player(self) -> ReplayPlayer | None:
        """The trajectory being (or last) replayed in this stream: its progress."""
        return self._replay

    def _leave_replay(self, why: str) -> None:
        if self._replay is not None and self._replay.active:
            self._replay.end()
            self.replay_error = why

    def _step_replay(self, shaper: JointShaper, player: ReplayPlayer) -> np.ndarray:
        q = player.advance()
        if player.state == PAUSED and shaper.mode != "replay":
            return shaper.step()  # paused at rest: the shaper holds the position
        # Not expected (the planner checked every sample the same way): a sample outside the ranges or
        # the held configuration, or too fast for the flange-speed cap, is not sent; the arm stops.
        why = self._replay_sample_refused(q)
        if why:
            player.end()
            self.replay_error = why
            shaper.stop("soft")
            return shaper.step()
        r, exact = shaper.follow(q)
        if not exact:  # the float32 guard changed it: leave the path, stop
            player.end()
            self.replay_error = f"sample {player.index}: the servo's limit guard changed it; stopped"
            shaper.stop("soft")
        elif player.state in (PAUSED, DONE) and not shaper.guard.v1.any() and not shaper.guard.a1.any():
            shaper.set_target(r)  # at rest on the path: the shaper holds it (and reports rest)
        return r

    def _replay_sample_refused(self, q: np.ndarray) -> str:
        """Why the replayed position ``q`` must not be sent (empty: it may): outside the joint ranges or
        the held configuration, or a flange speed above the cap's share from the last command."""
        if not self._safe(q)[0]:
            return f"sample {q.round(3).tolist()} leaves the joint ranges or the held configuration; stopped"
        if self._q_prev is not None:
            speed = flange_distance_mm(self._q_prev, q, self._j23, self._dims) / self.dt
            if speed > self.cap * self.settings.flange_speed_margin:
                return f"flange speed {speed:.0f} mm/s above the cap's share; stopped"
        return ""

    # ----------------------------------------------------------------- helpers
    def _tool_offset_mm(self) -> float:
        tool = self.settings.tool_xyzwpr
        return math.hypot(*tool[:3]) if tool else 0.0

    def _flange_speed_bound(self, linear_mm_s: float, angular_deg_s: float) -> float:
        """The most the flange can move for a TCP at ``linear_mm_s`` turning at ``angular_deg_s``: the
        controller's speed cap and Appendix B tables are the flange's, and a turn about a TCP r mm away
        swings the flange at up to |w| r on top (a 2 m tool at 90 deg/s: +3.1 m/s)."""
        return linear_mm_s + math.radians(angular_deg_s) * self._tool_offset_mm()

    def _tool_note(self, angular: float | tuple[float, ...]) -> str:
        r = self._tool_offset_mm()
        w = float(np.linalg.norm(angular))
        return f" + {w:g} deg/s about a TCP {r:.0f} mm from the flange (the flange moves up to the sum)" if r else ""

    def _stop_shaper(self, shaper: JointShaper, mode: str) -> None:
        """Time-optimal stop when its path stays in range and configuration, else along the line."""
        if shaper.at_rest:
            return
        try:
            path = shaper.stop_path(mode)  # type: ignore[arg-type]
        except ValueError:
            path = None
        if path is not None and bool(self._safe(path).all()):
            shaper.stop(mode)  # type: ignore[arg-type]  # time-optimal, and its path stays in range and configuration
            return
        # Near a boundary: stop along the joint-space line the motion was on, at a stop point checked
        # like a jog target (in range, same configuration), reached by a straight position profile.
        q, v, _ = shaper.state
        t_stop = shaper.optimal_stop_duration("soft")
        ahead = self._clip_to_range(q + v * t_stop / 2)
        shaper.set_target(q + (ahead - q) * self._config_keeping_reach(q, ahead), 1.0)

    @staticmethod
    def _redirects(shaper: JointShaper, direction: np.ndarray) -> bool:
        """True when the arm moves and ``direction`` is not the way it goes: the shaper's blend would
        curve off the straight line the new motion was checked on."""
        _, v, _ = shaper.state
        nv, nd = float(np.linalg.norm(v)), float(np.linalg.norm(direction))
        if nv < 1e-6 or shaper.at_rest:
            return False
        return nd < 1e-9 or float(np.dot(v, direction)) < 0.999 * nv * nd

    def _steer_ik(self, shaper: JointShaper, ahead: _Ahead | None = None) -> None:
        if isinstance(self._cart, PoseTarget) and self._finish_pose(shaper, self._cart):
            self._drop(ahead)
            return
        cart = self._ik_command()
        if ahead is not None and ahead.steps == self._steps and (ahead.command is cart
                                                                or _same_motion(ahead.command, cart)):
            q_f, v_f, q_m, dq_prev, res = ahead.q_f, ahead.v_f, ahead.q_m, ahead.dq_prev, ahead.result
            self.ahead_used += 1
        else:
            q_f, v_f = shaper.position_velocity()
            # The start in the model convention and what the shaper delivers, model rad/cycle (new
            # arrays each cycle: the IK may keep them).
            q_m, dq_prev = np.empty(len(q_f)), np.empty(len(q_f))
            cycle_kernels.ik_start(q_f, v_f, self._j23, self.dt, q_m, dq_prev)
            if ahead is not None:  # solved ahead for another command: from the same start again
                self.ahead_dropped += 1
                res = self.ik.step_again(q_m, cart, dq_prev=dq_prev)
            else:
                res = self.ik.step_owned(q_m, cart, dq_prev)
        while self.late_command is not None:
            # A command that arrived while the IK solved still makes this cycle's packet: the input
            # is read as late as the cycle allows, not only when the status packet arrived. The hook
            # stops offering commands once the answer would be late.
            cart = self._cart
            self.late_command()
            if self._cart is cart or not self._cart_active:
                break
            res = self.ik.step_again(q_m, self._cart, dq_prev=dq_prev)
            self.late_inputs += 1
        self.last_ik = res
        v = self._guard_ik_velocity(q_f, res.velocity, v_f, shaper)
        if self._cart is None and self._ease is None and not res.dq.any() and not v_f.any():
            self._cart_active = False  # braked to rest along the path
            shaper.stop("soft")
            return
        # The IK's line (a pose target's, a twist's, a stop braking along it): its joints change velocity
        # in proportion, or the TCP (joint motions that partly cancel) ran over its speed while the
        # shaper ramped (velocity_share_limits): a pose target's by up to 5 %, a twist's by up to 17 %
        # (14 % of its turn).
        shaper.set_velocity(v, one_profile=True, v_now=v_f)

    def _ik_command(self) -> Twist | PoseTarget | None:
        """What the IK follows this cycle: the command; while a twist's soft stop eases it out, the twist
        scaled by the ease's share (None once it has fallen to 0: the IK brakes along its last line)."""
        ease = self._ease
        if self._cart is not None or ease is None:
            return self._cart
        made = ease.scaled[0]
        if made[0] == self._steps:  # (solve_ahead's, or a late command's second look)
            return made[1]
        t = (self._steps - ease.step + 1) * self.dt  # the share the IK asks for the command it makes
        if t >= ease.share.duration:
            self._ease = None
            return None
        k = float(ease.share.at_time(t)[1][0])
        lin, ang = ease.twist.linear, ease.twist.angular
        cmd = Twist(linear=(k * lin[0], k * lin[1], k * lin[2]), angular=(k * ang[0], k * ang[1], k * ang[2]),
                    frame=ease.twist.frame, source=ease.twist.source, stamp=ease.twist.stamp)
        ease.scaled[0] = (self._steps, cmd)
        return cmd

    def _plan_ease(self, shaper: JointShaper, twist: Twist) -> _Ease | None:
        """A twist's soft stop: the twist's share falls from what the IK delivered to 0, jerk-limited at
        EASE_SHARE of the acceleration and jerk the fastest joint may use for it, and the IK follows the
        twist scaled by it along the twist's own path. None (the IK brakes along its line) at rest.

        Why: the IK's braking along its line asked ~0.7 of the velocity at once, the shaper took ~0.1 s
        to deliver it, each joint by its own profile (its acceleration was not along the change: the
        velocity-share limits did not hold), and a slow move turning fast about a long tool, its linear
        velocity the small difference of the flange's and the turn's lever arm, ran over: 5.74 mm/s
        released ran at 9.28 (+62 %). Eased out, the IK's velocity falls a little each cycle as it does
        while the twist is held, and the shaper keeps up with it."""
        res = self.last_ik
        _, v, _ = shaper.state
        share = 1.0 if res is None else min(1.0, max(0.0, float(res.scale)))
        speed = np.abs(v) / max(share, 1e-3)  # deg/s of each joint at the twist's full speed
        moving = speed > 1e-9
        _, acc, jerk = shaper.limits.scaled("soft")
        acc = np.minimum(acc, np.degrees(self.ik.acc))  # (the IK's rows: the fall within them)
        if share <= 0.0 or not moving.any():
            return None
        try:
            fall = ease_out(share, EASE_SHARE * float(np.min(acc[moving] / speed[moving])),
                            EASE_SHARE * float(np.min(jerk[moving] / speed[moving])))
        except ValueError:
            return None
        return _Ease(twist, fall, self._steps, [(-1, None)])

    def _finish_pose(self, shaper: JointShaper, cmd: PoseTarget) -> bool:
        """Within ``finish_mm`` / ``finish_deg`` of a pose target that has stayed the same for
        ``finish_after_s``: hand the rest to the shaper as a joint target (the analytical IK's solution
        in the held configuration), reached time-optimally without overshoot.

        The IK's velocity loop closes around the shaper, which follows a new velocity only after
        about acc/jerk (0.125 s here): near a fixed goal that loop hunted by +-2 mm for seconds. Over
        the last 2 mm the joint-space line and the Cartesian one differ by micrometres; a target that
        keeps moving (a tracker's stream) stays with the IK."""
        st = self.settings
        self._pose_held_s += self.dt
        if self._pose_held_s < st.finish_after_s:
            return False
        q_f = shaper.state[0]
        q_m = fanuc_deg_to_model_rad(q_f, self.profile.j23_factor)
        kin = self.ik.kin  # with the tool: pose targets are TCP poses
        goal = xyzwpr_to_matrix(cmd.xyzwpr)
        tcp = kin.fk_tcp(q_m)
        lin_mm = float(np.linalg.norm(goal[:3, 3] - tcp[:3, 3])) * 1000.0
        cos = (float(np.trace(goal[:3, :3] @ tcp[:3, :3].T)) - 1.0) / 2.0
        if lin_mm > st.finish_mm or math.degrees(math.acos(min(1.0, max(-1.0, cos)))) > st.finish_deg:
            return False
        solutions = [x.q_model_rad for x in kin.ik_tcp(goal, with_turns=True, within_limits=True, seed=q_m)
                     if x.config == self.configuration]
        if not solutions:
            return False
        q_goal = model_rad_to_fanuc_deg(min(solutions, key=lambda q: float(np.sum((q - q_m) ** 2))),
                                        self.profile.j23_factor)
        if not self._safe(q_goal)[0] or self._config_keeping_reach(q_f, q_goal) < 1.0:
            return False
        # Joint speeds at the share that keeps the flange under its cap and the TCP under the target's
        # speeds along the joint line (5 points: it is short). linear_speed / cap of the joint limits, as
        # before, ignored the tool: 1 deg about a TCP 1.5 m away swung the flange at 138 mm/s under a
        # 100 mm/s cap, the TCP at 125 mm/s for a 40 mm/s target. Once, when the finish begins.
        scale = self._cap_share(q_f, q_goal, samples=5, tcp_speeds=(cmd.linear_speed, cmd.angular_speed))
        # That share holds along the line alone: a move curved by the IK's motion across it ran each axis
        # at its own limit (3 x angular_speed, a 200 mm tool at 5 deg/s) and swung J3 out and back. Not
        # yet if the motion's turn onto the line would need more jerk than there is: the IK goes on.
        if not shaper.set_target_on_line(q_goal, scale * self._speed_scale):
            return False
        self._cart, self._cart_active = None, False
        self._target, self._finishing = (q_goal, scale), cmd
        self._cap_scale = 1.0  # (in scale already)
        return True

    def _guard_ik_velocity(self, q: np.ndarray, velocity_model: np.ndarray, v_now: np.ndarray,
                           shaper: JointShaper) -> np.ndarray:
        """The IK's joint velocity (model rad/s) in FANUC deg/s (``DifferentialIK.velocity_fanuc_deg_s``),
        cut to the largest share (whole vector, so the path keeps its direction) from which the arm can
        still stop inside the joint ranges and the held configuration; below a creep (it and the
        current ``v_now``), zero.

        A safety net under the IK's own limits: the stopping point allows for the shaper's lag in
        building up a deceleration (acc/jerk) and brakes at half the acceleration limit. Braking rows
        let the IK approach a boundary (a target out of reach) ever more slowly: below CREEP_DEG_S it
        only creeps, and the arm is held still and at rest instead.
        """
        if shaper.limits is not self._soft_for:
            self._soft_limits(shaper)
        v = self._ik_velocity  # (set_velocity copies it into ruckig's input)
        self.limit_scale = cycle_kernels.guard_ik_velocity(
            q, velocity_model, v_now, self._stop_lag, self._brake, self._j23, self._region_packed, CREEP_DEG_S,
            self._scratch, v)
        return v

    def _soft_limits(self, shaper: JointShaper) -> None:
        """The guards' view of the shaper's soft limits, derived again only when the limits change."""
        if shaper.limits is self._soft_for:
            return
        vel, acc, jerk = shaper.limits.scaled("soft")
        self._soft_vel = vel
        self._stop_lag = self.dt + float(np.max(acc / jerk))
        self._brake = 0.5 * acc
        self._soft_for = shaper.limits

    def _guard_flange_speed(self, shaper: JointShaper, q: np.ndarray) -> None:
        """Slow joint-space motion down before the flange exceeds the cap (the IK caps Cartesian speed)."""
        if self._q_prev is not None:
            self.flange_speed = flange_distance_mm(self._q_prev, q, self._j23, self._dims) / self.dt
        self._q_prev = q
        if self._cart_active or self.stopped or (self._replay is not None and self._replay.active):
            return  # (a replay's flange speed was checked with its plan)
        # Predict a few cycles ahead from the shaper's velocity: braking must start before the cap.
        _, v_f, a_f = shaper.state
        predicted = cycle_kernels.predicted_flange_speed(q, v_f, a_f, self.dt, self._j23, self._dims, self._scratch)
        limit = self.cap * self.settings.flange_speed_margin
        if predicted > limit:
            self._speed_scale = max(0.05, self._speed_scale * min(0.9, limit / predicted))
            if self._target is not None:
                shaper.set_target(self._target[0], self._cap_scale * max(0.01, self._target[1] * self._speed_scale))
        elif self._speed_scale < 1.0 and predicted < 0.7 * limit:
            self._speed_scale = min(1.0, self._speed_scale * 1.05)

    def _steer_jog(self, shaper: JointShaper, v: np.ndarray) -> None:
        self._soft_limits(shaper)
        # The target runs ahead, clipped to the ranges, cut where the line would leave the configuration.
        lo, hi = self._range_model_deg
        scale = cycle_kernels.jog_target(shaper.state[0], v, self._speed_scale * self._jog_cap, self._soft_vel,
                                         self._horizon, self._j23, lo, hi, self._region_packed, self._scratch,
                                         self._jog_goal)
        if scale <= 1e-9:
            if not shaper.at_rest and shaper.mode != "stop-soft":
                shaper.stop("soft")
            return
        shaper.set_target(self._jog_goal, min(scale, 1.0), speed_caps=self._jog_caps)

    def _safe(self, q_fanuc_deg: np.ndarray) -> np.ndarray:
        """Per row (or for one vector): inside the joint ranges and the held configuration, with margins.

        Near a configuration boundary (wrist or elbow stretched, wrist over the J1 axis, a joint at
        +-180 deg) a rounding step can change the configuration: hence the margins.
        """
        assert self._region is not None, "begin() sets the region"
        return self._region.contains(fanuc_deg_to_model_rad(q_fanuc_deg, self.profile.j23_factor))

    def _config_keeping_reach(self, q0: np.ndarray, q1: np.ndarray, samples: int = 24) -> float:
        """Share of the joint-space line q0 -> q1 along which the arm stays in range and configuration.

        Found to ~1e-4 of the line: a coarse answer would move a jog's target back and forth from one
        cycle to the next, and a target that jumps back can be overshot.
        """
        assert self._region is not None, "begin() sets the region"
        q0, q1 = np.ascontiguousarray(q0, dtype=float), np.ascontiguousarray(q1, dtype=float)
        return cycle_kernels.config_keeping_reach(q0, q1, samples, self._j23, self._region_packed, self._scratch)

    def _clip_to_range(self, q_fanuc_deg: np.ndarray) -> np.ndarray:
        lo, hi = self._range_model_deg
        out = np.empty(self.profile.dof)
        cycle_kernels.clip_to_range(np.ascontiguousarray(q_fanuc_deg, dtype=float), self._j23, lo, hi, out)
        return out

    def _require(self) -> JointShaper:
        if self.shaper is None:
            raise CommandRejected("not streaming: no motion command is accepted yet")
        return self.shaper

    def _joint_values(self, values: np.ndarray) -> np.ndarray:
        """``values`` as floats, one finite number per joint; CommandRejected naming the first that is not."""
        q = np.asarray(values, dtype=float)
        n = self.profile.dof
        if q.shape != (n,):
            raise CommandRejected(f"joints has {q.size} values, expected {n}")
        bad = np.flatnonzero(~np.isfinite(q))
        if bad.size:
            raise CommandRejected(f"joints[{bad[0]}]={q[bad[0]]} is not a finite number")
        return q

    def _checked_position(self, q_fanuc_deg: np.ndarray) -> np.ndarray:
        q = self._joint_values(q_fanuc_deg)
        q_model = np.degrees(fanuc_deg_to_model_rad(q, self.profile.j23_factor))
        lo, hi = self._range_model_deg
        out = np.flatnonzero((q_model < lo) | (q_model > hi))
        if out.size:
            i = out[0]
            raise CommandRejected(
                f"joints[{i}]={_deg(q[i])} deg (J{i + 1} = {_deg(q_model[i])} deg in model convention) is outside "
                f"the joint range [{lo[i]:.1f}, {hi[i]:.1f}]; send a value within the range"
            )
        return q
