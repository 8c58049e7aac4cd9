"""What adapters publish: twists, poses, measurements and button events, each stamped and named.

Stamps are seconds on the service's monotonic clock (the adapter's injected clock) at the moment
the value was valid, so ages compare directly with `clock()`. Constructors check that every number
is finite, so a NaN can never reach a slot.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType

from servo_app.inputs.validate import ValueRejected, check_finite

# The frames the servo process takes a twist in (servo_app.input_slot.FRAMES; a test checks they agree).
TWIST_FRAMES = ("base", "tool")


# A jog device reports every 4-8 ms; a shorter staleness timeout would see it go stale between two reports.
MIN_JOG_STALE_S = 0.02


def check_jog_stale(stale_after_s: float) -> float:
    """A SpaceMouse's or gamepad's stale_after_s; ValueError saying why a shorter one cannot work."""
    if stale_after_s < MIN_JOG_STALE_S:
        raise ValueError(f"below {MIN_JOG_STALE_S} s: the device reports every 4-8 ms, so its source would go "
                         "stale between two reports and stop the arm")
    return stale_after_s


def check_twist_frames(frames: Sequence[str]) -> list[str]:
    """A jog device's frames (its toggle_frame steps through them); ValueError naming one the servo lacks."""
    for f in frames:
        if f not in TWIST_FRAMES:
            raise ValueError(f"{f!r} is not a frame a twist is commanded in: one of {', '.join(TWIST_FRAMES)}")
    return list(frames)


def _vector(name: str, values: Sequence[float], n: int) -> tuple[float, ...]:
    if len(values) != n:
        raise ValueRejected(name, values, f"expected {n} values, got {len(values)}")
    return tuple(check_finite(f"{name}[{i}]", v) for i, v in enumerate(values))


@dataclass(frozen=True, slots=True)
class TwistSample:
    linear: tuple[float, float, float]  # mm/s
    angular: tuple[float, float, float]  # deg/s
    frame: str
    stamp: float
    source: str
    # A stop the operator asked for: zero, yet the source keeps control (a yield_when_idle source does
    # not hand the arm to another while its stop holds).
    stop: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "linear", _vector("linear", self.linear, 3))
        object.__setattr__(self, "angular", _vector("angular", self.angular, 3))

    def is_zero(self) -> bool:
        return not any(self.linear) and not any(self.angular)

    def holds_control(self) -> bool:
        """Whether this sample commands (engages its source) even while it is zero."""
        return self.stop

    def as_tuple(self) -> tuple[float, ...]:
        return self.linear + self.angular


@dataclass(frozen=True, slots=True)
class PoseSample:
    xyzwpr: tuple[float, float, float, float, float, float]  # mm and deg, W P R about fixed X Y Z
    stamp: float
    source: str
    frame: str = "base"

    def __post_init__(self) -> None:
        object.__setattr__(self, "xyzwpr", _vector("xyzwpr", self.xyzwpr, 6))

    def is_zero(self) -> bool:
        return False  # a pose is always a command to be somewhere


@dataclass(frozen=True, slots=True)
class Measurement:
    values: Mapping[str, float]
    stamp: float
    source: str

    def __post_init__(self) -> None:
        checked = {str(k): check_finite(str(k), v) for k, v in self.values.items()}
        object.__setattr__(self, "values", MappingProxyType(checked))

    def __getitem__(self, key: str) -> float:
        return self.values[key]

    def is_zero(self) -> bool:
        return not any(self.values.values())


@dataclass(frozen=True, slots=True)
class ButtonEvent:
    button: int
    pressed: bool
    action: str | None  # configured action name, e.g. "toggle_frame" or "toggle_output:DO[1]"
    stamp: float
    source: str
