"""Jerk-limited per-cycle joint shaper, in the controller's joint convention (FANUC degrees).

Every cycle ``JointShaper.step()`` returns the next joint position to send. The controller checks
the finite differences of the positions it receives over the fixed interval (manual 61.5 note 2,
FAQ: positions before the first packet equal the first), so that is the quantity guaranteed here:
for the float32-rounded outputs q_k,

    v_k = (q_k - q_{k-1}) / dt,  a_k = (v_k - v_{k-1}) / dt,  j_k = (a_k - a_{k-1}) / dt

stay within ``fraction`` x the given limits (``fast_fraction`` x during a fast stop), as long as
|q| stays within ``ShaperLimits.pos_abs_max`` (it sizes the float32 margins; the shaper has no joint
limits of its own, the callers keep targets and jogs inside the joint ranges).

Two layers:

1. Planning: ruckig (time-optimal, jerk-limited) from the internal continuous state. Sampling a C2
   curve whose |v|, |a|, |j| stay below bounds gives finite differences that are weighted averages of
   the continuous values (box, triangle and quadratic B-spline kernels), so they stay below the same
   bounds, also across target switches (ruckig continues from the sampled state, which keeps the
   curve C2). Rounding each sample to float32 adds at most h = ulp/2 per sample, i.e. at most
   2h/dt, 4h/dt^2, 8h/dt^3 to v, a, j: ruckig gets the limits minus these margins.
2. Guard: checks the float32 candidate exactly as the controller computes it, plus a discrete
   braking condition (the velocity can still be kept within the limit with jerk-limited
   deceleration of the acceleration). If a candidate fails (limits lowered mid-motion, the switch
   back from a fast stop, a ruckig failure, |q| beyond ``pos_abs_max``), it picks the nearest
   float32 that passes and re-seeds ruckig on the parabola through the last three outputs. Within the
   contract it never intervenes (``guard.interventions`` counts when it does).

Position moves from rest (or along the current line of motion) follow the straight line in joint
space: each axis gets its limits scaled to its share of the displacement, so all axes run one
profile, scaled (ruckig's phase synchronization alone falls back to curved time-synchronized
profiles whenever the straight one is not time-optimal).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
    Trajectory,
)

from servo_app.motion.ik_kernels import any_nonzero2
from servo_app.motion.limit_tables import LimitTables
from servo_app.motion.shaper_kernels import emit_if_passes, line_limits, velocity_share_limits, velocity_within
from servo_app.motion.stops import STOP_MODES, StopMode, stop_path, time_optimal_stop_duration

ArrayLike = Sequence[float] | np.ndarray

_PLAN_TOL = 1e-6  # relative slack for ruckig's own numerical tolerance on its limits
_CHECK_TOL = 1e-9  # the guard aims this far inside the limits so its choice survives re-evaluation
_REST_TOL = 1e-9  # deg/s, deg/s^2: internal state counts as at rest
_BISECT_ITERS = 52  # interval of ~J dt^3 down to float64 resolution
_NO_CHANGE = {n: np.zeros(n, dtype=bool) for n in range(1, 10)}


def to_f32(x: ArrayLike) -> np.ndarray:
    """Round to the wire format (float32), returned as float64 holding exactly those values."""
    return np.asarray(x, dtype=np.float64).astype(np.float32).astype(np.float64)


def _arr(x: ArrayLike | float, n: int | None = None) -> np.ndarray:
    a = np.array(x, dtype=np.float64, ndmin=1)
    if n is not None and a.shape == (1,) and n != 1:
        a = np.full(n, a[0])
    return a


@dataclass(frozen=True)
class ShaperLimits:
    """Per-axis controller limits (deg/s, deg/s^2, deg/s^3) and the share of them the shaper may use.

    ``fraction`` scales the limits for normal motion and soft stops, ``fast_fraction`` for fast stops.
    ``pos_abs_max`` (deg, scalar or per axis) bounds |position|: it sizes the float32 rounding margin.
    """

    vel: np.ndarray
    acc: np.ndarray
    jerk: np.ndarray
    fraction: float = 0.9
    fast_fraction: float = 0.99
    pos_abs_max: np.ndarray | float = 360.0  # stored as a per-axis array

    def __post_init__(self) -> None:
        vel, acc, jerk = _arr(self.vel), _arr(self.acc), _arr(self.jerk)
        if not (vel.shape == acc.shape == jerk.shape) or vel.ndim != 1:
            raise ValueError(f"vel/acc/jerk shapes differ: {vel.shape} {acc.shape} {jerk.shape}")
        for name, a in (("vel", vel), ("acc", acc), ("jerk", jerk)):
            if not np.isfinite(a).all() or (a <= 0).any():
                raise ValueError(f"{name} limits must be finite and positive, got {a}")
        if not 0.0 < self.fraction <= self.fast_fraction <= 1.0:
            raise ValueError(f"need 0 < fraction <= fast_fraction <= 1, got {self.fraction}, {self.fast_fraction}")
        pmax = _arr(self.pos_abs_max, len(vel))
        if pmax.shape != vel.shape or (pmax <= 0).any():
            raise ValueError(f"pos_abs_max must be positive, one per axis or scalar, got {self.pos_abs_max}")
        object.__setattr__(self, "vel", vel)
        object.__setattr__(self, "acc", acc)
        object.__setattr__(self, "jerk", jerk)
        object.__setattr__(self, "pos_abs_max", pmax)

    @property
    def n_axes(self) -> int:
        return len(self.vel)

    def scaled(self, mode: StopMode = "soft") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vel, acc, jerk) the emitted finite differences never exceed: ``soft`` (normal) or ``fast``."""
        f = self.fraction if mode == "soft" else self.fast_fraction
        return self.vel * f, self.acc * f, self.jerk * f

    @classmethod
    def from_tables(cls, tables: LimitTables, flange_speed_cap: float, payload_kg: float | None = None,
                    **kwargs: float) -> ShaperLimits:
        """From ``LimitTables.for_cap`` (limits valid at every flange speed up to the cap)."""
        vel, acc, jerk = tables.for_cap(flange_speed_cap, payload_kg)
        return cls(vel, acc, jerk, **kwargs)


@dataclass(frozen=True)
class Envelope:
    """One set of limits resolved for a cycle time: what is checked, what the guard brakes with,
    what ruckig plans with."""

    vel: np.ndarray  # checked: never exceeded by the emitted finite differences
    acc: np.ndarray
    jerk: np.ndarray
    brake_vel: np.ndarray  # the guard's braking model keeps future velocity within this ...
    brake_jerk: np.ndarray  # ... decelerating the acceleration at this jerk
    plan_vel: np.ndarray  # given to ruckig
    plan_acc: np.ndarray
    plan_jerk: np.ndarray
    # rows (vel, acc, jerk, brake_vel, brake_jerk * dt), per axis: the per-cycle check's table
    table: np.ndarray = field(repr=False, compare=False)

    @classmethod
    def build(cls, vel: np.ndarray, acc: np.ndarray, jerk: np.ndarray, pos_abs_max: np.ndarray,
              dt: float) -> Envelope:
        h = np.spacing(pos_abs_max.astype(np.float32)).astype(np.float64) / 2.0  # max f32 rounding error
        nv, na, nj = 2.0 * h / dt, 4.0 * h / dt**2, 8.0 * h / dt**3  # its effect on v, a, j
        brake_vel, brake_jerk = vel - nv, jerk - nj
        plan_jerk = brake_jerk * (1.0 - _PLAN_TOL)
        plan_acc = (acc - na) * (1.0 - _PLAN_TOL)
        # A rounded state's braking peak exceeds the exact one by at most nv + na * (a / J) <= ...
        plan_vel = (brake_vel - nv - na * (acc / np.maximum(brake_jerk, 1e-300) + dt)) * (1.0 - _PLAN_TOL)
        if (plan_vel <= 0).any() or (plan_acc <= 0).any() or (plan_jerk <= 0).any():
            raise ValueError("float32 rounding at this position range and dt leaves no room within the "
                             f"limits (vel {vel}, acc {acc}, jerk {jerk}, dt {dt}, |q| <= {pos_abs_max})")
        table = np.array([vel, acc, jerk, brake_vel, brake_jerk * dt], dtype=np.float64)
        return cls(vel, acc, jerk, brake_vel, brake_jerk, plan_vel, plan_acc, plan_jerk, table)


def _brake_peaks(v: np.ndarray, a: np.ndarray, brake_jerk: np.ndarray, dt: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Extreme future discrete velocity when |a| is ramped to zero at ``brake_jerk`` (the fastest
    way, so the least overshoot): (highest if a > 0 else v, lowest if a < 0 else v).

    With c = brake_jerk * dt the acceleration falls by c per cycle, n = floor(|a| / c) cycles keep
    its sign, adding dt * sum_{i=1..n} (|a| - i c) = dt * (n |a| - c n (n + 1) / 2) of velocity.
    """
    c = brake_jerk * dt
    n = np.floor(np.abs(a) / c)
    peak = v + dt * (n * a - np.copysign(c * n * (n + 1.0) / 2.0, a))
    return np.maximum(peak, v), np.minimum(peak, v)


class DiscreteGuard:
    """The emitted float32 history and the controller's finite-difference check on it.

    The per-cycle check and commit is one compiled kernel (:func:`~servo_app.motion.shaper_kernels.emit_if_passes`,
    the same IEEE arithmetic as numpy); numpy is used only on the rare slow path.
    """

    def __init__(self, dt: float, q0: ArrayLike) -> None:
        self.dt = float(dt)
        self.interventions = 0  # cycles where the candidate was replaced
        self.relaxed = 0  # axis-cycles that met the limits but not the braking reserve (|q| beyond range)
        self.failures = 0  # axis-cycles where no float32 met the limits (best effort was sent)
        self.reset(q0)

    def reset(self, q: ArrayLike) -> None:
        """At rest at ``q``: every earlier position equals it."""
        self._s = np.ascontiguousarray(to_f32(q))
        self._v = np.zeros(len(self._s))
        self._a = np.zeros(len(self._s))
        self._no_change = _NO_CHANGE[len(self._s)]  # filter's mask when it changed nothing

    @property
    def s1(self) -> np.ndarray:
        """Last emitted position (float32 values)."""
        return self._s.copy()

    @property
    def v1(self) -> np.ndarray:
        """Last finite-difference velocity."""
        return self._v.copy()

    @property
    def a1(self) -> np.ndarray:
        """Last finite-difference acceleration."""
        return self._a.copy()

    def differences(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(v, a, j) of emitting ``r`` next, computed exactly as the controller does."""
        v = (r - self.s1) / self.dt
        a = (v - self.v1) / self.dt
        return v, a, (a - self.a1) / self.dt

    def passes(self, r: np.ndarray, env: Envelope) -> np.ndarray:
        """Per axis: emitting ``r`` keeps v, a, j within ``env`` and leaves a braking-feasible state."""
        v, a, j = self.differences(r)
        up, down = _brake_peaks(v, a, env.brake_jerk, self.dt)
        return ((np.abs(v) <= env.vel) & (np.abs(a) <= env.acc) & (np.abs(j) <= env.jerk)
                & (up <= env.brake_vel) & (down >= -env.brake_vel))

    def passes_hard(self, r: np.ndarray, env: Envelope) -> np.ndarray:
        """Per axis: v, a, j of emitting ``r`` within ``env`` (the controller's check alone)."""
        v, a, j = self.differences(r)
        return (np.abs(v) <= env.vel) & (np.abs(a) <= env.acc) & (np.abs(j) <= env.jerk)

    def state_feasible(self, env: Envelope) -> bool:
        """Is the current (v, a) within ``env`` with a feasible braking future? (for switching limits)"""
        up, down = _brake_peaks(self.v1, self.a1, env.brake_jerk, self.dt)
        return bool(((np.abs(self.v1) <= env.vel) & (np.abs(self.a1) <= env.acc)
                     & (up <= env.brake_vel) & (down >= -env.brake_vel)).all())

    def brake_candidate(self, env: Envelope) -> np.ndarray:
        """Next position of a jerk-limited deceleration to rest per axis, from the emitted state: steer
        the acceleration towards the one that, ramped out at the braking jerk, ends at zero velocity."""
        dt, v, a = self.dt, self.v1, self.a1
        a_goal = -np.sign(v) * np.minimum(np.sqrt(2.0 * env.brake_jerk * np.abs(v)), env.acc * 0.99)
        a_next = a + np.clip(a_goal - a, -env.brake_jerk * dt, env.brake_jerk * dt)
        return self.s1 + dt * (v + dt * a_next)

    def commit(self, r: ArrayLike) -> None:
        """Emit ``r`` (float32 values): the controller's finite differences move on."""
        r = np.array(r, dtype=np.float64)
        v = (r - self._s) / self.dt
        self._a = (v - self._v) / self.dt
        self._s, self._v = r, v

    def filter(self, candidate: ArrayLike, env: Envelope) -> tuple[np.ndarray, np.ndarray]:
        """The float32 position to emit for ``candidate`` and the mask of axes that were changed."""
        # The candidate as a new array, rounded to float32 in place by the kernel: the position sent
        # (the caller keeps it), one numpy call where a conversion, a scratch array and its copy were.
        r = np.array(candidate, dtype=np.float64)
        if emit_if_passes(r, self._s, self._v, self._a, env.table, self.dt, r):
            return r, self._no_change
        ok = self.passes(r, env)
        if ok.all():  # the fast check is the stricter one only by rounding; trust the reference
            self.commit(r)
            return r, ~ok
        self.interventions += 1
        bad = np.flatnonzero(~ok)
        lo, hi = self._interval(bad, env)
        cand = np.asarray(candidate, dtype=np.float64)
        for k, i in enumerate(bad):
            r[i] = self._pick(int(i), float(np.clip(cand[i], lo[k], hi[k])), env)
        self.commit(r.tolist())
        return r, ~ok

    # -- slow path -------------------------------------------------------------------------------

    def _interval(self, idx: np.ndarray, env: Envelope) -> tuple[np.ndarray, np.ndarray]:
        """Positions the axes ``idx`` may take next: linear v/a/j bounds, then the braking bounds."""
        dt, s1, v1, a1 = self.dt, self.s1[idx], self.v1[idx], self.a1[idx]
        V, A, J = (x[idx] * (1.0 - _CHECK_TOL) for x in (env.vel, env.acc, env.jerk))
        # inverse of the difference formulas: x = s - s1 for a given v, a or j
        lo = np.maximum.reduce([dt * (v1 + dt * (a1 - dt * J)), dt * (v1 - dt * A), -dt * V])
        hi = np.minimum.reduce([dt * (v1 + dt * (a1 + dt * J)), dt * (v1 + dt * A), dt * V])
        vb, jb = env.brake_vel[idx] * (1.0 - _CHECK_TOL), env.brake_jerk[idx]

        def peaks(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            v = x / dt
            return _brake_peaks(v, (v - v1) / dt, jb, dt)

        # both peaks increase with x: bisect for the largest x with up <= vb, smallest with down >= -vb
        a, b = lo.copy(), hi.copy()
        need = peaks(b)[0] > vb
        for _ in range(_BISECT_ITERS if need.any() else 0):
            mid = (a + b) / 2.0
            good = peaks(mid)[0] <= vb
            a, b = np.where(good, mid, a), np.where(good, b, mid)
        hi = np.where(need, a, hi)
        a, b = lo.copy(), hi.copy()
        need = peaks(a)[1] < -vb
        for _ in range(_BISECT_ITERS if need.any() else 0):
            mid = (a + b) / 2.0
            good = peaks(mid)[1] >= -vb
            a, b = np.where(good, a, mid), np.where(good, mid, b)
        lo = np.where(need, b, lo)
        return s1 + lo, s1 + np.maximum(hi, lo)

    def _pick(self, i: int, target: float, env: Envelope) -> float:
        """Nearest float32 to ``target`` that passes on axis ``i`` (checked the controller's way)."""
        probe = self.s1.copy()

        def first_passing(options: list[np.float32], check: object) -> float | None:
            for x in options:
                probe[i] = float(x)
                if check(probe, env)[i]:  # type: ignore[operator]
                    return float(x)
            return None

        found = first_passing(_f32_around(target, 1), self.passes)
        if found is not None:
            return found
        # Only when the float32 grid is coarser than the margins (|q| beyond ``pos_abs_max``): keep the
        # controller's limits this cycle, as close as possible to ramping the acceleration to zero.
        self.relaxed += 1
        c = env.brake_jerk[i] * self.dt
        a = self.a1[i] - float(np.clip(self.a1[i], -c, c))
        brake = float(self.s1[i] + self.dt * (self.v1[i] + self.dt * a))
        found = first_passing(_f32_around(brake, 3), self.passes_hard)
        if found is not None:
            return found
        self.failures += 1
        return float(np.float32(brake))


def _f32_around(x: float, k: int) -> list[np.float32]:
    """The float32 values within ``k`` steps of ``x``, nearest first."""
    f = np.float32(x)
    out = [f]
    lo = hi = f
    for _ in range(k):
        lo, hi = np.nextafter(lo, np.float32(-np.inf)), np.nextafter(hi, np.float32(np.inf))
        out += [lo, hi]
    out.sort(key=lambda y: abs(float(y) - x))
    return out


class JointShaper:
    """Jerk-limited joint shaper: one ``step()`` per controller cycle, pure (no I/O, no threads).

    Commands (each replaces the previous one, any time, also mid-stop):
    ``set_target(q)`` a position (axes synchronized in phase: straight line in joint space whenever
    the start state allows, else time-synchronized), ``set_velocity(v)`` a joint velocity (jogging,
    teleop), ``stop(mode)`` a time-optimal deceleration to rest.
    """

    def __init__(self, limits: ShaperLimits, dt: float, q0: ArrayLike) -> None:
        if not dt > 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.dt = float(dt)
        self.n = limits.n_axes
        self._otg = Ruckig(self.n, self.dt)
        self._inp = InputParameter(self.n)
        self._out = OutputParameter(self.n)
        zeros = [0.0] * self.n
        self._inp.target_velocity = zeros
        self._inp.target_acceleration = zeros
        self.guard = DiscreteGuard(self.dt, np.zeros(self.n))
        self.planning_errors = 0  # ruckig failures answered by a fallback plan
        self.last_planning_error = ""  # ruckig's message with its input, for the log
        self._plan_mode: StopMode = "soft"
        self._vel_scale = 1.0
        self._mode = "position"
        self._target_key: tuple[list[float], float, bool] | None = None
        self._finished = True  # the last ruckig update reached its target and no command came since
        self._env = self._envelopes(limits)
        self.limits = limits
        self._guard_env = self._wanted_guard = self._env["soft"]  # guard: enforced now / to adopt
        # The plain limits ruckig has (see _apply_plan_limits).
        self._applied_plan: tuple[Envelope | None, float] | None = None
        self._line_limits = np.empty((3, self.n))  # scratch of _apply_line_limits and set_velocity
        # _applied_plan while ruckig has set_velocity's share limits (one_profile): no plan's, so the
        # next plain plan gives ruckig its limits again.
        self._share_plan = (None, 0.0)
        self._within = np.empty(self.n)  # scratch of set_velocity
        self._aim = np.empty(self.n)  # set_velocity's velocity for ruckig this cycle (velocity_share_limits)
        self._no_change = _NO_CHANGE[self.n]  # the guard's mask when it changed nothing
        self._target_still = True  # ruckig's target velocity is zero (what _settle asks)
        self._speed_caps: np.ndarray | None = None  # set_target's, for _apply_line_limits
        self.set_limits(limits)
        self.reseed(q0)

    # -- configuration ---------------------------------------------------------------------------

    def set_limits(self, limits: ShaperLimits) -> None:
        """New limits (e.g. another flange-speed cap). Planning uses them at once; the guard keeps the
        previous ones until the state fits the new ones (ruckig brakes into them)."""
        if limits.n_axes != self.n:
            raise ValueError(f"limits have {limits.n_axes} axes, shaper has {self.n}")
        if limits is not self.limits:  # (the constructor built the envelopes of its limits already)
            self._env = self._envelopes(limits)
        self.limits = limits
        self._wanted_guard = self._env[self._plan_mode]
        straight = self._mode == "position" and self._target_key is not None and self._target_key[2]
        self._applied_plan = None
        if straight:
            self._apply_line_limits(np.array(self._inp.target_position))
        else:
            self._apply_plan_limits()
        self._try_switch_guard()

    def _envelopes(self, limits: ShaperLimits) -> dict[str, Envelope]:
        return {m: Envelope.build(*limits.scaled(m), limits.pos_abs_max, self.dt)  # type: ignore[arg-type]
                for m in STOP_MODES}

    def reseed(self, q: ArrayLike) -> None:
        """Restart at rest at a commanded position (never the measured servo position).

        The first ``step()`` afterwards returns ``q`` itself (as float32): the controller assumes
        positions before the first packet equal the first, so the first packet must be the rest
        position for its finite differences to match ours.
        """
        q = to_f32(_arr(q))
        if q.shape != (self.n,):
            raise ValueError(f"expected {self.n} joint values, got {q.shape}")
        self._otg.reset()
        self._inp.current_position = q.tolist()
        self._inp.current_velocity = [0.0] * self.n
        self._inp.current_acceleration = [0.0] * self.n
        self.guard.reset(q)
        self._hold_first = True
        self._plan_mode = "soft"
        self._wanted_guard = self._guard_env = self._env["soft"]
        self._vel_scale = 1.0
        self._apply_plan_limits()
        self._set_position_mode(q)
        self._target_key = None
        self._finished = True

    # -- commands --------------------------------------------------------------------------------

    def set_target(self, q: ArrayLike, max_vel_scale: float = 1.0, straight: bool = True,
                   speed_caps: np.ndarray | None = None) -> None:
        """Move to joint position ``q`` (deg), at most ``max_vel_scale`` x the velocity limit.

        ``straight``: from rest, or from a motion along the same line, the path is the straight line in
        joint space (the time-optimal one along it); otherwise ruckig's phase synchronization, which
        the community edition drops for time synchronization (a curved path) whenever a straight
        profile is not the time-optimal one. ``speed_caps`` (deg/s, positive, per axis; inf: none): no
        axis faster off the line either (a jog's asked speeds; along the line the caller's scale keeps
        them), where time synchronization gives every axis its whole limit.
        """
        q = _arr(q)
        if q.shape != (self.n,) or not np.isfinite(q).all():
            raise ValueError(f"expected {self.n} finite joint values, got {q}")
        if not 0.0 < max_vel_scale <= 1.0:
            raise ValueError(f"max_vel_scale must be in (0, 1], got {max_vel_scale}")
        key = (q.tolist(), max_vel_scale, straight)
        if self._mode == "position" and key == self._target_key and self._plan_mode == "soft":
            return  # re-sent every cycle by a streaming caller: nothing changes, ruckig keeps its plan
        self._target_key = key
        self._speed_caps = speed_caps
        self._select_plan("soft", max_vel_scale, apply=not straight)
        if straight:
            self._apply_line_limits(q)
        self._set_position_mode(q)

    def set_target_on_line(self, q: ArrayLike, max_vel_scale: float = 1.0) -> bool:
        """:meth:`set_target` along the straight joint line from here to ``q``, also from a motion only
        nearly along it: the state's velocity and acceleration across the line are dropped, if the
        positions then sent pass the guard as they are. False if they would not: the motion it was in
        goes on (its target again).

        ruckig keeps a move straight only from a state exactly along the line; else its time
        synchronization curves it, each axis at its own limits rather than its share of the line's
        (the TCP faster than the speeds the line was scaled for), and an axis with almost nothing to
        cover can go out and back. A motion handed over by the differential IK is along the line to
        ~1e-5 at best. Dropping (dv, da) shifts the next positions by k dv dt + (k dt)^2 da / 2 from a
        history that had them, a step in the finite differences the guard would have to correct (and
        its re-seed is off the line again): so the first three positions of the new plan (after them
        the differences are the new plan's alone) are checked exactly as the guard will check them.
        """
        q = _arr(q)
        p, v, a = self.state
        d = q - p
        if q.shape != (self.n,) or not np.isfinite(q).all() or float(np.max(np.abs(d))) < 1e-6:
            self.set_target(q, max_vel_scale)  # (its errors; nothing to keep straight)
            return True
        # An axis with (numerically) nothing to cover (as line_limits counts it) is put on its target at
        # rest: ruckig checks the line on all of them, and 1e-15 deg/s there against a 1e-16 deg move
        # was enough for its time synchronization (J1 and J4 out by 0.15 deg and back at full acceleration).
        still = np.abs(d) < 1e-9 * float(np.max(np.abs(d)))
        d[still] = 0.0
        u = d / float(np.linalg.norm(d))
        before = (self._inp.current_position, self._inp.current_velocity, self._inp.current_acceleration)
        mode, key, caps = self._mode, self._target_key, self._speed_caps
        target_v = np.array(self._inp.target_velocity)
        self._inp.current_position = np.where(still, q, p).tolist()
        self._inp.current_velocity = (u * float(v @ u)).tolist()
        self._inp.current_acceleration = (u * float(a @ u)).tolist()
        self._target_key = None  # (plan again even if the target is the same)
        self.set_target(q, max_vel_scale)
        if self._passes_first_cycles():
            return True
        self._inp.current_position, self._inp.current_velocity, self._inp.current_acceleration = before
        self._target_key = None
        if mode == "position" and key is not None:  # the motion it was in goes on
            self.set_target(np.array(key[0]), key[1], key[2], caps)
        elif mode.startswith("stop-"):
            self.stop(mode.removeprefix("stop-"))  # type: ignore[arg-type]
        else:
            self.set_velocity(target_v)
        return False

    def _passes_first_cycles(self, cycles: int = 3) -> bool:
        """Would the guard pass the next ``cycles`` positions of ruckig's plan from its input unchanged?"""
        traj = Trajectory(self.n)
        try:
            if self._otg.calculate(self._inp, traj) not in (Result.Working, Result.Finished):
                return False
        except RuckigError:
            return False
        g = DiscreteGuard(self.dt, self.guard.s1)
        g._s, g._v, g._a = self.guard.s1, self.guard.v1, self.guard.a1
        env = self._guard_env
        for k in range(1, cycles + 1):
            r = to_f32(traj.at_time(min(k * self.dt, traj.duration))[0])
            if not g.passes(r, env).all():
                return False
            g.commit(r)
        return True

    def set_velocity(self, v: ArrayLike, one_profile: bool = False, v_now: np.ndarray | None = None) -> None:
        """Reach joint velocity ``v`` (deg/s) jerk-limited; above the limit all axes are scaled by one
        factor, which keeps the direction. ``one_profile``: while the acceleration is along the change,
        the axes change velocity in proportion (:func:`velocity_share_limits`), the joint velocity on
        the straight line from the present one to ``v``; ``v_now``: the present velocity, if the caller
        has it from :meth:`position_velocity` this cycle (saves reading it again)."""
        v = np.ascontiguousarray(v, dtype=np.float64)  # (not kept: no copy)
        within = self._within
        soft = self._env["soft"]
        if v.shape != (self.n,) or velocity_within(v, soft.plan_vel, within) < 0.0:
            raise ValueError(f"expected {self.n} finite joint velocities, got {v}")
        applied = self._applied_plan
        inp = self._inp
        lim = self._line_limits
        if one_profile and self._plan_mode == "soft" and velocity_share_limits(
                np.asarray(inp.current_velocity) if v_now is None else v_now, np.asarray(inp.current_acceleration),
                within, soft.plan_vel, soft.plan_acc, soft.plan_jerk, lim, self._aim):
            if applied is not self._share_plan:  # (the velocity limits are the plan's: set once)
                inp.max_velocity = soft.plan_vel.tolist()
                self._applied_plan = applied = self._share_plan
            inp.max_acceleration, inp.max_jerk = lim[1].tolist(), lim[2].tolist()
            self._vel_scale = 1.0
            within = self._aim  # (at a turn: the velocity its acceleration ends at; the target from there)
        elif (self._plan_mode == "soft" and applied is not None and applied[0] is soft and applied[1] == 1.0):
            # A velocity stream (a Cartesian jog: every cycle): ruckig has the plan's limits already.
            # What _select_plan comes to then, without its call and _apply_plan_limits' (each Python
            # layer costs ~0.5 us with caches cold after the wait).
            self._vel_scale = 1.0
        else:
            self._select_plan("soft", 1.0)
        self._set_velocity_mode(within, "velocity")

    def stop(self, mode: StopMode = "soft") -> None:
        """Decelerate to rest, time-optimally: ``soft`` within the normal limits, ``fast`` within the
        full limits (``fast_fraction``). Any later command resumes motion."""
        if mode not in STOP_MODES:
            raise ValueError(f"stop mode must be one of {STOP_MODES}, got {mode!r}")
        self._select_plan(mode, 1.0)
        self._set_velocity_mode(np.zeros(self.n), f"stop-{mode}")

    def follow(self, q: ArrayLike) -> tuple[np.ndarray, bool]:
        """Emit a precomputed, pre-checked position (trajectory replay) through the guard, and continue
        ruckig from what was emitted (the parabola through the last three outputs): a stop or another
        command afterwards starts from the true q, v, a. Returns the position sent and whether it was
        sent unchanged (False: the guard had to replace it; the caller should leave the replay)."""
        self._hold_first = False
        self._try_switch_guard()
        r, changed = self.guard.filter(np.ascontiguousarray(q, dtype=np.float64), self._guard_env)
        self._resync(np.ones(self.n, dtype=bool))
        self._mode = "replay"
        self._target_key = None
        self._finished = False
        return r, not (changed is not _NO_CHANGE[self.n] and changed.any())

    # -- the cycle -------------------------------------------------------------------------------

    def step(self) -> np.ndarray:
        """Advance one cycle; the joint position (deg) to send, as float64 holding float32 values."""
        if self._hold_first:
            self._hold_first = False
            r = self.guard.s1
            self.guard.commit(r.tolist())
            return r
        if self._guard_env is not self._wanted_guard:  # (_try_switch_guard's own test, without the call)
            self._try_switch_guard()
        # Ruckig's next position (its fallbacks in _replan, not expected).
        candidate = self._out.new_position if self._update() else self._replan()
        if candidate is None:
            # Last resort: a discrete braking step of our own (the guard still checks it); ruckig
            # restarts from the emitted state next cycle.
            r, _ = self.guard.filter(self.guard.brake_candidate(self._guard_env), self._guard_env)
            self._resync(np.ones(self.n, dtype=bool))
            self._finished = False
            return r
        r, changed = self.guard.filter(candidate, self._guard_env)
        self._out.pass_to_input(self._inp)
        if changed is not self._no_change and changed.any():
            self._resync(changed)
        elif self._finished and self._target_still:  # (_settle's own first test: a jog never calls it)
            self._settle()
        return r

    # -- observers -------------------------------------------------------------------------------

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Internal continuous (position, velocity, acceleration) the next cycle starts from."""
        return (np.asarray(self._inp.current_position), np.asarray(self._inp.current_velocity),
                np.asarray(self._inp.current_acceleration))

    def position_velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """``state``'s position and velocity alone (the IK's start each Cartesian cycle)."""
        inp = self._inp
        return np.asarray(inp.current_position), np.asarray(inp.current_velocity)

    @property
    def commanded(self) -> np.ndarray:
        """The last position emitted (float32 values): the one to re-seed from."""
        return self.guard.s1.copy()

    @property
    def at_rest(self) -> bool:
        """Not moving, as the controller sees it (the last three positions equal) and internally, and
        no command pending."""
        # The same terms, cheapest first and on the guard's own arrays (no copies): a moving arm fails on
        # the first two, ~2 us here where the whole test took 13 us (the servo process asks every publish).
        g = self.guard
        if not self._finished or any_nonzero2(g._v, g._a):  # nonzero or NaN, as "== 0.0" fails them
            return False
        p, v, a = self.state
        return bool(np.array_equal(g._s, to_f32(p)) and (np.abs(v) <= _REST_TOL).all()
                    and (np.abs(a) <= _REST_TOL).all())

    @property
    def mode(self) -> str:
        """"position", "velocity", "stop-soft", "stop-fast" or "replay" (:meth:`follow`)."""
        return self._mode

    @property
    def active_limits(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vel, acc, jerk) the guard enforces this cycle (the previous limits while braking into new
        ones, the fast limits during a fast stop)."""
        e = self._guard_env
        return e.vel, e.acc, e.jerk

    def envelope(self, mode: StopMode = "soft") -> Envelope:
        """The limits of ``mode`` resolved for this cycle time (what the guard checks in that mode)."""
        return self._env[mode]

    def check_limits(self, mode: StopMode = "soft") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vel, acc, jerk) the emitted finite differences respect in ``mode``."""
        e = self._env[mode]
        return e.vel, e.acc, e.jerk

    def remaining_duration(self) -> float:
        """Time (s) until the current ruckig profile ends (0 when finished)."""
        return max(float(self._out.trajectory.duration - self._out.time), 0.0)

    def stop_path(self, mode: StopMode = "soft", samples: int = 16) -> np.ndarray:
        """Where ``stop(mode)`` would take the axes from the current state: ``samples`` positions."""
        e = self._env[mode]
        p, v, a = self.state
        return stop_path(p, v, a, e.plan_vel, e.plan_acc, e.plan_jerk, samples)

    def optimal_stop_duration(self, mode: StopMode = "soft", planned: bool = False) -> float:
        """Theoretical time-optimal stop time (s) from the current state: ruckig's profile to zero
        velocity, axes independent, within ``mode``'s checked limits (the benchmark reference), or with
        ``planned`` within the limits ruckig is actually given (checked minus the float32 margins),
        which the stop meets to the cycle."""
        e = self._env[mode]
        p, v, a = self.state
        if planned:
            return time_optimal_stop_duration(p, v, a, e.plan_vel, e.plan_acc, e.plan_jerk)
        return time_optimal_stop_duration(p, v, a, e.vel, e.acc, e.jerk)

    # -- internals -------------------------------------------------------------------------------

    def _select_plan(self, mode: StopMode, vel_scale: float, apply: bool = True) -> None:
        """Plan in ``mode`` at ``vel_scale``; ``apply=False``: the caller gives ruckig the limits."""
        if mode != self._plan_mode:
            self._plan_mode = mode
            self._wanted_guard = self._env[mode]
            self._try_switch_guard()
        self._vel_scale = vel_scale
        if apply:
            self._apply_plan_limits()

    def _apply_plan_limits(self) -> None:
        """Give ruckig the mode's planning limits (velocity scaled by the plan's share), unless it has
        them already: a velocity stream (teleop) asks for the same ones every cycle."""
        e = self._env[self._plan_mode]
        applied = self._applied_plan
        if applied is not None and applied[0] is e and applied[1] == self._vel_scale:
            return
        self._inp.max_velocity = (e.plan_vel * self._vel_scale).tolist()
        self._inp.max_acceleration, self._inp.max_jerk = e.plan_acc.tolist(), e.plan_jerk.tolist()
        self._applied_plan = (e, self._vel_scale)

    def _apply_line_limits(self, q: np.ndarray) -> None:
        """Give ruckig the planning limits for a move to ``q``: along the straight line in joint space
        when the state allows one (at rest, or velocity and acceleration along the displacement),
        scaled so that every axis has the same limits relative to its displacement. The per-axis
        profiles are then one profile scaled, a straight line, and the slowest axis' limits still
        bind. Else the mode's plain limits."""
        e = self._env[self._plan_mode]
        p, v, a = self.state
        lim = self._line_limits
        if not line_limits(p, v, a, np.ascontiguousarray(q, dtype=np.float64), e.plan_vel, e.plan_acc,
                           e.plan_jerk, self._vel_scale, lim) and self._speed_caps is not None:
            np.minimum(lim[0], self._speed_caps, out=lim[0])
        self._inp.max_velocity, self._inp.max_acceleration, self._inp.max_jerk = lim.tolist()
        self._applied_plan = None

    def _set_position_mode(self, q: np.ndarray) -> None:
        self._mode = "position"
        self._inp.control_interface = ControlInterface.Position
        self._inp.synchronization = Synchronization.Phase  # falls back to Time when not possible
        self._inp.target_position = q.tolist()
        self._inp.target_velocity = [0.0] * self.n
        self._target_still = True
        self._finished = False

    def _set_velocity_mode(self, v: np.ndarray, name: str) -> None:
        if self._mode != name:  # (a velocity stream sets the same mode every cycle: ruckig has it already)
            self._mode = name
            self._inp.control_interface = ControlInterface.Velocity
            self._inp.synchronization = Synchronization.Phase
        target = v.tolist()
        self._inp.target_velocity = target
        self._target_still = not any(target)
        self._finished = False

    def _try_switch_guard(self) -> None:
        """Adopt the wanted guard limits once the emitted state fits them (at once if they are wider)."""
        if self._guard_env is not self._wanted_guard and self.guard.state_feasible(self._wanted_guard):
            self._guard_env = self._wanted_guard

    def _replan(self) -> list[float] | None:
        """Ruckig's next position after its update failed, or None if it cannot plan at all.

        Not expected, but ruckig 0.19 does raise on rare numerical edge cases (seen: velocity
        interface, "error in step 1"): retry less synchronized, then with a hair less jerk, then brake."""
        self.planning_errors += 1
        sync = self._inp.synchronization
        for retry in (Synchronization.Time, Synchronization.No):
            self._inp.synchronization = retry
            if self._update():
                self._inp.synchronization = sync
                return self._out.new_position  # type: ignore[no-any-return]
        jerk = self._inp.max_jerk
        self._inp.max_jerk = [j * (1.0 - 1e-6) for j in jerk]
        ok = self._update()
        self._inp.max_jerk, self._inp.synchronization = jerk, sync
        if ok:
            return self._out.new_position  # type: ignore[no-any-return]
        # No plan to the target (-101: braking from 190 deg/s to a jog target the line cut 1e-4 deg
        # ahead, then back at 1e-4 deg/s), but still a stop: brake towards rest on ruckig's velocity
        # interface, each axis on its own, and plan again from there next cycle.
        inp = self._inp
        interface, target = inp.control_interface, inp.target_velocity
        inp.control_interface, inp.synchronization, inp.target_velocity = (
            ControlInterface.Velocity, Synchronization.No, [0.0] * self.n)
        ok = self._update()
        inp.control_interface, inp.synchronization, inp.target_velocity = interface, sync, target
        self._finished = False  # (the stop's end is not the command's)
        return self._out.new_position if ok else None  # type: ignore[no-any-return]

    def _update(self) -> bool:
        try:
            result = self._otg.update(self._inp, self._out)
        except RuckigError as exc:
            self.last_planning_error = str(exc)
            return False
        except ValueError as exc:
            # ruckig 0.19's Python Result lacks two of its C++ codes, and its binding raises converting
            # them: -101 ErrorTrajectoryDuration (the plan would last over ~7.6e3 s), -104 ErrorZeroLimits.
            self.last_planning_error = f"ruckig result {exc} (-101: too long a plan, -104: zero limits): {self._inp}"
            return False
        self._finished = result == Result.Finished
        if self._finished or result == Result.Working:
            return True
        self.last_planning_error = f"{result}: {self._inp}"
        return False

    def _settle(self) -> None:
        """At the end of a stop or a move ruckig may leave ~1e-14 deg/s that would creep on forever,
        or end ~1e-16 deg off the target: snap to the exact end state (far inside the planning slack)."""
        inp = self._inp
        if not self._target_still:  # (any(inp.target_velocity), kept by the two modes that set it)
            return
        position = inp.control_interface == ControlInterface.Position
        if any(inp.current_velocity) or any(inp.current_acceleration) or (
                position and inp.current_position != inp.target_position):
            inp.current_velocity = [0.0] * self.n
            inp.current_acceleration = [0.0] * self.n
            if position:
                inp.current_position = inp.target_position

    def _resync(self, axes: np.ndarray) -> None:
        """Continue ruckig from the parabola through the last three emitted positions on ``axes``:
        a continuation with bounded jerk then keeps the finite differences consistent."""
        g = self.guard
        p, v, a = (np.asarray(x) for x in (self._inp.current_position, self._inp.current_velocity,
                                            self._inp.current_acceleration))
        p[axes], v[axes], a[axes] = g.s1[axes], g.v1[axes] + g.a1[axes] * self.dt / 2.0, g.a1[axes]
        self._inp.current_position, self._inp.current_velocity = p.tolist(), v.tolist()
        self._inp.current_acceleration = a.tolist()
