"""Trajectory replay: time a joint path so every controller limit holds, and play it back one sample a cycle.

Pure: no I/O, no threads, no clock. The API process plans (:class:`TrajectoryPlanner`, TOPP-RA plus a
jerk bound, checked the controller's way); the servo process plays the checked samples
(:class:`ReplayPlayer`), pausing and resuming along the path by a time-warp.

Timing a path (``TrajectoryPlanner.plan``):

1. The path is split into segments that start and end at rest: at each given waypoint, and inside a
   dense path (a CSV, a session log) wherever it turns back on itself. A segment is a cubic spline in
   joint space through its points, parameterised by chord length (a straight segment stays straight).
   Blended joint waypoints (``joint_segments(..., blend=True)``) are one segment through all of them,
   from the rest position to the last: the arm passes through the inner ones without stopping;
2. TOPP-RA (``toppra``) times each segment at a share of the velocity and acceleration limits;
3. TOPP-RA's acceleration is piecewise constant (unbounded jerk): the path parameter s(t), sampled at
   the stream interval, is smoothed by a moving average of ``m`` samples. The motion stays on the path,
   the finite differences of the smoothed s are box averages of the raw ones (so its acceleration does
   not grow) and its third difference is bounded by 2 max|s''| / (m dt): ``m`` is chosen from the
   acceleration-to-jerk ratio;
4. the samples (float32, as the wire carries them) are checked exactly as the servo process's guard
   checks them (:class:`~servo_app.motion.shaper.DiscreteGuard`) and by the controller's own check
   (:class:`~servo_app.motion.checker.ControllerLimitChecker`), with the flange speed under the cap.
   A segment that fails is slowed down (lower shares) and timed again.

Pause and resume (``ReplayPlayer``): the samples are played at a rate r (samples per cycle) that ramps
1 -> 0 (pause) and 0 -> 1 (resume) along ``3x^2 - 2x^3`` over an odd number ``n`` of cycles; positions
between samples come from a C2 quintic Hermite curve through them. With ``n`` odd a pause covers exactly
(n - 1) / 2 samples and a resume (n + 1) / 2: every ramp starts and ends on a sample, so the ramps
that can happen at all (a pause from any sample while playing, a resume from any sample at rest) are
finitely many, and the planner checks every one of them before the trajectory is accepted. The
planner leaves half of the acceleration and jerk limits to the ramps (the plan itself uses the rest).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from servo_app.motion.checker import ControllerLimitChecker, check_trajectory
from servo_app.motion.limit_tables import LimitTables
from servo_app.motion.shaper import Envelope, ShaperLimits, to_f32
from servo_app.robots.configuration import ConfigurationRegion, boundary_distances
from servo_app.robots.conventions import fanuc_deg_to_model_rad, model_rad_to_fanuc_deg, xyzwpr_to_matrix
from servo_app.robots.kernels import flange_speeds_mm_s, pack_dims
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import RobotProfile

# Shares of the (soft) limits the plan itself may use; the pause/resume ramps use the rest.
PLAN_ACC_SHARE = 0.5
PLAN_JERK_SHARE = 0.5
VEL_SHARE = 0.95  # of the velocity limit: the guard keeps a braking reserve above the speed
MAX_RETRIES = 12  # each retry slows a failing segment down by SLOWDOWN
SLOWDOWN = 0.8
DENSE_KNOT_DEG = 0.25  # a dense path keeps a knot every this many deg (chord) for its spline
CART_STEP_MM = 2.0  # Cartesian segments are solved every this many mm ...
CART_STEP_DEG = 1.0  # ... and this many deg of orientation
# 13 min at 8 ms, 6.7 at 4 ms: a plan beyond this is refused. The servo process takes a plan whole
# between two statuses (unpickled, checked, copied: ~95 ns a sample here, 9.5 ms for 100 000, no alarm
# at 4 ms with lead 2); 197 504 samples at 4 ms held the cycle up long enough for MOTN-603.
MAX_SAMPLES = 100_000
# A blended path's spline can overshoot its waypoints: it is checked against the joint ranges and the
# held configuration at this many points between two waypoints and at every joint's turning point (the
# samples are checked again after timing).
BLEND_CHECK_POINTS = 64
# deg: consecutive joint waypoints this close are one point (the wire's float32 step is 7.6e-6 deg at
# 64-128 deg; the approach takes an arm resting within 1e-6 deg of the first waypoint as there).
COINCIDENT_DEG = 1e-6
# deg (chord): a blended path's consecutive knots closer than this are refused, naming both. Below it
# the spline turns between them on the spot, alike at any scale: on the e2e via path (1.35 s blended,
# 2.18 s stopping at each), a waypoint added 0.03 or 0.25 deg from another in a random direction gave
# the same timings, up to 5.3 s; 2e-6 deg apart, up to 5.1 s, a neighbouring span newly overshooting its
# range, or "TOPP-RA found no timing". The planner spaces a dense path's knots as far (DENSE_KNOT_DEG);
# 0.25 deg is far above float noise (33 000 float32 steps at 64-128 deg), and a client sending two
# waypoints this close meant one point or a stop there: it can send one, or blend=false.
BLEND_MIN_CHORD_DEG = DENSE_KNOT_DEG


class TrajectoryRefused(ValueError):
    """The path cannot be replayed within the limits; the message names the waypoint, sample or field."""


@dataclass(frozen=True)
class PlanLimits:
    """What a plan must respect: the servo's checked (soft) limits and the flange-speed cap."""

    envelope: Envelope  # the shaper's soft envelope: what its float32 guard enforces
    dt: float
    flange_speed_max: float  # mm/s: the cap times the servo's flange-speed margin

    @classmethod
    def for_servo(cls, vel: np.ndarray, acc: np.ndarray, jerk: np.ndarray, dt: float, cap: float,
                  limit_fraction: float = 0.9, flange_margin: float = 0.8) -> PlanLimits:
        """From the limits the servo cycle streams within (``tables.for_cap(cap)``) and its settings."""
        limits = ShaperLimits(np.asarray(vel, float), np.asarray(acc, float), np.asarray(jerk, float),
                              fraction=limit_fraction)
        env = Envelope.build(*limits.scaled("soft"), limits.pos_abs_max, dt)  # type: ignore[arg-type]
        return cls(env, float(dt), float(cap) * flange_margin)


@dataclass
class TimedTrajectory:
    """Samples at the stream interval (FANUC deg, float32 values): the first is the start, the last
    three equal the end (at rest). ``waypoint_samples[i]``: where segment i ends (at rest)."""

    samples: np.ndarray
    dt: float
    ramp_steps: int  # the pause/resume ramp, cycles (odd)
    waypoint_samples: list[int] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return (len(self.samples) - 1) * self.dt


# ----------------------------------------------------------------------------- checks (vectorised)


def first_violation(samples: np.ndarray, env: Envelope, dt: float, history: np.ndarray | None = None) -> int:
    """Index of the first sample whose finite differences break ``env`` (as
    :meth:`DiscreteGuard.passes` judges: v, a, j and the braking reserve), or -1. ``history``: the
    (3, n) positions emitted before (default: at rest at the first sample)."""
    q = np.asarray(samples, float)
    h = np.repeat(q[:1], 3, axis=0) if history is None else np.asarray(history, float)
    full = np.concatenate([h, q])
    v = np.diff(full, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    v, a = v[2:], a[1:]
    c = env.brake_jerk * dt
    n = np.floor(np.abs(a) / c)
    peak = v + dt * (n * a - np.copysign(c * n * (n + 1.0) / 2.0, a))
    ok = ((np.abs(v) <= env.vel) & (np.abs(a) <= env.acc) & (np.abs(j) <= env.jerk)
          & (np.maximum(peak, v) <= env.brake_vel) & (np.minimum(peak, v) >= -env.brake_vel)).all(axis=1)
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if bad.size else -1


def flange_speeds(kin: ArmKinematics, samples: np.ndarray, dt: float) -> np.ndarray:
    """Flange-centre speed (mm/s) between consecutive samples, as the controller's check computes it
    (:func:`servo_app.robots.kernels.flange_speeds_mm_s`: a 20 000-sample plan in about a millisecond)."""
    rows = np.ascontiguousarray(samples, dtype=np.float64)
    out = np.empty(max(len(rows) - 1, 0))
    if len(rows) > 1:
        dims = pack_dims(kin.a1, kin.a2, kin.a3, kin.d4, kin.d6)
        flange_speeds_mm_s(rows, float(kin.j23_factor), dims, dt, out)
    return out


# ------------------------------------------------------------------------------- pause/resume ramp


def ramp_rates(n: int, up: bool) -> np.ndarray:
    """The rate per cycle of an ``n``-cycle ramp (n odd): 0 -> 1 (up) or 1 -> 0 (down), last value 1 / 0.
    Sums: (n + 1) / 2 up, (n - 1) / 2 down (whole samples, see the module's text)."""
    x = np.arange(1, n + 1) / n
    g = 3.0 * x * x - 2.0 * x * x * x
    g[-1] = 1.0
    return g if up else 1.0 - g


def warp_position(samples: np.ndarray, tau: float) -> np.ndarray:
    """The position at fractional sample index ``tau``: the sample itself at a whole index, else the
    quintic Hermite curve through the two samples around it, with the central differences as first
    and second derivatives there (C2: a warp along it has a bounded jerk; the ends held)."""
    return warp_positions(samples, np.array([tau]))[0]


def warp_positions(samples: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """:func:`warp_position` for an array of indices (any shape): positions of shape ``tau.shape + (n,)``."""
    n = len(samples)
    k = np.floor(tau).astype(np.int64)
    t = (tau - k)[..., None]
    p0, p1, p2, p3 = (samples[np.clip(k + d, 0, n - 1)] for d in (-1, 0, 1, 2))
    v1, v2 = (p2 - p0) / 2.0, (p3 - p1) / 2.0
    a1, a2 = p2 - 2.0 * p1 + p0, p3 - 2.0 * p2 + p1
    t2 = t * t
    t3 = t2 * t
    t4, t5 = t3 * t, t3 * t2
    out = ((1.0 - 10.0 * t3 + 15.0 * t4 - 6.0 * t5) * p1 + (t - 6.0 * t3 + 8.0 * t4 - 3.0 * t5) * v1
           + (0.5 * t2 - 1.5 * t3 + 1.5 * t4 - 0.5 * t5) * a1 + (0.5 * t3 - t4 + 0.5 * t5) * a2
           + (-4.0 * t3 + 7.0 * t4 - 3.0 * t5) * v2 + (10.0 * t3 - 15.0 * t4 + 6.0 * t5) * p2)
    exact = (t[..., 0] == 0.0) | (k >= n - 1)
    out[exact] = p1[exact]  # on a sample: the sample itself, bit for bit
    return out


def ramp_taus(start: np.ndarray, n: int, up: bool) -> np.ndarray:
    """The sample indices an ``n``-cycle ramp plays from each whole index in ``start``: (len, n);
    the last one whole (the ramp sums are whole, this removes the rounding)."""
    offsets = np.cumsum(ramp_rates(n, up))
    offsets[-1] = (n + 1) // 2 if up else (n - 1) // 2
    return np.asarray(start, float)[:, None] + offsets[None, :]


def ramp_positions(samples: np.ndarray, start: int, n: int, up: bool) -> np.ndarray:
    """The float32 positions a ramp emits from sample ``start`` (what the player sends)."""
    tau = np.minimum(ramp_taus(np.array([start]), n, up)[0], len(samples) - 1)
    return to_f32(warp_positions(samples, tau))


def _rows_fit(history: np.ndarray, pos: np.ndarray, env: Envelope, dt: float) -> np.ndarray:
    """Per row: the positions ``pos`` (rows, k, n) after ``history`` (rows, 3, n) keep ``env``."""
    full = np.concatenate([history, pos], axis=1)
    v = np.diff(full, axis=1) / dt
    a = np.diff(v, axis=1) / dt
    j = np.diff(a, axis=1) / dt
    v, a = v[:, 2:], a[:, 1:]
    c = env.brake_jerk * dt
    m = np.floor(np.abs(a) / c)
    peak = v + dt * (m * a - np.copysign(c * m * (m + 1.0) / 2.0, a))
    ok = ((np.abs(v) <= env.vel) & (np.abs(a) <= env.acc) & (np.abs(j) <= env.jerk)
          & (np.maximum(peak, v) <= env.brake_vel) & (np.minimum(peak, v) >= -env.brake_vel))
    return ok.all(axis=(1, 2))  # type: ignore[no-any-return]


def ramps_fit(samples: np.ndarray, n: int, env: Envelope, dt: float, block: int = 512) -> int:
    """-1 if every pause (from any sample while playing) and every resume (from any sample at rest)
    with an ``n``-cycle ramp keeps the guard's limits; else the first sample where one does not."""
    q = np.asarray(samples, float)
    last = len(q) - 1
    for b in range(2, last, block):
        ks = np.arange(b, min(b + block, last))
        for up in (False, True):
            tau = np.minimum(ramp_taus(ks, n, up), last)
            pos = to_f32(warp_positions(q, tau))
            hist = np.repeat(q[ks][:, None, :], 3, axis=1) if up else np.stack([q[ks - 2], q[ks - 1], q[ks]], axis=1)
            ok = _rows_fit(hist, pos, env, dt)
            if not ok.all():
                return int(ks[np.flatnonzero(~ok)[0]])
    return -1


def ramp_steps_for(samples: np.ndarray, env: Envelope, dt: float) -> int:
    """The shortest odd ramp (cycles) for which every pause and resume keeps the limits."""
    q = np.asarray(samples, float)
    v = np.abs(np.diff(q, axis=0)).max(axis=0) / dt if len(q) > 1 else np.zeros(q.shape[1])
    # Continuous estimate: r' <= 1.5 / T adds r' v to the acceleration, r'' <= 6 / T^2 adds r'' v to
    # the jerk; half of each limit is left to the ramps.
    free_a, free_j = env.acc * (1.0 - PLAN_ACC_SHARE), env.jerk * (1.0 - PLAN_JERK_SHARE)
    t = max(float(np.max(1.5 * v / free_a)), float(np.max(np.sqrt(6.0 * v / free_j))), 4.0 * dt)
    n = 2 * math.ceil(t / dt / 2.0) + 1
    for _ in range(8):
        if ramps_fit(q, n, env, dt) < 0:
            return n
        n = 2 * math.ceil(n * 1.3 / 2.0) + 1
    raise TrajectoryRefused("no pause ramp keeps the limits along this trajectory; send it with a lower "
                            "speed_scale")


# ------------------------------------------------------------------------------------------ planner


@dataclass
class _Segment:
    points: np.ndarray  # (k, n) FANUC deg, k >= 2, no two consecutive equal
    duration_s: float | None = None  # requested (times), None: as fast as the limits allow
    share: float = 1.0  # share of the plan's velocity and acceleration limits (lowered on failure)
    label: str = ""
    # A recording's pace (dense rows, one per interval): each knot's time, s. The replay's path speed
    # between two knots stays at or below the recorded one (None: as fast as the limits allow).
    knot_times: np.ndarray | None = None


class TrajectoryPlanner:
    """Times joint or Cartesian paths for the servo cycle (see the module's text).

    ``region``: joint ranges and the held configuration (model rad) every sample must stay in;
    ``checker``: the controller's limit check, built fresh for each verification.
    """

    def __init__(self, profile: RobotProfile, limits: PlanLimits, region: ConfigurationRegion,
                 checker: Callable[[], ControllerLimitChecker], tool_xyzwpr: Sequence[float] | None = None,
                 speed_scale: float = 1.0) -> None:
        self.profile = profile
        self.limits = limits
        self.region = region
        self.checker = checker
        self.kin = ArmKinematics(profile, tool_xyzwpr)
        self.flange_kin = ArmKinematics(profile)
        self.speed_scale = float(speed_scale)
        self.dof = profile.dof

    @classmethod
    def for_stream(cls, profile: RobotProfile, dt: float, tables: LimitTables, q_now: np.ndarray, *,
                   cap: float | None = None, payload_kg: float | None = None, limit_fraction: float = 0.9,
                   flange_margin: float = 0.8, joint_margin_deg: float = 0.5, config_margin_deg: float = 1.0,
                   tool_xyzwpr: Sequence[float] | None = None, speed_scale: float = 1.0) -> TrajectoryPlanner:
        """A planner for a stream resting at ``q_now`` (FANUC deg), with the servo cycle's settings: the
        limits for the flange-speed cap, the joint ranges less the margin and ``q_now``'s configuration
        (as :meth:`ServoCycle.begin` holds it), the controller's check with ``tables``."""
        cap = tables.cap(cap)
        dof = profile.dof
        vel, acc, jerk = (np.asarray(x[:dof], float) for x in tables.for_cap(cap, payload_kg))
        limits = PlanLimits.for_servo(vel, acc, jerk, dt, cap, limit_fraction, flange_margin)
        kin = ArmKinematics(profile)
        q_model = fanuc_deg_to_model_rad(np.asarray(q_now, float)[:dof], profile.j23_factor)
        margins = np.minimum(np.radians(config_margin_deg), boundary_distances(q_model, kin) * 0.999)
        lo = np.radians(np.asarray(profile.joint_min_deg) + joint_margin_deg)
        hi = np.radians(np.asarray(profile.joint_max_deg) - joint_margin_deg)
        region = ConfigurationRegion.around(q_model, kin, margins).within(lo, hi)

        def checker() -> ControllerLimitChecker:
            return ControllerLimitChecker.for_profile(profile, kin.flange_xyz_mm_fanuc_deg, tables=tables,
                                                      interval_s=dt, payload_kg=payload_kg)

        return cls(profile, limits, region, checker, tool_xyzwpr, speed_scale)

    # -- inputs -> segments
    def joint_segments(self, start: np.ndarray, waypoints: np.ndarray, times: Sequence[float] | None,
                       blend: bool = False) -> list[_Segment]:
        """Straight joint-space segments: start -> waypoint 0 (the approach), then waypoint to waypoint,
        each from rest to rest; with ``blend`` one segment through them all (:meth:`blended_segment`)."""
        self._check_inside(waypoints, "joints")
        if blend:
            if times is not None:
                raise TrajectoryRefused("times: not with blend (a blended path is one motion, timed as fast as "
                                        "the limits allow); drop times, or send blend=false to reach each "
                                        "waypoint at its time")
            return self.blended_segment(start, waypoints)
        segs = self._approach(start, waypoints[0])
        at = 0  # the waypoint the path has reached
        for i in range(1, len(waypoints)):
            pts = np.array([waypoints[at], waypoints[i]])
            if _coincident(pts[0], pts[1]):
                # A repeated point (to COINCIDENT_DEG: 3e-211 deg apart made the spline's knots equal,
                # 1e-9 deg left TOPP-RA no timing): the arm stays, for its time if it has one.
                if times is not None and times[i] > times[i - 1]:
                    segs.append(_Segment(pts[:1].repeat(2, axis=0), float(times[i] - times[i - 1]),
                                         label=f"waypoint {i}"))
                continue
            duration = None if times is None else float(times[i] - times[i - 1])
            label = f"waypoint {at} -> {i}" + (f" (times[{i}])" if times is not None else "")
            segs.append(_Segment(_densify_line(pts[0], pts[1]), duration, label=label))
            at = i
        return self._anchored(segs)

    def blended_segment(self, start: np.ndarray, waypoints: np.ndarray) -> list[_Segment]:
        """One segment from rest at ``start`` through every waypoint to rest at the last: a cubic spline
        in joint space by chord length (as a dense path's), so the arm passes through the inner
        waypoints (and the first, if it rests elsewhere) without stopping. The spline can overshoot
        between waypoints: one that leaves the joint ranges or the held configuration is refused,
        naming the two waypoints (another waypoint between them pulls it in; straight segments stay in),
        and so are two consecutive knots closer than BLEND_MIN_CHORD_DEG, naming both."""
        self._start = np.array(start, dtype=float)
        knots, names = [self._start], ["the start"]
        for i, w in enumerate(np.asarray(waypoints, float)):
            if _coincident(knots[-1], w):
                continue  # (a repeated waypoint, or the first where the arm rests: one point)
            knots.append(w)
            names.append(f"joints[{i}]")
        if len(knots) < 2:
            return []
        pts = np.array(knots)
        chord = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        near = np.flatnonzero(chord < BLEND_MIN_CHORD_DEG)
        if near.size and len(pts) > 2:  # (two knots: a straight line, no turn)
            k = int(near[0])
            first, merge = ("the start (where the arm rests)", f"drop {names[1]}") if k == 0 else \
                (names[k], "send them as one waypoint")
            raise TrajectoryRefused(
                f"blend: {first} and {names[k + 1]} are {chord[k]:.3g} deg apart, closer than "
                f"{BLEND_MIN_CHORD_DEG:g} deg (the spline would turn on the spot between them); {merge}, or "
                f"send blend=false to stop at each")
        label = "the blended path through joints[0.." + f"{len(waypoints) - 1}]"
        if len(pts) == 2:
            return [_Segment(_densify_line(pts[0], pts[1]), label=label)]
        from scipy.interpolate import CubicSpline

        ss = np.concatenate([[0.0], np.cumsum(chord)])
        spline = CubicSpline(ss, pts)  # the path _time_segment times (toppra's SplineInterpolator: not-a-knot)
        u = np.linspace(0.0, 1.0, BLEND_CHECK_POINTS + 1)
        # Points along every span, and every joint's turning points (where an overshoot peaks).
        s_check = np.sort(np.concatenate([(ss[:-1, None] + u[None, :] * chord[:, None]).ravel(),
                                          _turning_points(spline)]))
        q = spline(s_check)
        q_model = fanuc_deg_to_model_rad(q, self.profile.j23_factor)
        outside = np.flatnonzero(~self.region.contains(q_model))
        if outside.size:
            i = int(outside[0])
            k = min(int(np.searchsorted(ss, s_check[i], side="right")) - 1, len(chord) - 1)
            raise TrajectoryRefused(
                f"blend: the spline from {names[k]} to {names[k + 1]} overshoots at "
                f"{100 * (s_check[i] - ss[k]) / chord[k]:.0f} % of the way, {np.round(q[i], 3).tolist()}, leaving "
                f"the joint ranges or the held configuration {self.region.reference}: "
                f"{self._outside_axes(q_model[i])}; add a waypoint between them, or send blend=false")
        return [_Segment(pts, label=label)]

    def dense_segments(self, start: np.ndarray, rows: np.ndarray, what: str, *, recorded_pace: bool = True,
                       row_dt: float | None = None) -> list[_Segment]:
        """A dense path (CSV rows, a log's commands: one row per interval): split where it turns back,
        knots every DENSE_KNOT_DEG; the approach from ``start`` to its first row first.

        ``recorded_pace``: never faster along the path than the rows were recorded (times the speed
        scale). A hand-guided stretch at 15 deg/s was replayed at 59 deg/s when timed only by the
        limits: an operator beside the arm expects the motion they taught, not its fastest version.
        ``row_dt``: the time between rows as recorded (a log's own interval; default the stream's)."""
        self._check_inside(rows, what)
        segs = self._approach(start, rows[0])
        # The recorded time of each knot counts only rows that moved: the arm resting before, between
        # or after motions is no pace to keep (0.25 deg over a 5 s rest would be a creep).
        moved = np.concatenate([[0.0], np.any(np.diff(rows, axis=0) != 0.0, axis=1)])
        clock = np.cumsum(moved) * (row_dt or self.limits.dt)
        # Pieces end where the recording rested or turned back, found on the rows themselves: thinned
        # first, the knots skipped the point of rest, and the spline cut the corner there (0.08 deg
        # short of a target the recording reached), or TOPP-RA found no timing through the near-cusp.
        for lo, hi in _rest_pieces(rows):
            keep = [lo + k for k in _thin_indices(rows[lo: hi + 1], DENSE_KNOT_DEG)]
            knots, times = rows[keep], clock[keep]
            for a, b in _reversal_pieces(knots):
                piece, t = knots[a: b + 1], times[a: b + 1]
                if len(piece) == 2:
                    piece, t = _densify_line(piece[0], piece[1]), np.array([t[0], (t[0] + t[1]) / 2.0, t[1]])
                segs.append(_Segment(piece, label=f"{what} rows", knot_times=t if recorded_pace else None))
        return self._anchored(segs)

    def cartesian_segments(self, start: np.ndarray, poses: np.ndarray, times: Sequence[float] | None
                           ) -> tuple[list[_Segment], np.ndarray]:
        """Straight TCP segments between poses (X Y Z mm, W P R deg), solved in the held configuration;
        the joints of each pose are returned too (the approach goes to the first in joint space)."""
        joints = self._poses_to_joints(start, poses, "poses")
        segs = self._approach(start, joints[0])
        for i in range(1, len(poses)):
            pts = self._cartesian_line(poses[i - 1], poses[i], joints[i - 1], i)
            segs.append(_Segment(pts, None if times is None else float(times[i] - times[i - 1]),
                                 label=f"poses[{i - 1}] -> poses[{i}]" + (f" (times[{i}])" if times else "")))
        return self._anchored(segs), joints

    def dense_pose_segments(self, start: np.ndarray, poses: np.ndarray, what: str, *, recorded_pace: bool = True
                            ) -> list[_Segment]:
        """Dense flange poses (a CSV of X Y Z W P R rows, one per interval, as ``servo-app check`` reads
        them: the flange centre, whatever the tool): each solved in the held configuration, then timed as
        a dense joint path (:meth:`dense_segments`), not from rest to rest between every two rows."""
        joints = self._poses_to_joints(start, poses, what, self.flange_kin)
        return self.dense_segments(start, joints, what, recorded_pace=recorded_pace)

    def _poses_to_joints(self, start: np.ndarray, poses: np.ndarray, what: str,
                         kin: ArmKinematics | None = None) -> np.ndarray:
        """FANUC deg of each pose (of ``kin``'s TCP; default the tool's) in the held configuration, each
        seeded by the previous one."""
        seed = fanuc_deg_to_model_rad(start, self.profile.j23_factor)
        joints = np.empty((len(poses), self.dof))
        for i, pose in enumerate(poses):
            q = self._solve(xyzwpr_to_matrix(pose), seed, kin)
            if q is None:
                raise TrajectoryRefused(f"{what}[{i}]={[round(float(v), 3) for v in pose]} has no joint solution in "
                                        f"the held configuration {self.region.reference} within the joint ranges; "
                                        f"send a pose the arm reaches in that configuration")
            joints[i] = model_rad_to_fanuc_deg(q, self.profile.j23_factor)
            seed = q
        return joints

    # -- timing
    def plan(self, segments: list[_Segment]) -> TimedTrajectory:
        """Time, sample and check ``segments`` (each from rest to rest); refuses with the reason."""
        env, dt = self.limits.envelope, self.limits.dt
        if not segments:
            raise TrajectoryRefused("nothing to do: the path does not move")
        samples = self._time_all(segments)
        for _ in range(MAX_RETRIES):
            bad = self._verify(samples)
            if bad is None:
                break
            seg, why = bad
            segments[seg].share *= SLOWDOWN
            if segments[seg].duration_s is not None and segments[seg].share < 1.0:
                raise TrajectoryRefused(f"times: {segments[seg].label} cannot be done in the "
                                        f"{segments[seg].duration_s:g} s given within the limits ({why}); "
                                        f"give it more time, or drop times")
            samples = self._time_all(segments)
        else:
            raise TrajectoryRefused(f"no timing of {segments[bad[0]].label} keeps the limits ({bad[1]}); "
                                    f"{_reshape(segments[bad[0]].label)}")
        ramp = ramp_steps_for(samples, env, dt)
        ends = np.cumsum([0, *self._segment_lengths])
        return TimedTrajectory(samples, dt, ramp, [int(e) for e in ends[1:]])

    def _time_all(self, segments: list[_Segment]) -> np.ndarray:
        parts: list[np.ndarray] = []
        self._segment_lengths = []
        self._segment_of: list[int] = []
        for i, seg in enumerate(segments):
            q = self._time_segment(seg)
            if parts:
                q = q[1:]  # the previous segment ends at rest at this one's start
            parts.append(q)
            self._segment_lengths.append(len(q))
            self._segment_of.extend([i] * len(q))
            if sum(len(p) for p in parts) > MAX_SAMPLES:
                raise TrajectoryRefused(f"the trajectory would last over {MAX_SAMPLES * self.limits.dt:.0f} s: "
                                        "split it")
        samples = np.concatenate(parts)
        # Three equal samples at the end: the controller's finite differences end at rest.
        tail = np.repeat(samples[-1:], 3, axis=0)
        self._segment_of.extend([len(segments) - 1] * 3)
        self._segment_lengths[-1] += 3
        return np.concatenate([samples, tail])

    def _time_segment(self, seg: _Segment) -> np.ndarray:
        import toppra
        import toppra.algorithm
        import toppra.constraint

        env, dt = self.limits.envelope, self.limits.dt
        pts = seg.points
        if len(pts) < 2 or np.abs(pts - pts[0]).max() <= COINCIDENT_DEG:  # (a repeated pose, too)
            steps = max(1, round((seg.duration_s or 0.0) / dt))
            return to_f32(np.repeat(pts[:1], steps + 1, axis=0))
        chord = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        ss = np.concatenate([[0.0], np.cumsum(chord)])
        path = toppra.SplineInterpolator(ss, pts)
        vel = env.vel * VEL_SHARE * seg.share * self.speed_scale
        acc = env.acc * PLAN_ACC_SHARE * seg.share
        grid = np.linspace(0.0, ss[-1], int(min(2000, max(50, 4 * len(pts)))))
        constraints = [toppra.constraint.JointVelocityConstraint(np.column_stack([-vel, vel])),
                       toppra.constraint.JointAccelerationConstraint(np.column_stack([-acc, acc]))]
        if seg.knot_times is not None:
            constraints.append(_recorded_pace(path, ss, seg.knot_times, self.speed_scale * seg.share))
        instance = toppra.algorithm.TOPPRA(constraints, path, gridpoints=grid, parametrizer="ParametrizeConstAccel")
        _sdd, sd, _ = instance.compute_parameterization(0.0, 0.0)
        if sd is None or not np.all(np.isfinite(sd)):
            raise TrajectoryRefused(f"{seg.label}: TOPP-RA found no timing within the limits; {_reshape(seg.label)}")
        s = _sample_constant_acceleration(grid, np.maximum(sd, 0.0), dt)
        if seg.duration_s is not None:
            try:
                s = _stretch(s, seg.duration_s, dt, self._smoothing_width(vel, acc))
            except TrajectoryRefused as exc:
                raise TrajectoryRefused(f"times: {seg.label} {exc}") from None
        sigma = _moving_average(s, self._smoothing_width(vel, acc))
        q = path(sigma)
        q[sigma <= 0.0] = pts[0]
        q[sigma >= ss[-1]] = pts[-1]
        return to_f32(q)

    def _smoothing_width(self, vel: np.ndarray, acc: np.ndarray) -> int:
        """Samples of the moving average: the third difference of s stays within the jerk share."""
        env, dt = self.limits.envelope, self.limits.dt
        ratio = float(np.max(2.0 * acc / (env.jerk * PLAN_JERK_SHARE)))
        return max(2, math.ceil(ratio / dt))

    def _verify(self, samples: np.ndarray) -> tuple[int, str] | None:
        """(segment, why) of the first failure: guard, configuration, flange speed, controller check."""
        env, dt = self.limits.envelope, self.limits.dt
        k = first_violation(samples, env, dt)
        if k >= 0:
            return self._segment_of[k], f"sample {k}: the servo's float32 limit check"
        speeds = flange_speeds(self.flange_kin, samples, dt)
        over = np.flatnonzero(speeds > self.limits.flange_speed_max)
        if over.size:
            return (self._segment_of[int(over[0]) + 1],
                    f"sample {int(over[0]) + 1}: flange speed {speeds[over[0]]:.0f} mm/s above "
                    f"{self.limits.flange_speed_max:.0f}")
        outside = np.flatnonzero(~self.region.contains(fanuc_deg_to_model_rad(samples, self.profile.j23_factor)))
        if outside.size:
            i = int(outside[0])
            raise TrajectoryRefused(f"{self._label_of(i)}: sample {i} {np.round(samples[i], 3).tolist()} leaves the "
                                    f"joint ranges or the held configuration {self.region.reference}")
        checker = self.checker()
        found = [v for v in check_trajectory(checker, samples) if not v.warning]
        if found:
            v = found[0]
            k = max(0, (v.seq or 1) - 1)
            return (self._segment_of[min(k, len(samples) - 1)],
                    f"sample {k}: controller check {v.code} {v.kind} J{v.axis}")
        return None

    def _label_of(self, sample: int) -> str:
        return f"segment {self._segment_of[sample]}"

    # -- helpers
    def _approach(self, start: np.ndarray, first: np.ndarray) -> list[_Segment]:
        """The move from where the arm rests to the path's first point; none if it rests there (to
        within 1e-6 deg, what an IK solution of the pose it rests at may differ by: the path is then
        anchored at ``start`` itself, so its first sample is the commanded position, bit for bit)."""
        self._start = np.array(start, dtype=float)
        if np.allclose(start, first, atol=1e-6):
            return []
        return [_Segment(_densify_line(start, first), label="the approach to the first waypoint")]

    def _anchored(self, segments: list[_Segment]) -> list[_Segment]:
        if segments and not np.array_equal(segments[0].points[0], self._start):
            first = segments[0]
            points = first.points.copy()
            points[0] = self._start
            segments[0] = _Segment(points, first.duration_s, first.share, first.label)
        return segments

    def _check_inside(self, rows: np.ndarray, what: str) -> None:
        q = fanuc_deg_to_model_rad(rows, self.profile.j23_factor)
        outside = np.flatnonzero(~self.region.contains(q))
        if outside.size:
            i = int(outside[0])
            raise TrajectoryRefused(f"{what}[{i}]={np.round(rows[i], 3).tolist()} leaves the joint ranges or the held "
                                    f"configuration {self.region.reference}: {self._outside_axes(q[i])}; "
                                    f"send it within them")

    def _outside_axes(self, q_model: np.ndarray) -> str:
        """Which joints of ``q_model`` (rad) leave the region's ranges, or that the wrist centre crosses."""
        lo, hi = np.degrees(self.region.lower), np.degrees(self.region.upper)
        qd = np.degrees(q_model)
        axes = [f"J{a + 1}={qd[a]:.3f} (allowed {lo[a]:.1f}..{hi[a]:.1f})" for a in range(6)
                if not lo[a] <= qd[a] <= hi[a]]
        return (", ".join(axes) or "the wrist centre crosses the J1 axis") + " (model convention, deg)"

    def _solve(self, goal: np.ndarray, seed: np.ndarray, kin: ArmKinematics | None = None) -> np.ndarray | None:
        kin = kin or self.kin
        sols = [s.q_model_rad for s in kin.ik_tcp(goal, with_turns=True, within_limits=True, seed=seed)]
        sols = [q for q in sols if bool(self.region.contains(q)[0])]
        if not sols:
            return None
        return min(sols, key=lambda q: float(np.sum((q - seed) ** 2)))

    def _cartesian_line(self, a: np.ndarray, b: np.ndarray, q_a: np.ndarray, index: int) -> np.ndarray:
        ta, tb = xyzwpr_to_matrix(a), xyzwpr_to_matrix(b)
        lin = float(np.linalg.norm(b[:3] - a[:3]))
        rel = ta[:3, :3].T @ tb[:3, :3]
        angle = math.acos(max(-1.0, min(1.0, (float(np.trace(rel)) - 1.0) / 2.0)))
        n = max(2, math.ceil(max(lin / CART_STEP_MM, math.degrees(angle) / CART_STEP_DEG)) + 1)
        axis = _rotation_axis(rel, angle)
        out = [q_a]
        seed = fanuc_deg_to_model_rad(q_a, self.profile.j23_factor)
        for k in range(1, n):
            u = k / (n - 1)
            goal = np.eye(4)
            goal[:3, 3] = (ta[:3, 3] + u * (tb[:3, 3] - ta[:3, 3]))
            goal[:3, :3] = ta[:3, :3] @ _axis_angle(axis, u * angle)
            q = self._solve(goal, seed)
            if q is None:
                raise TrajectoryRefused(f"poses[{index - 1}] -> poses[{index}]: the straight line leaves the reach or "
                                        f"the held configuration {self.region.reference} at {100 * u:.0f} % of it; "
                                        f"add a pose between them that keeps it inside, or send joints")
            out.append(model_rad_to_fanuc_deg(q, self.profile.j23_factor))
            seed = q
        return np.array(out)


def _reshape(label: str) -> str:
    """The next step for a segment no timing fits: change its shape."""
    if "blended" in label:
        return "add a waypoint where it turns, or send blend=false"
    return "send it with a lower speed_scale"


def _coincident(a: np.ndarray, b: np.ndarray) -> bool:
    """The same point to within COINCIDENT_DEG on every joint."""
    return bool(np.abs(np.asarray(b) - np.asarray(a)).max() <= COINCIDENT_DEG)


def _turning_points(spline: Any) -> np.ndarray:
    """The path parameters where a joint of a cubic spline (scipy's, per span t^3 t^2 t 1 coefficients)
    turns: the roots of its derivative inside each span."""
    c3, c2, c1 = spline.c[0], spline.c[1], spline.c[2]  # (spans, joints)
    h = np.diff(spline.x)[:, None]
    a, b = 3.0 * c3, 2.0 * c2
    disc = np.sqrt(np.maximum(b * b - 4.0 * a * c1, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        quadratic = [(-b + disc) / (2.0 * a), (-b - disc) / (2.0 * a)]
        t = np.stack([*(np.where(np.abs(a) > 1e-12, r, -c1 / b) for r in quadratic)])
    ok = np.isfinite(t) & (t > 0.0) & (t < h)
    return (spline.x[:-1][None, :, None] + t)[ok]  # type: ignore[no-any-return]


def _densify_line(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A straight joint segment as three collinear knots (the spline through them is the line)."""
    return np.array([a, (a + b) / 2.0, b], dtype=float)


def _thin_indices(rows: np.ndarray, min_chord: float) -> list[int]:
    """Indices of rows at least ``min_chord`` apart (the last row always kept); repeats dropped."""
    keep = [0]
    for i in range(1, len(rows)):
        if np.linalg.norm(rows[i] - rows[keep[-1]]) >= min_chord:
            keep.append(i)
    if not np.array_equal(rows[keep[-1]], rows[-1]):
        if len(keep) > 1 and np.linalg.norm(rows[-1] - rows[keep[-1]]) < min_chord / 2:
            keep[-1] = len(rows) - 1
        else:
            keep.append(len(rows) - 1)
    return keep


def _rest_pieces(rows: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) row indices of the motions of a dense path (one row per interval), cut at each
    row where it stood still (the same row twice) or turned back (the step after it points against
    the step before). A motion shorter than DENSE_KNOT_DEG joins the one before: a creep of a few
    thousandths of a degree is no motion of its own to stop for."""
    d = np.diff(rows, axis=0)
    still = ~np.any(d != 0.0, axis=1)  # step i: rows[i] -> rows[i + 1]
    back = np.einsum("ij,ij->i", d[:-1], d[1:]) < 0.0  # at row i + 1
    cuts = sorted({i + 1 for i in np.flatnonzero(back)} | {i for i in np.flatnonzero(still)}
                  | {i + 1 for i in np.flatnonzero(still)})
    pieces: list[tuple[int, int]] = []
    start = 0
    for c in [*cuts, len(rows) - 1]:
        if c <= start:
            continue
        if np.array_equal(rows[start], rows[c]):  # stood still from start to c
            start = c
            continue
        if pieces and pieces[-1][1] == start and np.linalg.norm(rows[c] - rows[start]) < DENSE_KNOT_DEG:
            pieces[-1] = (pieces[-1][0], c)  # (a creep: part of the motion before)
        else:
            pieces.append((start, c))
        start = c
    return pieces or [(0, len(rows) - 1)]


def _reversal_pieces(pts: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) point indices of the pieces of a polyline between the points where it turns back
    (a dense path's cusps)."""
    if len(pts) < 2:
        return []
    d = np.diff(pts, axis=0)
    cos = np.einsum("ij,ij->i", d[:-1], d[1:]) / (np.linalg.norm(d[:-1], axis=1) * np.linalg.norm(d[1:], axis=1))
    cuts = (np.flatnonzero(cos < 0.0) + 1).tolist()
    pieces, start = [], 0
    for c in [*cuts, len(pts) - 1]:
        if c > start:
            pieces.append((start, c))
        start = c
    return pieces


def _recorded_pace(path: Any, ss: np.ndarray, knot_times: np.ndarray, scale: float) -> Any:
    """A TOPP-RA constraint: the path speed ds/dt at most the recorded one between the knots around s
    (the slower at a knot), as joint velocity bounds |q'(s)| * sdot_max(s) for every joint: for any
    joint that moves, |q_i' sdot| <= |q_i'| sdot_max is sdot <= sdot_max."""
    import toppra.constraint

    pace = np.diff(ss) / np.maximum(np.diff(knot_times), 1e-9) * scale  # chord per second between knots
    at_knot = np.minimum(np.concatenate([pace[:1], pace]), np.concatenate([pace, pace[-1:]]))

    def limits(s: float) -> np.ndarray:
        i = min(max(int(np.searchsorted(ss, s, side="right")) - 1, 0), len(pace))
        sdot = at_knot[i] if i == len(pace) or s == ss[i] else pace[i]
        bound = np.abs(path(s, 1)) * sdot * (1.0 + 1e-9) + 1e-12
        return np.column_stack([-bound, bound])

    return toppra.constraint.JointVelocityConstraintVarying(limits)


def _sample_constant_acceleration(grid: np.ndarray, sd: np.ndarray, dt: float) -> np.ndarray:
    """s(t) at t = 0, dt, 2dt, ... for TOPP-RA's velocities ``sd`` on ``grid`` (constant acceleration
    between grid points); ends with the last grid point."""
    ds = np.diff(grid)
    sdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2.0 * ds)
    seg_t = 2.0 * ds / np.maximum(sd[1:] + sd[:-1], 1e-12)
    t0 = np.concatenate([[0.0], np.cumsum(seg_t)])
    t = np.arange(0.0, t0[-1], dt)
    i = np.clip(np.searchsorted(t0, t, side="right") - 1, 0, len(ds) - 1)
    tau = t - t0[i]
    s = np.minimum(grid[i] + sd[i] * tau + 0.5 * sdd[i] * tau * tau, grid[i + 1])
    return np.concatenate([s, [grid[-1]]])


def _stretch(s: np.ndarray, duration_s: float, dt: float, width: int) -> np.ndarray:
    """``s`` slowed down uniformly so that it and its smoothing last ``duration_s``; refused if the
    fastest timing is longer (the caller names the segment)."""
    fastest = (len(s) - 1 + width - 1) * dt
    if duration_s + 1e-9 < fastest:
        raise TrajectoryRefused(f"needs at least {fastest:.3f} s within the limits, {duration_s:g} s given; "
                                f"give it at least {fastest:.3f} s")
    steps = max(1, round(duration_s / dt) - (width - 1))
    t_old = np.arange(len(s))
    t_new = np.linspace(0.0, len(s) - 1, steps + 1)
    return np.interp(t_new, t_old, s)


def _moving_average(s: np.ndarray, m: int) -> np.ndarray:
    """The box average of ``m`` samples, ``s`` held at its ends: starts at s[0] and ends, exactly, at s[-1]."""
    padded = np.concatenate([np.full(m - 1, s[0]), s, np.full(m - 1, s[-1])])
    c = np.concatenate([[0.0], np.cumsum(padded)])
    out = (c[m:] - c[:-m]) / m
    out[0], out[-1] = s[0], s[-1]
    out[out <= s[0]] = s[0]
    out[out >= s[-1]] = s[-1]
    return out


def _rotation_axis(rel: np.ndarray, angle: float) -> np.ndarray:
    if angle < 1e-9:
        return np.array([0.0, 0.0, 1.0])
    w = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    n = float(np.linalg.norm(w))
    if n < 1e-9:  # 180 deg: the axis from the symmetric part
        m = (rel + np.eye(3)) / 2.0
        return m[:, int(np.argmax(np.diag(m)))] / math.sqrt(max(float(np.max(np.diag(m))), 1e-12))
    return w / n


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


# ------------------------------------------------------------------------------------------- player

IDLE, PLAYING, PAUSING, PAUSED, RESUMING, DONE, ENDED = range(7)
PLAYER_STATES = ("idle", "playing", "pausing", "paused", "resuming", "done", "ended")


class ReplayPlayer:
    """Plays a checked trajectory one position per cycle, pausing and resuming along it.

    A pause asked for during a resume ramp starts when that ramp ends (and two samples have been
    played, so the pause starts from the history the planner checked); a resume asked for during a
    pause starts once the arm is at rest. Only ``ramp_steps`` odd keeps every ramp on whole samples.
    """

    def __init__(self, samples: np.ndarray, ramp_steps: int) -> None:
        if ramp_steps < 1 or ramp_steps % 2 == 0:
            raise ValueError(f"ramp_steps={ramp_steps} must be odd and positive")
        self.samples = np.ascontiguousarray(samples, dtype=np.float64)
        self.n = ramp_steps
        # The ramps' sample offsets, computed as the planner's check computes them (ramp_taus).
        self._down = ramp_taus(np.zeros(1), ramp_steps, up=False)[0]
        self._up = ramp_taus(np.zeros(1), ramp_steps, up=True)[0]
        self._ramp_from = 0.0
        self.tau = 0.0  # the sample being played (fractional during ramps)
        self.state = PLAYING
        self._ramp_i = 0
        self._played = 3  # whole samples played since the last ramp (the start counts as at rest)
        self._pause_wanted = False
        self._resume_wanted = False
        self._rest_cycles = 0

    @property
    def total(self) -> int:
        return len(self.samples)

    @property
    def index(self) -> int:
        return int(self.tau)

    @property
    def active(self) -> bool:
        return self.state in (PLAYING, PAUSING, PAUSED, RESUMING)

    def pause(self) -> None:
        if self.state == PLAYING or self.state == RESUMING:
            self._pause_wanted = True
        self._resume_wanted = False

    def resume(self) -> None:
        if self.state in (PAUSING, PAUSED):
            self._resume_wanted = True
        self._pause_wanted = False

    def end(self) -> None:
        """Another command took over, or a fast stop or fault left the path."""
        if self.active:
            self.state = ENDED

    def advance(self) -> np.ndarray:
        """The next position to send (float64 holding float32 values where on a sample)."""
        last = len(self.samples) - 1
        if self.state == PLAYING:
            if self._pause_wanted and self._played >= 2 and self.tau < last:
                self._pause_wanted = False
                self.state, self._ramp_i, self._ramp_from = PAUSING, 0, self.tau
            else:
                self.tau = min(self.tau + 1.0, last)
                self._played += 1
                if self.tau >= last:
                    self.state = DONE
                return self.samples[int(self.tau)].copy()
        if self.state == PAUSING:
            self.tau = min(self._ramp_from + self._down[self._ramp_i], last)
            self._ramp_i += 1
            if self._ramp_i >= self.n:
                self.state, self._rest_cycles = PAUSED, 0
            return to_f32(warp_position(self.samples, self.tau))
        if self.state == PAUSED:
            self._rest_cycles += 1
            if self._resume_wanted and self._rest_cycles >= 3:
                self._resume_wanted = False
                self.state, self._ramp_i, self._ramp_from = RESUMING, 0, self.tau
            else:
                return self.samples[int(self.tau)].copy()
        if self.state == RESUMING:
            self.tau = min(self._ramp_from + self._up[self._ramp_i], last)
            self._ramp_i += 1
            if self._ramp_i >= self.n:
                self.state, self._played = PLAYING, 0
                if self.tau >= last:
                    self.state = DONE
            return to_f32(warp_position(self.samples, self.tau))
        return self.samples[min(int(self.tau), last)].copy()

    @property
    def paused(self) -> bool:
        return self.state == PAUSED
