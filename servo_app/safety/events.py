"""Inputs to the safety transition function. Time never enters here: watchdogs turn it into events."""

from __future__ import annotations

from dataclasses import dataclass

# --- from the controller / link ---------------------------------------------------------------

# The status byte as the safety machine reads it (J519's layout; other backends map their link state
# onto the same booleans): bit 0 waiting for commands, bit 1 command received, bit 2 SYSRDY, bit 3 moving.
STATUS_WAITING_FOR_COMMAND = 0x01
STATUS_COMMAND_RECEIVED = 0x02
STATUS_SYSRDY = 0x04
STATUS_MOVING = 0x08


@dataclass(frozen=True)
class StatusReceived:
    bit0: bool  # waiting for command packets
    bit1: bool  # command packet received
    sysrdy: bool
    moving: bool = False  # informative only: lags the commands

    @classmethod
    def from_byte(cls, status: int) -> StatusReceived:
        return cls(
            bit0=bool(status & STATUS_WAITING_FOR_COMMAND),
            bit1=bool(status & STATUS_COMMAND_RECEIVED),
            sysrdy=bool(status & STATUS_SYSRDY),
            moving=bool(status & STATUS_MOVING),
        )


@dataclass(frozen=True)
class StatusLost:
    """No status packet within the StatusWatch timeout."""

    detail: str = ""


@dataclass(frozen=True)
class Disconnected:
    """The socket is gone (closed, unreachable)."""

    detail: str = ""


@dataclass(frozen=True)
class ControllerAlarm:
    """An alarm the controller posted, classified by whoever creates the event from its backend's
    catalogue; an empty ``cause`` means the code is not in it (it still stops, with generic texts)."""

    code: str  # e.g. "MOTN-603", "JNM-007"
    message: str = ""  # the controller's one-line text
    warning: bool = False  # posted but does not stop the robot
    cause: str = ""
    remedy: str = ""


# --- operator / API requests ------------------------------------------------------------------


@dataclass(frozen=True)
class ConnectRequested:
    """Ask the controller for status packets (status output start)."""


@dataclass(frozen=True)
class DisconnectRequested:
    """Stop status packets (status output stop); refused while a command stream is alive."""


@dataclass(frozen=True)
class StartRequested:
    pass


@dataclass(frozen=True)
class StopRequested:
    reason: str = "stop requested"
    fast: bool = False


@dataclass(frozen=True)
class ResumeRequested:
    pass


@dataclass(frozen=True)
class EndRequested:
    """End the stream: a soft stop, then last data. ``reason``, when given, names the stop (the
    service's own end: its session log cannot take the stream); else a stop under way keeps its own."""

    reason: str | None = None


@dataclass(frozen=True)
class ResetRequested:
    """Clear a fault, or acknowledge a fast stop at rest."""


# --- from the servo cycle ---------------------------------------------------------------------


@dataclass(frozen=True)
class ShaperAtRest:
    """The shaper's commanded velocity and acceleration are zero."""


@dataclass(frozen=True)
class LastDataProcessed:
    """The controller has processed the last-data packet (bit 0 fell after it was sent)."""


@dataclass(frozen=True)
class InputStale:
    source: str


@dataclass(frozen=True)
class SensorFault:
    source: str
    detail: str = ""  # e.g. "NaN on axis 3"


@dataclass(frozen=True)
class LeaseLost:
    holder: str = ""


@dataclass(frozen=True)
class Signal:
    sig: int  # signal number; SIGTERM and SIGINT shut down, others are ignored


@dataclass(frozen=True)
class LimitApproaching:
    """A limit that diff-IK cannot avoid will be reached unless the arm stops now."""

    detail: str = ""


@dataclass(frozen=True)
class JogExpired:
    """Hold-to-run deadline passed without a renewing jog."""

    source: str = ""


Event = (
    StatusReceived
    | StatusLost
    | Disconnected
    | ControllerAlarm
    | ConnectRequested
    | DisconnectRequested
    | StartRequested
    | StopRequested
    | ResumeRequested
    | EndRequested
    | ResetRequested
    | ShaperAtRest
    | LastDataProcessed
    | InputStale
    | SensorFault
    | LeaseLost
    | Signal
    | LimitApproaching
    | JogExpired
)

# Requests come from people or clients; a request the state cannot honour is refused with an error.
REQUESTS: tuple[type, ...] = (
    ConnectRequested,
    DisconnectRequested,
    StartRequested,
    StopRequested,
    ResumeRequested,
    EndRequested,
    ResetRequested,
)
