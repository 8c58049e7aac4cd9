"""What the caller must do after a transition, in order."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from servo_app.safety.state import FaultInfo


@dataclass(frozen=True)
class BeginDeceleration:
    """Switch the shaper to its stop ramp (the HOLD-equivalent path, manual 61.7); ignore motion inputs."""

    fast: bool

    @property
    def mode(self) -> Literal["soft", "fast"]:
        """The stop mode as the shaper names it (``JointShaper.stop(mode)``)."""
        return "fast" if self.fast else "soft"


@dataclass(frozen=True)
class SendFirstCommand:
    """Seed the commanded state from the measured position; send it with the status packet's seq."""


@dataclass(frozen=True)
class HoldPosition:
    """Command the current commanded position every interval; motion inputs are not used."""


@dataclass(frozen=True)
class ResumeMotion:
    """Feed the arbiter's live command to the shaper again (it blends from where it is)."""


@dataclass(frozen=True)
class SendLastData:
    """Send the current (at-rest) position with last data = 1; keep answering status until bit 0 falls."""


@dataclass(frozen=True)
class StartStatusOutput:
    pass


@dataclass(frozen=True)
class StopStatusOutput:
    pass


@dataclass(frozen=True)
class AbandonStream:
    """The controller stopped (or will alarm): stop sending commands, drop the commanded state."""


@dataclass(frozen=True)
class RecordFault:
    fault: FaultInfo


@dataclass(frozen=True)
class ReportWarning:
    """A controller warning: posted, does not stop the robot (61.9)."""

    code: str
    message: str
    cause: str
    remedy: str


Action = (
    BeginDeceleration
    | SendFirstCommand
    | HoldPosition
    | ResumeMotion
    | SendLastData
    | StartStatusOutput
    | StopStatusOutput
    | AbandonStream
    | RecordFault
    | ReportWarning
)

SEND_FIRST_COMMAND = SendFirstCommand()
HOLD_POSITION = HoldPosition()
RESUME_MOTION = ResumeMotion()
SEND_LAST_DATA = SendLastData()
START_STATUS_OUTPUT = StartStatusOutput()
STOP_STATUS_OUTPUT = StopStatusOutput()
ABANDON_STREAM = AbandonStream()
