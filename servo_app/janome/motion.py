"""The Janome servo stage: live command -> the next short step to send, one per status frame.

Pure (no sockets, no clock): each call of :meth:`JanomeMotion.next_step` advances the commanded
X Y Z R by one link step of ``step_s`` through the jerk-limited :class:`JointShaper` (used here on
Cartesian axes), so consecutive steps grow and shrink smoothly. Each step is a short point-to-point
move on the robot, bounded by ``max_step_mm`` / ``max_step_deg``: that bound is the stop distance,
because a stop simply sends no further step and the robot ends the one it is doing.

The commanded state integrates from what was sent, never from the robot's reported position (the
robot reports the same value once the step is done; DESIGN.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from servo_app.errors import CommandRejected, InvalidRequest
from servo_app.janome.kinematics import AXES, UNITS, Workspace
from servo_app.janome.profile import JanomeProfile
from servo_app.janome.protocol import SCALE, Arm, Cmd, RobotKind
from servo_app.motion.commands import check_speed_scale
from servo_app.motion.shaper import JointShaper, ShaperLimits

_MOVE_EPS = 0.5 / SCALE  # below half a wire unit a step does not exist on the wire


@dataclass(frozen=True)
class Step:
    """One target for the robot: absolute X Y Z R and the speeds to get there in about ``step_s``."""

    xyzr: tuple[float, float, float, float]
    speed: float  # mm/s along the XYZ line (lineMove)
    rspeed: float  # deg/s for R (monoMove when only R moves)
    cmd: Cmd
    cond: int
    arm: int


@dataclass
class MotionSettings:
    speed_fraction: float = 0.9  # share of the profile's speeds and accelerations used
    jerk_per_s: float = 10.0  # jerk = acceleration x this (configured; the robot publishes none)
    margin: float = 0.5  # mm / deg kept inside the strokes (and SCARA joint ranges)
    move: Cmd = Cmd.LINE  # LINE (lineMove, speed from the frame) or PTP (moveAPTP, the robot's PTP condition)
    ptp_cond: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.speed_fraction <= 1.0:
            raise ValueError(f"speed_fraction={self.speed_fraction} must be in (0, 1]")
        if self.move not in (Cmd.LINE, Cmd.PTP):
            raise ValueError(f"move={self.move!r} must be Cmd.LINE or Cmd.PTP")
        if not 0 <= self.ptp_cond <= 99:
            raise ValueError(f"ptp_cond={self.ptp_cond} must be 0..99")


@dataclass(frozen=True)
class StreamSpeeds:
    """The fastest the stream commands each axis and the X Y Z line, and where each bound comes from."""

    vel: np.ndarray  # X Y Z (mm/s), R (deg/s)
    cp_speed: float  # the X Y Z line (mm/s)
    vel_source: tuple[str, ...]
    cp_source: str


def stream_speeds(profile: JanomeProfile, step_s: float, speed_fraction: float) -> StreamSpeeds:
    """The tighter, per axis, of the profile's speed (its share ``speed_fraction``) and the link's step:
    one step of at most max_step_mm / max_step_deg per ``step_s`` (100 mm/s at 10 mm per 0.1 s, for a
    profile allowing 800). What the service commands, what /api/limits reports and jogs are held to."""
    f = speed_fraction
    step = (f"the link's step: link.max_step_mm {profile.max_step_mm:g} mm per {step_s:g} s step",
            f"the link's step: link.max_step_deg {profile.max_step_deg:g} deg per {step_s:g} s step")
    vel, src = [], []
    for i, unit in enumerate(UNITS):
        by_step = (profile.max_step_deg if unit == "deg" else profile.max_step_mm) / step_s
        by_profile = profile.speed[i] * f
        vel.append(min(by_profile, by_step))
        src.append(step[unit == "deg"] if by_step < by_profile else
                   f"{f:g} of the profile's axes.speed[{i}] {profile.speed[i]:g} {unit}/s")
    cp_by_step, cp_by_profile = profile.max_step_mm / step_s, profile.cp_speed * f
    cp_source = step[0] if cp_by_step < cp_by_profile else f"{f:g} of the profile's cp.speed_mm_s {profile.cp_speed:g}"
    return StreamSpeeds(np.array(vel), min(cp_by_step, cp_by_profile), tuple(src), cp_source)


class JanomeMotion:
    def __init__(self, profile: JanomeProfile, step_s: float | None = None,
                 settings: MotionSettings | None = None) -> None:
        self.profile = profile
        self.settings = settings or MotionSettings()
        self.step_s = float(step_s or profile.step_s)
        if not 0.01 <= self.step_s <= 2.0:
            raise ValueError(f"step_s={self.step_s} must be in 0.01..2 s")
        f = self.settings.speed_fraction
        self.speeds = stream_speeds(profile, self.step_s, f)
        self.vel = self.speeds.vel
        self.acc = np.array(profile.accel) * f
        self.jerk = self.acc * self.settings.jerk_per_s
        self.cp_speed = self.speeds.cp_speed
        self.limits = ShaperLimits(self.vel, self.acc, self.jerk, fraction=1.0, fast_fraction=1.0,
                                   pos_abs_max=profile.pos_abs_max)
        self.ws: Workspace = profile.workspace(self.settings.margin)  # where commands may lead
        self.ws_hard: Workspace = profile.workspace()  # what every step is checked against
        self.shaper: JointShaper | None = None
        self.arm: int = int(profile.elbow)
        self.last: np.ndarray | None = None  # the last position sent (wire-rounded)
        self.stopped = False
        self._jog: np.ndarray | None = None
        self._target: tuple[np.ndarray, float] | None = None
        self._jog_at_limit: np.ndarray | None = None  # the jog that stopped at the envelope's edge
        # a jog target runs this far ahead: beyond the braking distance at full speed
        self._horizon = float(np.max(2.0 * (self.vel / self.acc + self.acc / self.jerk))) + self.step_s
        self.steps_sent = 0

    # ------------------------------------------------------------------ source
    def begin(self, xyzr: tuple[float, ...] | np.ndarray, arm: int) -> None:
        """Streaming starts where the robot reports it is, in its arm configuration."""
        p = np.asarray(xyzr, dtype=float)
        if self.profile.kind == RobotKind.SCARA and arm not in (Arm.RIGHTY, Arm.LEFTY):
            raise CommandRejected(f"arm={arm} from the robot is neither righty (1) nor lefty (-1)")
        self.arm = int(arm) if self.profile.kind == RobotKind.SCARA else int(Arm.RIGHTY)
        self.shaper = JointShaper(self.limits, self.step_s, p)
        self.shaper.step()  # the shaper's first output is the start itself: nothing to send
        self.last = np.round(p * SCALE) / SCALE
        self.stopped = False
        self._jog = None
        self._target = None
        self._jog_at_limit = None

    def next_step(self) -> Step | None:
        """The next target, or None when nothing moves (the session then sends HOLD)."""
        shaper = self._require()
        assert self.last is not None
        if self._jog is not None and not self.stopped:
            self._steer_jog(shaper, self._jog)
        q = np.round(shaper.step() * SCALE) / SCALE
        at_limit = False
        if self._jog is not None and self.ws.check_path(self.last, q, self.arm) is not None:
            # The jog's target is clipped to the envelope, but it is found again from each new position
            # and can creep back while the shaper brakes to it: the shaper then overshoots it (JS3 along
            # the outer reach, where 0.5 deg of J2 is 0.03 mm, by up to 0.05 mm: past the hard limit).
            # The jog has reached the limit: this step ends on it and the jog stops there.
            clipped = np.round(self.ws.clip_segment(self.last, q, self.arm) * SCALE) / SCALE
            at_limit = not np.array_equal(clipped, q)
            q = clipped
        d = q - self.last
        if np.all(np.abs(d) < _MOVE_EPS):
            if at_limit:
                self._stop_at_limit()
            return None
        why = self.ws_hard.check_path(self.last, q, self.arm)
        if why is not None:  # never expected: targets and jogs are clipped to the workspace
            self.stop()
            raise CommandRejected(f"step refused: {why.message}")
        lin = float(np.linalg.norm(d[:3]))
        speed = min(max(lin / self.step_s, 0.1), self.profile.cp_speed) if lin >= _MOVE_EPS else 0.0
        rspeed = min(max(abs(float(d[3])) / self.step_s, 0.1), self.profile.speed[3]) \
            if abs(d[3]) >= _MOVE_EPS else 0.0
        self.last = q
        self.steps_sent += 1
        if at_limit:
            self._stop_at_limit()
        s = self.settings
        return Step((float(q[0]), float(q[1]), float(q[2]), float(q[3])), speed, rspeed, s.move, s.ptp_cond, self.arm)

    def request_rest(self) -> None:
        if self.shaper is not None:
            self.stop()

    def at_rest(self) -> bool:
        return self.shaper is None or self.shaper.at_rest

    # ---------------------------------------------------------------- commands
    def check_target(self, xyzr: np.ndarray, speed_scale: float = 1.0, name: str = "joints") -> np.ndarray:
        """The target X Y Z R if it is in the work envelope (and, while streaming, the straight path to
        it too); else InvalidRequest naming the axis and its stroke. Changes nothing."""
        p = self._checked(xyzr, name)
        check_speed_scale(speed_scale)
        why = self.ws.check(p, self.arm)
        if why is not None:
            raise InvalidRequest(f"target refused: {why.message}")
        if self.last is not None:
            why = self.ws_hard.check_path(self.last, p, self.arm)
            if why is not None:
                raise InvalidRequest(f"target refused: the straight path from the current position leaves the "
                                     f"work envelope: {why.message}")
        return p

    def set_target(self, xyzr: np.ndarray, speed_scale: float = 1.0) -> None:
        shaper = self._require()
        p = self.check_target(xyzr, speed_scale)
        self._target, self._jog, self._jog_at_limit = (p, float(speed_scale)), None, None
        self.stopped = False
        shaper.set_target(p, float(speed_scale))

    def jog(self, v: np.ndarray) -> None:
        """Jog at X Y Z R velocities (mm/s, deg/s); the XYZ speed is capped at the CP speed, keeping the
        direction, and the jog brakes to rest at the work envelope's edge. Requests over the speeds were
        refused before (JanomeSupervisor); a device's input is scaled down here."""
        v = self._checked(v, "joints")
        self._require()
        lin = float(np.linalg.norm(v[:3]))
        over = max(1.0, lin / self.cp_speed, float(np.max(np.abs(v) / self.vel)))
        v = v / over
        if self._jog_at_limit is not None and np.array_equal(v, self._jog_at_limit):
            return  # the held jog renewed: it stays stopped at the limit (from rest it would crawl on)
        self._jog, self._target, self._jog_at_limit = v, None, None
        self.stopped = False

    def stop(self, fast: bool = False) -> None:
        """Send no further step: the robot finishes the step it has (at most max_step) and stays.
        Soft and fast stops are the same here; a fast one only needs acknowledging (the state machine)."""
        self.stopped = True
        self._jog = None
        self._jog_at_limit = None
        if self.shaper is None or self.last is None:
            return
        shaper = self.shaper
        shaper.reseed(self.last)
        shaper.step()  # consume the re-seed's echo of the position

    def resume(self) -> None:
        self.stopped = False
        if self._target is not None and self.shaper is not None:
            self.shaper.set_target(*self._target)

    # ----------------------------------------------------------------- helpers
    def _steer_jog(self, shaper: JointShaper, v: np.ndarray) -> None:
        scale = float(np.max(np.abs(v) / self.vel))
        if scale <= 1e-9:
            if not shaper.at_rest and shaper.mode != "stop-soft":
                shaper.stop("soft")
            return
        p = shaper.state[0]
        ahead = self.ws.clip_segment(p, p + v * self._horizon, self.arm)
        shaper.set_target(ahead, min(scale, 1.0))

    def _stop_at_limit(self) -> None:
        jog = self._jog
        self.stop()  # (re-seeds the shaper at the last step: the robot ends it and stays)
        self._jog_at_limit = jog

    def _require(self) -> JointShaper:
        if self.shaper is None:
            raise CommandRejected("not streaming: no motion command is accepted yet")
        return self.shaper

    @staticmethod
    def _checked(values: np.ndarray, name: str) -> np.ndarray:
        v = np.asarray(values, dtype=float).reshape(-1)
        if v.shape != (4,):
            raise InvalidRequest(f"{name} has {v.size} values, expected 4 (X, Y, Z, R)")
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            i = int(bad[0])
            raise InvalidRequest(f"{name}[{i}] ({AXES[i]})={v[i]} {UNITS[i]} is not a finite number")
        return v
