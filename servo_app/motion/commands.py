"""Motion command types the servo cycle accepts (the arbiter hands the live one to the diff-IK).

Every command is an immutable dataclass validated on construction: a bad value raises
``ValueError`` naming the field and the value, so NaN/Inf never reach the IK. Units are the
operator's (FANUC) units: mm, mm/s, deg, deg/s; joints in the FANUC convention (J3 measured from
the horizontal), converted to the model convention by the IK.

``source`` names the input that produced the command (``"spacemouse"``, ``"api"``...), ``stamp`` is
the time it was produced on the caller's clock (seconds); ``is_live(now, timeout)`` tells whether it
may still drive the robot (MoveIt Servo's default timeout is 0.1 s).

The caps below are sanity bounds for any arm we stream (a typo like 5000 deg/s is rejected here);
each robot's own joint speed limits are enforced later by the IK and the shaper.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from servo_app.errors import InvalidRequest

MAX_LINEAR_MM_S = 4000.0  # J519 $MAX_SPD order of magnitude
MAX_ANGULAR_DEG_S = 1000.0  # the fastest FANUC wrist axis
MAX_JOINT_DEG_S = 1000.0
MAX_POSITION_MM = 100_000.0  # 100 m: anything beyond is a units mistake
MAX_JOINT_DEG = 1080.0  # three turns: the widest joint range we know is +-360
# The slowest motion a target may ask for. Slower, a move never ends in practice, and the product with
# the flange-speed guard's reduction could underflow to zero: a speed of 5e-324 (subnormal, above 0)
# once reached the shaper as 0, which raised inside the cycle and ended the servo process.
MIN_SPEED_SCALE = 0.001  # of the joint speed limits: a few tenths of a degree a second
MIN_LINEAR_MM_S = 0.1
MIN_ANGULAR_DEG_S = 0.1
N_JOINTS = 6

Frame = Literal["base", "tool"]


_FLOAT_ONLY = {float}


def _floats(name: str, value: Sequence[float], n: int) -> tuple[float, ...]:
    # The usual case (a request's floats) as it is, by C calls alone (a generator's 8 steps, 110 bytecodes,
    # a twist before): a tuple of floats whose sum is finite has none NaN or infinite (a sum that
    # overflows takes the item-by-item path, which takes the values).
    if type(value) is tuple and len(value) == n and set(map(type, value)) <= _FLOAT_ONLY and math.isfinite(sum(value)):
        return value
    try:
        items = list(value)
    except TypeError:
        raise ValueError(f"{name}={value!r} must be a sequence of {n} numbers") from None
    if len(items) != n:
        raise ValueError(f"{name}={value!r} has {len(items)} values, expected {n}")
    out = []
    for i, v in enumerate(items):
        if isinstance(v, bool) or (not isinstance(v, int | float) and not hasattr(v, "__float__")):
            raise ValueError(f"{name}[{i}]={v!r} is not a number")
        f = float(v)
        if not math.isfinite(f):
            raise ValueError(f"{name}[{i}]={f} is not a finite number")
        out.append(f)
    return tuple(out)


def _bounded(name: str, values: tuple[float, ...], limit: float, unit: str) -> None:
    if -limit <= min(values) and max(values) <= limit:  # (finite values: the usual case in two C calls)
        return
    for i, v in enumerate(values):
        if abs(v) > limit:
            raise ValueError(f"{name}[{i}]={v} {unit} is outside [-{limit}, {limit}]; send a value within it")


def check_speed_scale(value: float) -> float:
    """A target's ``speed_scale`` (a share of the joint speed limits) as a float in
    [MIN_SPEED_SCALE, 1]; otherwise InvalidRequest (a ValueError) naming the value: the request's own
    fault wherever it is checked (REST, the servo process, the trajectory planner)."""
    try:
        return _scalar("speed_scale", value, MIN_SPEED_SCALE, 1.0)
    except ValueError as exc:
        raise InvalidRequest(str(exc)) from None


def _scalar(name: str, value: float, lo: float, hi: float, *, lo_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name}={value!r} is not a number")
    f = float(value)
    if not math.isfinite(f):
        raise ValueError(f"{name}={f} is not a finite number")
    if f > hi or f < lo or (lo_open and f == lo):
        raise ValueError(f"{name}={f} must be in {'(' if lo_open else '['}{lo}, {hi}]")
    return f


@dataclass(frozen=True, kw_only=True)
class _Stamped:
    source: str
    stamp: float

    def _check_stamp(self) -> None:
        if type(self.source) is str and type(self.stamp) is float and math.isfinite(self.stamp):
            return  # the usual case (a request's): _scalar's float() would give the same float
        if not isinstance(self.source, str):
            raise ValueError(f"source={self.source!r} must be a string")
        object.__setattr__(self, "stamp", _scalar("stamp", self.stamp, -math.inf, math.inf))

    def age(self, now: float) -> float:
        return now - self.stamp

    def is_live(self, now: float, timeout: float) -> bool:
        """True while ``0 <= now - stamp <= timeout``.

        A stamp from the future is not live: a clock mix-up must never extend a command's life.
        """
        age = now - self.stamp
        return 0.0 <= age <= timeout


@dataclass(frozen=True, kw_only=True)
class Twist(_Stamped):
    """Cartesian velocity of the TCP: ``linear`` mm/s (x, y, z), ``angular`` deg/s about x, y, z.

    ``frame="base"``: both vectors in the robot's world frame; ``"tool"``: in the current TCP frame.
    Rotation is always about the TCP (the TCP position is unaffected by ``angular``).
    """

    linear: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular: tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame: Frame = "base"

    def __post_init__(self) -> None:
        self._check_stamp()
        lin = _floats("linear", self.linear, 3)
        ang = _floats("angular", self.angular, 3)
        _bounded("linear", lin, MAX_LINEAR_MM_S, "mm/s")
        _bounded("angular", ang, MAX_ANGULAR_DEG_S, "deg/s")
        if self.frame not in ("base", "tool"):
            raise ValueError(f"frame={self.frame!r} must be 'base' or 'tool'")
        object.__setattr__(self, "linear", lin)
        object.__setattr__(self, "angular", ang)

    @property
    def is_zero(self) -> bool:
        return not any(self.linear) and not any(self.angular)


@dataclass(frozen=True, kw_only=True)
class PoseTarget(_Stamped):
    """Absolute TCP pose ``xyzwpr`` (X Y Z mm, W P R deg, FANUC world frame) reached in a straight
    line at no more than ``linear_speed`` mm/s and ``angular_speed`` deg/s."""

    xyzwpr: tuple[float, float, float, float, float, float] = (0.0,) * 6
    linear_speed: float = 100.0
    angular_speed: float = 30.0

    def __post_init__(self) -> None:
        self._check_stamp()
        pose = _floats("xyzwpr", self.xyzwpr, 6)
        _bounded("xyzwpr", pose[:3], MAX_POSITION_MM, "mm")
        for i in (3, 4, 5):
            if abs(pose[i]) > 360.0:
                raise ValueError(f"xyzwpr[{i}]={pose[i]} deg is outside [-360, 360]; send an angle within it")
        object.__setattr__(self, "xyzwpr", pose)
        object.__setattr__(self, "linear_speed",
                           _scalar("linear_speed", self.linear_speed, MIN_LINEAR_MM_S, MAX_LINEAR_MM_S))
        object.__setattr__(self, "angular_speed",
                           _scalar("angular_speed", self.angular_speed, MIN_ANGULAR_DEG_S, MAX_ANGULAR_DEG_S))


@dataclass(frozen=True, kw_only=True)
class JointJog(_Stamped):
    """Joint velocities, deg/s per joint, FANUC convention (J3 from the horizontal)."""

    velocity: tuple[float, ...] = (0.0,) * N_JOINTS

    def __post_init__(self) -> None:
        self._check_stamp()
        vel = _floats("velocity", self.velocity, N_JOINTS)
        _bounded("velocity", vel, MAX_JOINT_DEG_S, "deg/s")
        object.__setattr__(self, "velocity", vel)


@dataclass(frozen=True, kw_only=True)
class JointTarget(_Stamped):
    """Absolute joint position, deg, FANUC convention, reached in a straight joint-space line at
    ``speed_scale`` [MIN_SPEED_SCALE, 1] times the joint speed limits."""

    position: tuple[float, ...] = (0.0,) * N_JOINTS
    speed_scale: float = 0.1

    def __post_init__(self) -> None:
        self._check_stamp()
        pos = _floats("position", self.position, N_JOINTS)
        _bounded("position", pos, MAX_JOINT_DEG, "deg")
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "speed_scale", check_speed_scale(self.speed_scale))


Command = Twist | PoseTarget | JointJog | JointTarget
