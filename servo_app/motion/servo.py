"""The servo cycle's motion stage: live command -> jerk-limited next joint position.

Pure: no sockets, no threads, no clock (time advances by the fixed interval per command). It keeps
the *commanded* joint state (FANUC convention, degrees) and never reads the servo position after the
start. Commands arrive from the runner (which got them from the API process):

- joint target (absolute, FANUC deg) with a speed scale;
- joint jog (deg/s per axis); hold-to-run is the supervisor's (it calls ``stop`` when the hold runs out);
- stop (soft: resumable; fast: shortest stop) and resume.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from servo_app.fanuc.packets import Status
from servo_app.motion.limit_tables import LimitTables, default_tables
from servo_app.motion.shaper import JointShaper, ShaperLimits
from servo_app.robots.conventions import fanuc_deg_to_model_rad, model_rad_to_fanuc_deg
from servo_app.robots.profile import RobotProfile


class CommandRejected(ValueError):
    """A motion command that cannot be executed; the message names the field and the value."""


@dataclass
class ServoSettings:
    limit_fraction: float = 0.9  # share of the controller's limits the shaper may use
    flange_speed_cap: float | None = None  # mm/s; None: the profile's $MAX_SPD
    payload_kg: float | None = None  # None: the controller assumes max payload (Appendix B)
    joint_margin_deg: float = 0.5  # keep this far inside the joint ranges


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
        lo = np.asarray(profile.joint_min_deg) + self.settings.joint_margin_deg
        hi = np.asarray(profile.joint_max_deg) - self.settings.joint_margin_deg
        self._range_model_deg = (lo, hi)

    # ------------------------------------------------------------ MotionSource
    def begin(self, q_start: np.ndarray, tables: LimitTables | None) -> None:
        if tables is None:
            tables = default_tables(self.profile)
            self.tables_source = "profile"
        else:
            self.tables_source = "controller"
        cap = self.settings.flange_speed_cap or tables.vmax
        vel, acc, jerk = (x[: self.profile.dof] for x in tables.for_cap(cap, self.settings.payload_kg))
        self.limits = (vel, acc, jerk)
        self.shaper = JointShaper(ShaperLimits(vel, acc, jerk, fraction=self.settings.limit_fraction),
                                  self.dt, np.asarray(q_start[: self.profile.dof], dtype=float))
        # A jog target runs this far ahead: always beyond the braking distance at full speed.
        self._horizon = float(np.max(2.0 * (vel / acc + acc / jerk))) + 0.1
        self.stopped = False
        self._target = None
        self._jog = None

    def next_command(self, status: Status) -> np.ndarray:
        shaper = self._require()
        if self._jog is not None and not self.stopped:
            self._steer_jog(shaper, self._jog)
        return shaper.step()

    def request_rest(self) -> None:
        if self.shaper is not None and not self.shaper.at_rest:
            self.stop(fast=False)

    def at_rest(self) -> bool:
        return self.shaper is None or self.shaper.at_rest

    # --------------------------------------------------------------- commands
    def set_joint_target(self, q_fanuc_deg: np.ndarray, speed_scale: float = 1.0) -> None:
        q = self._checked_position(q_fanuc_deg)
        if not (np.isfinite(speed_scale) and 0.0 < speed_scale <= 1.0):
            raise CommandRejected(f"speed_scale={speed_scale} must be in (0, 1]")
        shaper = self._require()
        self._target, self._jog = (q, speed_scale), None
        self.stopped = False
        shaper.set_target(q, speed_scale)

    def jog_joints(self, v_deg_s: np.ndarray) -> None:
        """Jog at joint velocities (deg/s): a target kept ahead in the jog direction, clipped to the ranges,
        so the shaper brakes to rest at a joint limit instead of running into it."""
        v = np.asarray(v_deg_s, dtype=float)
        n = self.profile.dof
        if v.shape != (n,):
            raise CommandRejected(f"joints has {v.size} values, expected {n}")
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise CommandRejected(f"joints[{bad[0]}]={v[bad[0]]} is not a finite number")
        self._require()
        self._jog, self._target = v, None
        self.stopped = False

    def stop(self, fast: bool = False) -> None:
        shaper = self._require()
        self.stopped = True
        self._jog = None
        shaper.stop("fast" if fast else "soft")

    def resume(self) -> None:
        """Continue after a soft stop: towards the target that was interrupted, if any."""
        self.stopped = False
        if self._target is not None and self.shaper is not None:
            self.shaper.set_target(*self._target)

    # ----------------------------------------------------------------- helpers
    def _steer_jog(self, shaper: JointShaper, v: np.ndarray) -> None:
        vmax = shaper.limits.scaled("soft")[0]
        scale = float(np.max(np.abs(v) / vmax))
        if scale <= 1e-9:
            if not shaper.at_rest and shaper.mode != "stop-soft":
                shaper.stop("soft")
            return
        q = shaper.state[0]
        ahead = q + v * self._horizon
        shaper.set_target(self._clip_to_range(ahead), min(scale, 1.0))

    def _clip_to_range(self, q_fanuc_deg: np.ndarray) -> np.ndarray:
        j23 = self.profile.j23_factor
        q_model = np.degrees(fanuc_deg_to_model_rad(q_fanuc_deg, j23))
        lo, hi = self._range_model_deg
        clipped = np.radians(np.clip(q_model, lo, hi))
        return model_rad_to_fanuc_deg(clipped, j23)

    def _require(self) -> JointShaper:
        if self.shaper is None:
            raise CommandRejected("not streaming: no motion command is accepted yet")
        return self.shaper

    def _checked_position(self, q_fanuc_deg: np.ndarray) -> np.ndarray:
        q = np.asarray(q_fanuc_deg, dtype=float)
        n = self.profile.dof
        if q.shape != (n,):
            raise CommandRejected(f"joints has {q.size} values, expected {n}")
        bad = np.flatnonzero(~np.isfinite(q))
        if bad.size:
            raise CommandRejected(f"joints[{bad[0]}]={q[bad[0]]} is not a finite number")
        q_model = np.degrees(fanuc_deg_to_model_rad(q, self.profile.j23_factor))
        lo, hi = self._range_model_deg
        out = np.flatnonzero((q_model < lo) | (q_model > hi))
        if out.size:
            i = out[0]
            raise CommandRejected(
                f"joints[{i}]={q[i]:.3f} deg (J{i + 1} = {q_model[i]:.3f} deg in model convention) is outside "
                f"the joint range [{lo[i]:.1f}, {hi[i]:.1f}]"
            )
        return q
