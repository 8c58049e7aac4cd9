"""The controller's limit check of a command stream (manual 61.5 notes 2-3, FAQ, Appendix B).

Pure, no I/O, a few numpy operations on 6-vectors per cycle: the simulator runs it every 4-8 ms
and ``servo-app check`` runs it over recorded trajectories.

What is checked, per command ``q_k`` (FANUC joint convention, degrees, axes 1-6; extended axes are
never checked, manual 61.5):

- finite differences over the FIXED interval ``dt`` (note 2): ``v_k = (q_k - q_{k-1}) / dt``,
  ``a_k = (v_k - v_{k-1}) / dt``, ``j_k = (a_k - a_{k-1}) / dt``. Positions before the first command
  equal the first command (FAQ), so the first command has v = a = j = 0;
- velocity against the constant velocity table, every cycle: MOTN-609, warning MOTN-612;
- acceleration and jerk per Appendix B, with the flange-centre speed ``s_k`` from consecutive
  commanded positions (the injected flange function):

  * every sample is checked at once against the stage-1 limit (the limit at Vmax/20): note 2,
    "whenever the limit value at Vmax/20 is exceeded, the robot will stop immediately";
  * a sample with ``s_k > Vmax/20`` belongs to a *window*; the window tracks Vpeak and the per-axis
    maxima of |a| and |j| (with the sequence number where each occurred). The first sample with
    ``s_k <= Vmax/20`` closes the window, which is then judged against the limits at Vpeak (that
    sample itself is judged at stage 1, its own speed domain);
  * while a window stays open, a tentative judgment at Vpeak-so-far every intermediate check time;
  * MOTN-610 / MOTN-611, warnings MOTN-613 / MOTN-614 at $WARN_LIM % of the same limits;

- if several limits are exceeded at one judgment, only the largest excess is reported (note 3),
  excess = |value| / limit;
- MOTN-617 (discontinuous command): the first command farther than ``first_jump_cycles`` cycles at
  the velocity limit from the controller's command position on any axis (the FAQ rule hides this
  step from v/a/j, so this is the only check that sees it); a later command that moves any axis more
  than ``jump_cycles`` (default 2) cycles at its velocity limit. Between 1x and 2x the velocity
  check (MOTN-609) reports it instead;
- joint position limits: the model-convention range of the profile after the J2/J3 conversion
  (``q3_model = J3 + j23_factor * J2``). The manual only says "the robot will stop with an alarm";
  we report FANUC's general joint-limit alarm MOTN-017 "Limit error" (not in chapter 61.9; its text
  is in the FANUC alarm catalogue with the other codes);
- offline only (``check_max_spd=True``): flange speed above $MAX_SPD as violation CHK-001. The
  controller has no such alarm (its limits just extrapolate down above Vmax), a planner should
  never go there.

Warnings are edge-triggered per axis and type (re-armed when the value falls back below the
threshold, or once per window), so they never flood. Alarms are edge-triggered the same way, which
only matters offline: on a controller the first alarm stops the robot.

A :class:`Violation` carries the code and the numbers, no text: the controller's one-line rendering
is the alarm catalogue's (``format_violation`` beside ``format_alarm`` in the FANUC backend).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from servo_app.motion.limit_tables import ACC, JERK, VEL, LimitTables, evaluate_stages
from servo_app.robots.profile import RobotProfile

FlangeFn = Callable[[np.ndarray], np.ndarray]  # FANUC joints (deg) -> flange centre XYZ (mm)

N_ARM = 6
KINDS = ("velocity", "acceleration", "jerk")
ALARM_CODE = ("MOTN-609", "MOTN-610", "MOTN-611")
WARN_CODE = ("MOTN-612", "MOTN-613", "MOTN-614")
NAN_CODE = "MOTN-605"
JUMP_CODE = "MOTN-617"
POSITION_CODE = "MOTN-017"
MAX_SPD_CODE = "CHK-001"


@dataclass(frozen=True)
class Violation:
    """One alarm or warning found in a command stream.

    ``seq`` is the command where the value occurred (what the controller's alarm text names);
    ``detected_seq`` the command at which it was judged (later for Appendix B windows, note 1).
    ``limit`` is the allowable limit itself, also for warnings (posted above $WARN_LIM % of it).
    ``value`` and ``limit`` are in deg/s, deg/s^2, deg/s^3 (position: deg; jump: deg per cycle;
    flange speed: mm/s). ``flange_speed`` is the Vpeak used for a window judgment.
    """

    code: str
    kind: str
    axis: int | None
    seq: int | None
    value: float
    limit: float
    warning: bool = False
    detected_seq: int | None = None
    flange_speed: float | None = None

    @property
    def excess(self) -> float:
        return abs(self.value) / self.limit if self.limit > 0 else math.inf


@dataclass
class Usage:
    """Peak usage over the stream: ``ratio[type, axis]`` = max |value| / applicable limit.

    Rows are velocity, acceleration, jerk (limit_tables.VEL/ACC/JERK). For acceleration and jerk the
    applicable limit is the one the controller judged against (stage 1, or the window's Vpeak limit).
    """

    ratio: np.ndarray = field(default_factory=lambda: np.zeros((3, N_ARM)))
    peak: np.ndarray = field(default_factory=lambda: np.zeros((3, N_ARM)))  # max |value|
    ratio_seq: np.ndarray = field(default_factory=lambda: np.full((3, N_ARM), -1, dtype=np.int64))
    max_flange_speed: float = 0.0
    steps: int = 0


def _seq_or_none(s: int) -> int | None:
    return None if s < 0 else int(s)


class ControllerLimitChecker:
    """Checks commanded joint positions one cycle at a time, as the controller does.

    ``flange_xyz_mm(q_fanuc_deg) -> xyz mm`` gives the flange-centre position; without it the flange
    speed is taken as 0 and acceleration/jerk are judged at the stage-1 limit only.
    """

    def __init__(
        self,
        tables: LimitTables,
        interval_s: float,
        flange_xyz_mm: FlangeFn | None = None,
        *,
        payload_kg: float | None = None,
        warn_lim_pct: float = 80.0,
        joint_min_deg: Sequence[float] | None = None,
        joint_max_deg: Sequence[float] | None = None,
        j23_factor: float = 1.0,
        first_jump_cycles: float = 1.0,
        jump_cycles: float = 2.0,
        check_max_spd: bool = True,
    ) -> None:
        if interval_s <= 0:
            raise ValueError(f"interval_s={interval_s} must be > 0")
        self.tables = tables
        self.dt = float(interval_s)
        self.flange_xyz_mm = flange_xyz_mm
        self.warn_frac = warn_lim_pct / 100.0
        self.j23_factor = j23_factor
        self.check_max_spd = check_max_spd
        n = min(tables.n_axes, N_ARM)
        self.n = n
        self.vmax = float(tables.vmax)
        self.s_low = self.vmax / 20.0
        self._jump_cycles = (first_jump_cycles, jump_cycles)
        self.set_payload(payload_kg)
        self.q_min = None if joint_min_deg is None else np.asarray(joint_min_deg, float)[:n]
        self.q_max = None if joint_max_deg is None else np.asarray(joint_max_deg, float)[:n]
        self.n_check = max(1, round(tables.check_time_s / self.dt))
        self.reset()

    def set_payload(self, payload_kg: float | None) -> None:
        """Judge against the tables at this payload (None: the maximum), as a controller does after a
        PAYLOAD instruction changed its payload schedule."""
        self.payload_kg = payload_kg
        n = self.n
        # Stage values for this payload, once: the hot path only evaluates them at Vpeak.
        self._stages = [self.tables.stage_values(k, payload_kg)[:n] for k in (VEL, ACC, JERK)]
        self.vel_lim = self._stages[VEL][:, 0].copy()
        self.acc1 = self._stages[ACC][:, 0].copy()
        self.jrk1 = self._stages[JERK][:, 0].copy()
        self.first_jump = self.vel_lim * self.dt * self._jump_cycles[0]
        self.jump = self.vel_lim * self.dt * self._jump_cycles[1]

    def set_tables(self, tables: LimitTables) -> None:
        """Judge against these tables from now on (at the current payload): a controller that published
        other tables at a later stream's start (one log can span several streams)."""
        self.tables = tables
        self.vmax = float(tables.vmax)
        self.s_low = self.vmax / 20.0
        self.n_check = max(1, round(tables.check_time_s / self.dt))
        self.set_payload(self.payload_kg)

    @classmethod
    def for_profile(cls, profile: RobotProfile, flange_xyz_mm: FlangeFn | None = None, *,
                    tables: LimitTables | None = None, interval_s: float | None = None,
                    **kwargs: float | bool | None) -> ControllerLimitChecker:
        """A checker with the profile's interval, joint ranges and J2/J3 factor (tables default to
        ``default_tables(profile)``)."""
        from servo_app.motion.limit_tables import default_tables

        return cls(tables if tables is not None else default_tables(profile),
                   interval_s if interval_s is not None else profile.interval_s, flange_xyz_mm,
                   joint_min_deg=profile.joint_min_deg, joint_max_deg=profile.joint_max_deg,
                   j23_factor=profile.j23_factor, **kwargs)  # type: ignore[arg-type]

    # ---- state ----------------------------------------------------------------------------------

    def reset(self, start_q_deg: Sequence[float] | np.ndarray | None = None) -> None:
        """Start a new stream. ``start_q_deg``: the controller's command position (for MOTN-617 on the
        first command); None skips that check (offline, the start position is unknown)."""
        n = self.n
        self.start_q = None if start_q_deg is None else np.asarray(start_q_deg, float)[:n].copy()
        self.q = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self.j = np.zeros(n)
        self.p = np.zeros(3)
        self.flange_speed = 0.0
        self.started = False
        self.last_seq: int | None = None
        self.usage = Usage(ratio=np.zeros((3, n)), peak=np.zeros((3, n)),
                           ratio_seq=np.full((3, n), -1, dtype=np.int64))
        # Edge-trigger state: True while a value is above the alarm / warning threshold.
        self._alarm_on = np.zeros((3, n), dtype=bool)
        self._warn_on = np.zeros((3, n), dtype=bool)
        self._pos_on = np.zeros(n, dtype=bool)
        self._jump_on = False
        self._spd_on = False
        self._close_window()

    def _close_window(self) -> None:
        n = self.n
        self.window_open = False
        self.vpeak = 0.0
        self._win_max = np.zeros((2, n))  # |a|, |j|
        self._win_seq = np.full((2, n), -1, dtype=np.int64)
        self._win_count = 0
        self._win_alarmed = np.zeros((2, n), dtype=bool)
        self._win_warned = np.zeros((2, n), dtype=bool)

    @property
    def velocity(self) -> np.ndarray:
        return self.v

    @property
    def acceleration(self) -> np.ndarray:
        return self.a

    @property
    def jerk(self) -> np.ndarray:
        return self.j

    def limits_at(self, flange_speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vel, acc, jerk) limits at a flange speed for the configured payload (Appendix B)."""
        return (self.vel_lim, evaluate_stages(self._stages[ACC], flange_speed, self.vmax),
                evaluate_stages(self._stages[JERK], flange_speed, self.vmax))

    # ---- one cycle ------------------------------------------------------------------------------

    def step(self, q_deg: Sequence[float] | np.ndarray, seq: int | None = None) -> list[Violation]:
        """Check one command; returns the alarms (at most one, the largest excess) and warnings."""
        n = self.n
        q = np.asarray(q_deg, dtype=float)[:n]
        out: list[Violation] = []
        s = -1 if seq is None else seq
        if not np.all(np.isfinite(q)):
            axis = int(np.flatnonzero(~np.isfinite(q))[0]) + 1
            out.append(Violation(NAN_CODE, "non_finite", axis, seq, float(q[axis - 1]), 0.0,
                                 detected_seq=seq))
            return out  # state untouched: the controller never uses such a command
        self.usage.steps += 1
        jump_alarm: Violation | None = None
        if not self.started:
            self.started = True
            self.q = q.copy()
            self.v[:] = 0.0
            self.a[:] = 0.0
            self.j[:] = 0.0
            self.p = self._flange(q)
            self.flange_speed = 0.0
            if self.start_q is not None:
                jump_alarm = self._jump(np.abs(q - self.start_q), self.first_jump, seq)
        else:
            dq = q - self.q
            jump_alarm = self._jump(np.abs(dq), self.jump, seq)
            v = dq / self.dt
            a = (v - self.v) / self.dt
            self.j = (a - self.a) / self.dt
            self.a = a
            self.v = v
            self.q = q.copy()
            p = self._flange(q)
            self.flange_speed = float(np.linalg.norm(p - self.p)) / self.dt
            self.p = p
        self.last_seq = seq

        candidates: list[Violation] = []  # alarms competing for note 3 (largest excess wins)
        self._velocity(s, seq, candidates, out)
        absa, absj = np.abs(self.a), np.abs(self.j)
        high = self.flange_speed > self.s_low
        if high:
            self._window_add(absa, absj, s)
        elif self.window_open:  # speed fell back to Vmax/20: judge the window at its Vpeak
            self._judge(seq, candidates, out)
            self._close_window()
        self._immediate(absa, absj, s, seq, candidates, out, in_window=high)
        if high and self._win_count % self.n_check == 0:  # tentative judgment (intermediate check)
            self._judge(seq, candidates, out)
        if self.usage.max_flange_speed < self.flange_speed:
            self.usage.max_flange_speed = self.flange_speed
        if self.check_max_spd:
            over = self.flange_speed > self.vmax
            if over and not self._spd_on:
                out.append(Violation(MAX_SPD_CODE, "flange_speed", None, seq, self.flange_speed, self.vmax,
                                     detected_seq=seq))
            self._spd_on = over

        # One alarm per cycle, by precedence: discontinuity, position, then the largest excess.
        position_alarm = self._position(q, seq)
        alarm = jump_alarm or position_alarm
        if alarm is None and candidates:
            alarm = max(candidates, key=lambda c: c.excess)
        if alarm is not None:
            out.insert(0, alarm)
        return out

    def finish(self, seq: int | None = None) -> list[Violation]:
        """End of the stream: judge a window that is still open (e.g. the last data came at speed)."""
        candidates: list[Violation] = []
        out: list[Violation] = []
        if self.window_open:
            self._judge(seq if seq is not None else self.last_seq, candidates, out)
            self._close_window()
        if candidates:
            out.insert(0, max(candidates, key=lambda c: c.excess))
        return out

    # ---- pieces ---------------------------------------------------------------------------------

    def _flange(self, q: np.ndarray) -> np.ndarray:
        if self.flange_xyz_mm is None:
            return np.zeros(3)
        return np.asarray(self.flange_xyz_mm(q), dtype=float)

    def _jump(self, dist: np.ndarray, threshold: np.ndarray, seq: int | None) -> Violation | None:
        ratio = dist / threshold
        axis = int(np.argmax(ratio))
        over = bool(ratio[axis] > 1.0)
        hit = over and not self._jump_on
        self._jump_on = over
        if not hit:
            return None
        return Violation(JUMP_CODE, "discontinuity", axis + 1, seq, float(dist[axis]),
                         float(threshold[axis]), detected_seq=seq)

    def _position(self, q: np.ndarray, seq: int | None) -> Violation | None:
        if self.q_min is None or self.q_max is None:
            return None
        qm = q.copy()
        if self.n > 2:
            qm[2] += self.j23_factor * q[1]
        below, above = self.q_min - qm, qm - self.q_max
        over = np.maximum(below, above)
        outside = over > 0.0
        new = outside & ~self._pos_on
        self._pos_on = outside
        if not new.any():
            return None
        axis = int(np.argmax(np.where(new, over, -np.inf)))
        limit = self.q_min[axis] if below[axis] > 0 else self.q_max[axis]
        return Violation(POSITION_CODE, "position", axis + 1, seq, float(qm[axis]), float(limit),
                         detected_seq=seq)

    def _velocity(self, s: int, seq: int | None, candidates: list[Violation], out: list[Violation]) -> None:
        ratio = np.abs(self.v) / self.vel_lim
        self._track(VEL, ratio, np.abs(self.v), s)
        self._edges(VEL, ratio, self.vel_lim, self.v, seq, candidates, out, warn=True)

    def _immediate(self, absa: np.ndarray, absj: np.ndarray, s: int, seq: int | None,
                   candidates: list[Violation], out: list[Violation], *, in_window: bool) -> None:
        """Note 2: every sample against the stage-1 limit; outside windows this is the judgment."""
        ra, rj = absa / self.acc1, absj / self.jrk1
        if not in_window:
            self._track(ACC, ra, absa, s)
            self._track(JERK, rj, absj, s)
        for k, ratio, lim, val in ((ACC, ra, self.acc1, self.a), (JERK, rj, self.jrk1, self.j)):
            self._edges(k, ratio, lim, val, seq, candidates, out, warn=not in_window)
            if in_window:  # do not report the same maximum again at the window's judgment
                self._win_alarmed[k - 1] |= ratio > 1.0

    def _edges(self, k: int, ratio: np.ndarray, lim: np.ndarray, val: np.ndarray, seq: int | None,
               candidates: list[Violation], out: list[Violation], *, warn: bool) -> None:
        over = ratio > 1.0
        if over.any():
            for i in np.flatnonzero(over & ~self._alarm_on[k]):
                candidates.append(Violation(ALARM_CODE[k], KINDS[k], int(i) + 1, seq, float(val[i]),
                                            float(lim[i]), detected_seq=seq))
        self._alarm_on[k] = over
        if not warn:
            return
        near = ratio > self.warn_frac
        if near.any():
            for i in np.flatnonzero(near & ~over & ~self._warn_on[k]):
                out.append(Violation(WARN_CODE[k], KINDS[k], int(i) + 1, seq, float(val[i]),
                                     float(lim[i]), warning=True, detected_seq=seq))
        self._warn_on[k] = near

    def _window_add(self, absa: np.ndarray, absj: np.ndarray, s: int) -> None:
        """A sample above Vmax/20: open a window if needed, track Vpeak and the maxima."""
        if not self.window_open:
            self._close_window()  # fresh maxima, Vpeak = 0
            self.window_open = True
        self.vpeak = max(self.vpeak, self.flange_speed)
        for row, val in ((0, absa), (1, absj)):
            upd = val > self._win_max[row]
            if upd.any():
                self._win_max[row][upd] = val[upd]
                self._win_seq[row][upd] = s
        self._win_count += 1

    def _judge(self, seq: int | None, candidates: list[Violation], out: list[Violation]) -> None:
        """Judge the window's maxima against the limits at Vpeak."""
        _, lim_a, lim_j = self.limits_at(self.vpeak)
        for row, k, lim in ((0, ACC, lim_a), (1, JERK, lim_j)):
            vals = self._win_max[row]
            ratio = np.divide(vals, lim, out=np.full_like(vals, np.inf), where=lim > 0)
            upd = ratio > self.usage.ratio[k]
            if upd.any():
                self.usage.ratio[k][upd] = ratio[upd]
                self.usage.ratio_seq[k][upd] = self._win_seq[row][upd]
            np.maximum(self.usage.peak[k], vals, out=self.usage.peak[k])
            over = ratio > 1.0
            for i in np.flatnonzero(over & ~self._win_alarmed[row]):
                candidates.append(Violation(ALARM_CODE[k], KINDS[k], int(i) + 1,
                                            _seq_or_none(self._win_seq[row][i]), float(vals[i]),
                                            float(lim[i]), detected_seq=seq, flange_speed=self.vpeak))
            self._win_alarmed[row] |= over
            near = (ratio > self.warn_frac) & ~over & ~self._win_warned[row]
            for i in np.flatnonzero(near):
                out.append(Violation(WARN_CODE[k], KINDS[k], int(i) + 1, _seq_or_none(self._win_seq[row][i]),
                                     float(vals[i]), float(lim[i]), warning=True,
                                     detected_seq=seq, flange_speed=self.vpeak))
            self._win_warned[row] |= near | over

    def _track(self, k: int, ratio: np.ndarray, val: np.ndarray, s: int) -> None:
        u = self.usage
        upd = ratio > u.ratio[k]
        if upd.any():
            u.ratio[k][upd] = ratio[upd]
            u.ratio_seq[k][upd] = s
        np.maximum(u.peak[k], val, out=u.peak[k])


def check_trajectory(checker: ControllerLimitChecker, rows: np.ndarray,
                     seqs: Sequence[int] | None = None) -> list[Violation]:
    """Run a whole (N, >=6) array of FANUC joints (deg) through ``checker``; all records in order."""
    found: list[Violation] = []
    for i, q in enumerate(rows):
        found.extend(checker.step(q, seqs[i] if seqs is not None else i + 1))
    found.extend(checker.finish(seqs[-1] if seqs is not None and len(seqs) else len(rows)))
    return found
