"""What the point job's error codes and the link's failures mean, with a remedy, for fault reports.

The shared safety state machine words its own faults for FANUC (IBGN, MOTN-603); the Janome
supervisor replaces cause and remedy with these texts when a Janome link or robot error is the cause.
"""

from __future__ import annotations

from dataclasses import dataclass

from servo_app.janome.protocol import ErrorCode


@dataclass(frozen=True)
class JanomeAlarm:
    cause: str
    remedy: str


_RESTART = ("Check the robot's teaching pendant for an error, start the program with the streaming point job "
            "again (it connects to servo_app), then reset here and start a new stream.")

# Frame-level rejections: the point job cleared its buffer and asked again; servo_app resends the
# same target. Only repeated rejections become a fault.
FRAME_ERRORS = frozenset({ErrorCode.BAD_MAGIC, ErrorCode.BAD_CHECKSUM, ErrorCode.BAD_TERMINATOR,
                          ErrorCode.BAD_SEQUENCE, ErrorCode.BUFFER_OVERFLOW})

ROBOT_ERRORS: dict[ErrorCode, JanomeAlarm] = {
    ErrorCode.BAD_MAGIC: JanomeAlarm(
        "The point job did not find the target header \"JRT1\" at the head of its receive buffer (cmpCOM).",
        "Check that nothing else writes to the robot's client port; servo_app resends the target."),
    ErrorCode.BAD_CHECKSUM: JanomeAlarm(
        "A target frame's checksum did not match its fields on the robot.",
        "Check the point job's checksum lines against docs/janome_pointjob.txt; servo_app resends the target."),
    ErrorCode.BAD_TERMINATOR: JanomeAlarm(
        "A target frame did not end with CR LF on the robot: the frame length is off.",
        "Check the inCOM lengths in the point job against docs/janome_pointjob.txt."),
    ErrorCode.BAD_SEQUENCE: JanomeAlarm(
        "A target frame answered an older status frame.",
        "Usually a stale frame after a reconnect; servo_app resends the target."),
    ErrorCode.BUFFER_OVERFLOW: JanomeAlarm(
        "More than 8 KB waited in the robot's receive buffer (manual 19): it was cleared.",
        "Only one target may be outstanding: check that a single servo_app instance serves this port."),
    ErrorCode.BAD_COMMAND: JanomeAlarm(
        "The robot rejected a target's cmd, stop or arm field (detail = the field number).",
        "servo_app and the point job disagree on the protocol version: update the point job."),
    ErrorCode.OUT_OF_RANGE: JanomeAlarm(
        "The robot rejected a target outside an axis stroke (detail = axis 1 X, 2 Y, 3 Z, 4 R).",
        "The profile's strokes are wider than the robot's: correct configs/robots/janome/<model>.toml. " + _RESTART),
    ErrorCode.UNREACHABLE: JanomeAlarm(
        "The SCARA robot found no joint solution for a target in the commanded arm configuration.",
        "Correct the arm lengths and joint ranges in the profile, or stay away from the workspace edge. " + _RESTART),
    ErrorCode.BAD_SPEED: JanomeAlarm(
        "The robot rejected a target's speed (zero, or above its maximum).",
        "Lower cp.speed_mm_s in the profile to the robot's CP speed limit. " + _RESTART),
    ErrorCode.MOVE_FAILED: JanomeAlarm(
        "The robot's move command reported an error (e.g. #FlMoveOutRange after lineMove).",
        "Read the error on the teaching pendant. " + _RESTART),
    ErrorCode.RX_TIMEOUT: JanomeAlarm(
        "The point job received no target within its setWTCOM timeout and left the loop.",
        "servo_app answered too late or the network stalled; " + _RESTART),
    ErrorCode.TOO_MANY_ERRORS: JanomeAlarm(
        "The point job rejected too many frames in a row and left the loop.",
        "See the earlier rejections (warnings); " + _RESTART),
}

LINK_LOST = JanomeAlarm(
    "The robot's TCP connection closed or reset while the stream was alive: the point job ended, the robot "
    "was stopped, the cable or network failed, or the controller was switched off. The robot finishes at "
    "most its current short move.",
    "Check the robot (emergency stop, pendant errors) and the network. " + _RESTART)
LINK_TIMEOUT = JanomeAlarm(
    "No status frame arrived within the expected move time plus the link timeout: the point job stalled, "
    "or the network did. servo_app closed the connection so the point job leaves its loop.",
    "Check the robot's pendant for a stopped program and the network. " + _RESTART)
ROBOT_LEFT = JanomeAlarm(
    "The point job left its loop (BYE) while the stream was alive.",
    "Read the error code in the message and on the pendant. " + _RESTART)
PROTOCOL = JanomeAlarm(
    "The robot broke the link protocol (wrong sequence or acknowledgement, or malformed frames in a row).",
    "Compare the point job with docs/janome_pointjob.txt. " + _RESTART)


def alarm_code(error: ErrorCode) -> str:
    return f"JNM-{int(error):03d}"


def alarm_for_code(code: str) -> JanomeAlarm | None:
    """The text for a ``JNM-nnn`` code, None for any other code."""
    if not code.startswith("JNM-"):
        return None
    try:
        return ROBOT_ERRORS.get(ErrorCode(int(code[4:])))
    except ValueError:
        return None
