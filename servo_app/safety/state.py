"""The safety supervisor's state: one immutable value, replaced by every transition."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class Mode(StrEnum):
    DISCONNECTED = "disconnected"  # no status packets
    CONNECTED = "connected"  # status flowing, controller not waiting for a first command
    READY = "ready"  # controller waiting for a first command (bit 0 = 1, bit 1 = 0, SYSRDY)
    STREAMING = "streaming"  # command stream alive, motion commands accepted (holding or moving)
    STOPPING = "stopping"  # command stream alive, shaper decelerating to rest
    STOPPED = "stopped"  # command stream alive, holding at rest
    ENDING = "ending"  # last-data packet sent, controller draining its buffer
    ENDED = "ended"  # stream ended normally
    FAULT = "fault"  # stream lost or controller alarm; only ResetRequested leaves


# Modes in which command packets must keep flowing every interval: the controller has no HOLD here,
# so a gap is an alarm (MOTN-603) and a power-off stop.
STREAM_ALIVE = frozenset({Mode.STREAMING, Mode.STOPPING, Mode.STOPPED, Mode.ENDING})


class StopKind(StrEnum):
    SOFT = "soft"  # gentle ramp; resumable at once
    FAST = "fast"  # shortest ramp within the controller's limits; resume needs a reset at rest first


class Then(StrEnum):
    """What follows the stop once the shaper is at rest."""

    HOLD = "hold"  # stay in the stream, holding position (-> stopped)
    END = "end"  # send last data (-> ending)


@dataclass(frozen=True)
class StatusBits:
    """The status-byte bits the supervisor decides on (manual 61.3 table 2).

    Bit 3 (moving) is left out on purpose: it lags the commands, so rest is the shaper's word.
    """

    bit0: bool  # waiting for command packets (IBGN start executing)
    bit1: bool  # a command packet was received in this IBGN run
    sysrdy: bool  # bit 2, servo power ready

    @property
    def waiting(self) -> bool:
        """Controller waiting for a *first* command: a fresh IBGN run, servo ready."""
        return self.bit0 and not self.bit1 and self.sysrdy


@dataclass(frozen=True)
class Stop:
    reason: str
    kind: StopKind = StopKind.SOFT
    then: Then = Then.HOLD

    @property
    def fast(self) -> bool:
        return self.kind is StopKind.FAST


@dataclass(frozen=True)
class FaultInfo:
    """Why the stream died; for alarms the cause and remedy from the backend's alarm catalogue."""

    message: str
    cause: str
    remedy: str
    code: str | None = None  # controller alarm code, e.g. "MOTN-603"; None for our own detections
    during: Mode | None = None  # the mode the fault interrupted


@dataclass(frozen=True)
class SafetyState:
    mode: Mode = Mode.DISCONNECTED
    status: StatusBits | None = None  # last status bits; None while status packets are not flowing
    stop: Stop | None = None  # set in stopping, stopped, ending, ended
    fault: FaultInfo | None = None  # set exactly in fault
    shutdown: bool = False  # SIGTERM/SIGINT seen: never connect, start or resume again

    @property
    def stop_reason(self) -> str | None:
        return self.stop.reason if self.stop else None

    @property
    def stop_fast(self) -> bool:
        return bool(self.stop and self.stop.fast)

    @property
    def resumable(self) -> bool:
        return (
            self.mode in (Mode.STOPPING, Mode.STOPPED)
            and self.stop is not None
            and self.stop.kind is StopKind.SOFT
            and self.stop.then is Then.HOLD
            and not self.shutdown
        )


def motion_allowed(state: SafetyState) -> bool:
    """Jog and target commands reach the shaper only while streaming."""
    return state.mode is Mode.STREAMING


def stream_alive(state: SafetyState) -> bool:
    """Command packets must be sent every interval."""
    return state.mode in STREAM_ALIVE


def safe_to_exit(state: SafetyState) -> bool:
    """No command stream and no status output left running on the controller."""
    return state.mode not in STREAM_ALIVE and state.status is None
