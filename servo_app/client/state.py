"""The typed state (``GET /api/state``, one ``/ws/telemetry`` message) and a taught point.

Plain dataclasses, no pydantic: the client is installable on its own, without the server's models.
Every field the client does not name stays in ``raw``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Alarm:
    code: str
    message: str
    cause: str | None = None
    remedy: str | None = None
    warning: bool = False

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Alarm:
        return cls(code=str(d.get("code")), message=str(d.get("message", "")), cause=d.get("cause"),
                   remedy=d.get("remedy"), warning=bool(d.get("warning")))


@dataclass(frozen=True)
class Fault:
    message: str
    code: str | None = None
    cause: str | None = None
    remedy: str | None = None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Fault:
        return cls(message=str(d.get("message", "")), code=d.get("code"), cause=d.get("cause"),
                   remedy=d.get("remedy"))


def _floats(v: Any) -> tuple[float, ...] | None:
    return None if v is None else tuple(float(x) for x in v)


@dataclass(frozen=True)
class Tool:
    """A tool of the cell: the TCP from the flange (X Y Z mm, W P R deg) and its payload (kg; None:
    the robot's maximum)."""

    name: str
    xyzwpr: tuple[float, ...]
    payload_kg: float | None = None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Tool:
        payload = d.get("payload_kg")
        return cls(name=str(d["name"]), xyzwpr=tuple(float(v) for v in d["xyzwpr"]),
                   payload_kg=None if payload is None else float(payload))


@dataclass(frozen=True)
class State:
    """The service's state: safety ``state`` (disconnected, ready, streaming, stopping, stopped,
    ending, ended, fault, ...), the ``link`` phase, positions and the flags a script waits on."""

    state: str
    link: str
    joints: tuple[float, ...] | None = None  # commanded position (q_cmd): deg, or mm for a linear axis
    joints_feedback: tuple[float, ...] | None = None  # what the robot reports (q_servo)
    pose: tuple[float, ...] | None = None  # the active tool's TCP pose: X Y Z mm, W P R deg (cart_servo)
    flange_pose: tuple[float, ...] | None = None  # the flange pose the robot reports
    tool: Tool | None = None  # the active tool
    at_rest: bool = False
    settled: bool = False
    resumable: bool = False
    stop_reason: str | None = None
    stop_fast: bool = False
    fault: Fault | None = None
    alarms: tuple[Alarm, ...] = ()
    lease_holder: str | None = None
    model: str | None = None
    published_unix: float | None = None
    trajectory: TrajectoryProgress | None = None  # a replay in this stream (POST /api/trajectory)
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> State:
        lease = d.get("lease") or {}
        return cls(state=str(d["state"]), link=str(d["link"]), joints=_floats(d.get("q_cmd")),
                   joints_feedback=_floats(d.get("q_servo")), pose=_floats(d.get("cart_servo")),
                   flange_pose=_floats(d.get("flange_pose")),
                   tool=Tool.from_json(d["tool"]) if d.get("tool") else None,
                   at_rest=bool(d.get("at_rest")), settled=bool(d.get("settled")),
                   resumable=bool(d.get("resumable")), stop_reason=d.get("stop_reason"),
                   stop_fast=bool(d.get("stop_fast")),
                   fault=Fault.from_json(d["fault"]) if d.get("fault") else None,
                   alarms=tuple(Alarm.from_json(a) for a in d.get("alarms") or ()),
                   lease_holder=lease.get("client") if lease.get("held") else None, model=d.get("model"),
                   published_unix=d.get("published_unix"),
                   trajectory=TrajectoryProgress.from_json(d["trajectory"]) if d.get("trajectory") else None,
                   raw=d)


@dataclass(frozen=True)
class TrajectoryProgress:
    """A replay's progress: ``state`` playing, pausing, paused, resuming, done or ended (left by a fast
    stop, a fault or another command); the sample played of ``total``, and the same in seconds."""

    state: str
    index: int
    total: int
    time_s: float
    total_s: float
    paused: bool

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TrajectoryProgress:
        return cls(state=str(d["state"]), index=int(d["index"]), total=int(d["total"]),
                   time_s=float(d["time_s"]), total_s=float(d["total_s"]), paused=bool(d["paused"]))


@dataclass(frozen=True)
class Point:
    """A taught point: the joints (what ``move_to`` goes back to), the TCP pose at teach time and the
    tool that TCP belongs to."""

    name: str
    joints: tuple[float, ...]
    pose: tuple[float, ...]
    model: str
    taught_unix: float
    tool: str | None = None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Point:
        return cls(name=str(d["name"]), joints=tuple(float(x) for x in d["joints"]),
                   pose=tuple(float(x) for x in d["xyzwpr"]), model=str(d["model"]),
                   taught_unix=float(d["taught_unix"]), tool=d.get("tool"))
