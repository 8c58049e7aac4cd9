"""The servo cycle's motion stage: live command -> jerk-limited next joint position.

Pure: no sockets, no threads, no clock (time advances by the fixed interval per command). It keeps
the *commanded* joint state (FANUC convention, degrees) and never reads the servo position after the
start. Commands arrive from the runner (which got them from the API process):

- joint target (absolute, FANUC deg) with a speed scale;
- joint jog (deg/s per axis) with a hold-to-run time: when no renewal comes in time, it decelerates;
- stop (soft: resumable; fast: shortest stop) and resume.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from servo_app.fanuc.packets import Status
from servo_app.motion.limit_tables import LimitTables, default_tables
from servo_app.motion.shaper import JointShaper, ShaperLimits
from servo_app.robots.conventions import fanuc_deg_to_model_rad
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
        self.t = 0.0
        self.shaper: JointShaper | None = None
        self.limits: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._hold_until: float | None = None
        self._stopped = False
        self._paused_goal: tuple[str, np.ndarray, float] | None = None
        self._goal: tuple[str, np.ndarray, float] | None = None
        self.tables_source = "profile"

    # ------------------------------------------------------------ MotionSource
    def begin(self, q_start: np.ndarray, tables: LimitTables | None) -> None:
        if tables is None:
            tables = default_tables(self.profile)
        else:
            self.tables_source = "controller"
        cap = self.settings.flange_speed_cap or tables.vmax
        vel, acc, jerk = tables.for_cap(cap, self.settings.payload_kg)
        n = self.profile.dof
        self.limits = (vel[:n], acc[:n], jerk[:n])
        self.shaper = JointShaper(ShaperLimits(vel[:n], acc[:n], jerk[:n], fraction=self.settings.limit_fraction),
                                  self.dt, np.asarray(q_start[:n], dtype=float))
        self.t = 0.0
        self._hold_until = None
        self._stopped = False
        self._goal = None

    def next_command(self, status: Status) -> np.ndarray:
        shaper = self._require()
        self.t += self.dt
        if self._hold_until is not None and self.t > self._hold_until:
            self._hold_until = None
            self._goal = None
            shaper.stop("soft")
        return shaper.step()

    def request_rest(self) -> None:
        self.stop(fast=False)

    def at_rest(self) -> bool:
        return self.shaper is None or self.shaper.at_rest

    # --------------------------------------------------------------- commands
    def set_joint_target(self, q_fanuc_deg: np.ndarray, speed_scale: float = 1.0) -> None:
        q = self._checked_position(q_fanuc_deg)
        if not 0.0 < speed_scale <= 1.0 or not np.isfinite(speed_scale):
            raise CommandRejected(f"speed_scale={speed_scale} must be in (0, 1]")
        self._goal = ("target", q, speed_scale)
        self._hold_until = None
        if not self._stopped:
            self._require().set_target(q, speed_scale)

    def jog_joints(self, v_deg_s: np.ndarray, hold_s: float) -> None:
        v = np.asarray(v_deg_s, dtype=float)
        n = self.profile.dof
        if v.shape != (n,):
            raise CommandRejected(f"joints has {v.size} values, expected {n}")
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise CommandRejected(f"joints[{bad[0]}]={v[bad[0]]} is not a finite number")
        if not 0.0 < hold_s <= 2.0:
            raise CommandRejected(f"hold_s={hold_s} must be in (0, 2]")
        vmax = self.limits[0] * self.settings.limit_fraction if self.limits else np.inf
        v = np.clip(v, -vmax, vmax)
        self._goal = ("velocity", v, 1.0)
        self._hold_until = self.t + hold_s
        if not self._stopped:
            self._require().set_velocity(self._range_guarded_velocity(v))

    def stop(self, fast: bool = False) -> None:
        shaper = self._require()
        self._stopped = True
        self._hold_until = None
        shaper.stop("fast" if fast else "soft")

    def resume(self) -> None:
        self._stopped = False

    # ----------------------------------------------------------------- helpers
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
        lo = np.asarray(self.profile.joint_min_deg) + self.settings.joint_margin_deg
        hi = np.asarray(self.profile.joint_max_deg) - self.settings.joint_margin_deg
        out = np.flatnonzero((q_model < lo) | (q_model > hi))
        if out.size:
            i = out[0]
            raise CommandRejected(
                f"joints[{i}]={q[i]:.3f} deg (J{i + 1} {q_model[i]:.3f} deg in model convention) is outside "
                f"the joint range [{lo[i]:.1f}, {hi[i]:.1f}]"
            )
        return q

    def _range_guarded_velocity(self, v: np.ndarray) -> np.ndarray:
        return v
