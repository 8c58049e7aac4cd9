"""Typed messages between the service (API process) and its servo process, in both directions.

Requests go down the pipe as ``Envelope(id, request)``; the servo process answers each one that has
an id with a :class:`Reply`, and sends :class:`Event` objects of its own accord. Every message is a
frozen dataclass: the supervisor dispatches requests by type (one handler per type, no op strings),
and an unknown or malformed request is refused by name instead of raising a ``KeyError`` somewhere.

Units are the backend's own (FANUC: degrees in its J2/J3 convention; Janome: mm and degrees); the
backend checks counts, ranges and plausibility before anything changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from servo_app.motion.limit_tables import LimitTables

# ----------------------------------------------------------------------------------------- requests


@dataclass(frozen=True)
class Request:
    """Base of every request to the servo process."""


@dataclass(frozen=True)
class Start(Request):
    """Start a stream: status output on if needed, then the first command (the hold position)."""


@dataclass(frozen=True)
class Stop(Request):
    reason: str = "stop requested"
    fast: bool = False


@dataclass(frozen=True)
class Resume(Request):
    pass


@dataclass(frozen=True)
class End(Request):
    """Decelerate to rest, send last data, end the stream."""


@dataclass(frozen=True)
class Reset(Request):
    """Leave a fault, or acknowledge a fast stop at rest."""


@dataclass(frozen=True)
class LeaseLost(Request):
    holder: str = ""


@dataclass(frozen=True)
class ControllerAlarm(Request):
    """An alarm the controller posted, reported by whoever can see it (the embedded simulator)."""

    code: str
    message: str = ""


@dataclass(frozen=True)
class Jog(Request):
    """Per-axis velocity, hold-to-run: it stops unless renewed within ``hold_s``."""

    joints: tuple[float, ...]
    hold_s: float | None = None  # None: the backend's default


@dataclass(frozen=True)
class Twist(Request):
    """Cartesian velocity (mm/s, deg/s) in the base or tool frame, hold-to-run."""

    linear: tuple[float, float, float]
    angular: tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame: str = "base"
    hold_s: float = 0.2
    source: str = "api"


@dataclass(frozen=True)
class PoseTarget(Request):
    """Move the TCP to X Y Z (mm) W P R (deg, world)."""

    xyzwpr: tuple[float, ...]
    linear_speed: float = 100.0
    angular_speed: float = 30.0
    source: str = "api"


@dataclass(frozen=True)
class JointTarget(Request):
    joints: tuple[float, ...]
    speed_scale: float = 1.0


@dataclass(frozen=True)
class Trajectory(Request):
    """Replay joint positions planned and checked beforehand (``servo_app.motion.trajectory``), one
    per cycle. ``joints`` (N, dof) FANUC deg, float32 values, the first the current commanded position;
    ``ramp_steps`` (odd): cycles of the pause/resume ramp, checked with the plan."""

    joints: np.ndarray
    ramp_steps: int
    label: str = ""  # what was planned (for the state and the audit line)


@dataclass(frozen=True)
class ConfigureInputs(Request):
    """Hand the arm to the input sources (or take it back)."""

    enable: bool
    sources: tuple[str, ...] | None = None


@dataclass(frozen=True)
class IoRead(Request):
    """Read 16 points from ``index`` through the command packets (sticky until changed)."""

    type: str
    index: int
    mask: int = 0xFFFF


@dataclass(frozen=True)
class IoWrite(Request):
    """Write the masked points of the 16 from ``index`` with the next command packet."""

    type: str
    index: int
    mask: int
    value: int


@dataclass(frozen=True)
class SetTool(Request):
    """Make this tool the TCP (offset from the flange: X Y Z mm, W P R deg) and its payload the limit
    tables' (kg; None: the maximum). Only at rest; refused otherwise, changing nothing."""

    name: str
    xyzwpr: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    payload_kg: float | None = None


@dataclass(frozen=True)
class Envelope:
    """A request on the pipe; ``id`` None means fire-and-forget (no reply). ``deadline``: a
    ``time.monotonic()`` (CLOCK_MONOTONIC, one clock for every process of the machine) after which the
    servo process refuses the request unapplied, for a change the parent stops waiting for: a servo
    process stalled past it must not apply it later, behind the back of a service that said "not done"."""

    id: int | None
    request: Request
    deadline: float | None = None


@dataclass(frozen=True)
class Reply:
    """The answer to a request. A refusal has ``ok`` False, the reason in ``error``, and ``invalid``
    True when the request itself was bad (a count, a range: 422) rather than refused by the state (409)."""

    id: int
    ok: bool
    result: Any = None
    error: str = ""
    invalid: bool = False


# ------------------------------------------------------------------------------------------- events


@dataclass(frozen=True)
class Event:
    """Base of every event from the servo process."""


@dataclass(frozen=True)
class Ready(Event):
    pid: int
    realtime: str = ""
    address: tuple[str, int] | None = None  # where a listening backend waits for its robot


@dataclass(frozen=True)
class SafetyChanged(Event):
    """The supervisor's view after its safety state changed (sent before the state vector shows it)."""

    view: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class LinkPhase(Event):
    phase: str
    reason: str = ""


@dataclass(frozen=True)
class LimitTablesReceived(Event):
    """The controller's limit tables (Appendix B), once a stream's start has read them: what anything
    planned outside the servo process (a trajectory's timing) must keep, not the profile's defaults."""

    tables: LimitTables


@dataclass(frozen=True)
class ReplayLeft(Event):
    """A trajectory replay left before its end, and why (a fast stop, another command, a sample the
    servo's guards would not send): shown as the replay's ``reason`` in the state."""

    reason: str
    index: int


@dataclass(frozen=True)
class LogOpened(Event):
    path: str


@dataclass(frozen=True)
class LogClosed(Event):
    path: str
    records: int
    removed: bool = False  # it held no record (nothing came before it closed): deleted


@dataclass(frozen=True)
class PeerConnected(Event):
    peer: str


@dataclass(frozen=True)
class PeerDisconnected(Event):
    peer: str
    reason: str


@dataclass(frozen=True)
class PeerRefused(Event):
    peer: str
    reason: str


@dataclass(frozen=True)
class Crashed(Event):
    traceback: str
