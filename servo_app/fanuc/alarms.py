"""The alarm codes of manual 61.9 with their texts, causes and remedies, plus the few codes outside
61.9 that the simulator and ``servo-app check`` report (MOTN-017, MOTN-018, CHK-001).

The simulator raises them; the service shows them (code, cause, remedy) when a controller reports
a stop. ``format_alarm`` renders the one-line form the controller shows, e.g.
``MOTN-611 ST:Exceeded Jnt Jerk Limit.(A:3,Sq.1234)``; ``format_violation`` that of a limit
checker's record (servo_app.motion.checker, which carries codes and numbers only).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from servo_app.motion.checker import Violation


@dataclass(frozen=True)
class AlarmSpec:
    code: str
    text: str  # format string; fields: axis, seq, pc, rob
    cause: str
    remedy: str
    warning: bool = False  # warnings are posted but do not stop the robot


_SPECS = [
    AlarmSpec(
        "MOTN-600",
        "ST:Sequence No error. PC {pc}, Rob {rob}",
        "The sequence number (= xx) of the command packet did not match that (= yy) requested by the robot.",
        "Make sure that the sequence number of the command packet to be sent is set correctly. Make sure "
        "that the data structure, endianness, and message size to be sent are correct.",
    ),
    AlarmSpec(
        "MOTN-602",
        "ST:Data type error",
        "The value of the command packet data format (0: Cartesian, 1: Joint) is invalid.",
        "Make sure that the value of the data format of the command packet to be sent is set correctly.",
    ),
    AlarmSpec(
        "MOTN-603",
        "ST:Receiving interval over",
        "The robot could not confirm the command packet with the next sequence number within the "
        "communication interval.",
        "If the cause is thought to be communication delay, consider using buffering of command packets "
        "(61.4). Make sure that there is no large processing time before the external program sends the "
        "command packet.",
    ),
    AlarmSpec(
        "MOTN-604",
        "ST:Too many packet received",
        "The robot has received too many command packets.",
        "Make sure that the command packet is not sent in excess of the bufferable size.",
    ),
    AlarmSpec(
        "MOTN-605",
        "ST:Command is NaN or infinity.(A:{axis},Sq.{seq})",
        "An abnormal value (NaN or infinity) is set in the desired position data of the command packet.",
        "Make sure that the desired position data is set correctly.",
    ),
    AlarmSpec(
        "MOTN-606",
        "ST:Need to AUTO and 100% ovrd",
        "When executing the IBGN start [*] instruction, it is necessary to be in AUTO mode and 100% OVERRIDE.",
        "Execute the program in AUTO mode and 100% OVERRIDE. Do not change the override during execution.",
    ),
    AlarmSpec(
        "MOTN-607",
        "ST:Protocol version mismatch PC {pc}, Rob {rob}",
        "A packet (= xx) with an incorrect protocol version was received.",
        "Check the protocol version (= yy) used on the robot side, and use the correct version.",
    ),
    AlarmSpec(
        "MOTN-608",
        "ST:TCP/IP error. See Cause & Remedy.",
        "The status packet could not be communicated correctly from the robot.",
        "Check the cable status, communication settings, and Ethernet is not busy. Do not stop the status "
        "output while command packets are still being processed.",
    ),
    AlarmSpec(
        "MOTN-609",
        "ST:Exceeded Jnt Velocity Limit.(A:{axis},Sq.{seq})",
        "As the speed of axis xx exceeded the allowable upper limit at the command packet with Sq. yy, "
        "the robot stopped.",
        "Check the speed of the relevant part from the sent trajectory data, and then consider improving "
        "the trajectory generation algorithm.",
    ),
    AlarmSpec(
        "MOTN-610",
        "ST:Exceeded Jnt Acc/Dec Limit.(A:{axis},Sq.{seq})",
        "As the acceleration of axis xx exceeded the allowable upper limit at the command packet with "
        "Sq. yy, the robot stopped.",
        "Check the acceleration at the relevant part from the sent trajectory data, and then consider "
        "improving the trajectory generation algorithm.",
    ),
    AlarmSpec(
        "MOTN-611",
        "ST:Exceeded Jnt Jerk Limit.(A:{axis},Sq.{seq})",
        "As the jerk of axis xx exceeds the allowable upper limit at the command packet with Sq. yy, "
        "the robot stopped.",
        "Check the jerk of the relevant part from the sent trajectory data, and then consider improving "
        "the trajectory generation algorithm.",
    ),
    AlarmSpec(
        "MOTN-612",
        "ST:Close to Jnt Velocity Limit.(A:{axis},Sq.{seq})",
        "In the command packet of sequence number yy, the speed of axis xx approaches the allowable upper "
        "limit.",
        "No special countermeasure is required. Set $STMO_GRP[].$WARN_LIM to 100 to silence it.",
        warning=True,
    ),
    AlarmSpec(
        "MOTN-613",
        "ST:Close to Jnt Acc/Dec Limit.(A:{axis},Sq.{seq})",
        "In the command packet with sequence number yy, the acceleration of axis xx approaches the "
        "allowable upper limit.",
        "No special countermeasure is required. Set $STMO_GRP[].$WARN_LIM to 100 to silence it.",
        warning=True,
    ),
    AlarmSpec(
        "MOTN-614",
        "ST:Close to Jnt Jerk Limit.(A:{axis},Sq.{seq})",
        "In the command packet with sequence number yy, the jerk of axis xx approaches the allowable upper "
        "limit.",
        "No special countermeasure is required. Set $STMO_GRP[].$WARN_LIM to 100 to silence it.",
        warning=True,
    ),
    AlarmSpec(
        "MOTN-615",
        "ST:Please Disable Brake Control.",
        "The IBGN start [*] instruction could not be started because brake control is enabled.",
        "Set $PARAM_GROUP[].$SV_OFF_ENB[1-9] = FALSE, and cycle power of the controller.",
    ),
    AlarmSpec(
        "MOTN-616",
        "ST:Reducer load excess.(A:{axis})",
        "The robot stopped because the load level applied to the reducer unit on axis xx exceeds a threshold.",
        "Consider measures such as making the motion more conservative.",
    ),
    AlarmSpec(
        "MOTN-617",
        "ST:Discontinous command.(Sq.{seq})",
        "A large discrepancy was found between the desired position and the current position at the "
        "command packet of Sq.xx.",
        "Make sure that the desired position data that connects smoothly from the current position is set "
        "correctly.",
    ),
    AlarmSpec("MOTN-618", "ST:Internal Error.", "This is an internal error.", "Cycle power of the controller."),
    AlarmSpec(
        "MOTN-619",
        "ST:Cartesian type is not supported",
        "Cartesian format is used with a robot model that cannot support Cartesian format for the desired "
        "position data.",
        "Use Joint format for the target position data.",
    ),
    AlarmSpec(
        "MOTN-623",
        "ST:Please Disable Resume Offset.",
        "The IBGN start [*] instruction could not be started because Resume Offset function is enabled.",
        "Disable the Resume Offset.",
    ),
    AlarmSpec(
        "MOTN-156",
        "PM:Configuration changed",
        "The configuration of desired position data (Cartesian format) is different from that at the start "
        "of the IBGN start [*] instruction.",
        "In this feature, if the desired position data is in Cartesian format, the robot motion cannot "
        "across the configuration.",
    ),
    AlarmSpec(
        "PRIO-023",
        "There is no I/O for this type",
        "The I/O to be read or written via the command packet is not set for allocation.",
        "Allocate the I/O to be read or written, or specify another I/O.",
    ),
    # Not in 61.9, which only says "the robot will stop with an alarm" for an unreachable desired
    # position (61.5): FANUC's general motion alarms stand in for it.
    AlarmSpec(
        "MOTN-017",
        "Limit error (G:1, A:{axis}, Sq.{seq})",
        "The desired position of the command packet is outside the stroke limit of the axis "
        "(manual 61.5 'Reachable positions'; FANUC's general joint limit alarm). For Cartesian format: "
        "the joints converted from the pose.",
        "Keep every commanded joint inside its range (J3 range in the model convention, after J2/J3 "
        "conversion).",
    ),
    AlarmSpec(
        "MOTN-018",
        "Position not reachable (Sq.{seq})",
        "The Cartesian desired position has no joint solution: the flange centre is outside the work "
        "envelope of the arm (manual 61.5 'Reachable positions').",
        "Keep the Cartesian path inside the reachable space of the arm (flange centre, world frame).",
    ),
    # Offline only (servo-app check): the controller has no such alarm.
    AlarmSpec(
        "CHK-001",
        "Flange speed {pc} mm/s above $MAX_SPD {rob} mm/s.(Sq.{seq})",
        "The flange-centre speed of the commanded path exceeds $STMO_GRP[].$MAX_SPD; above it the "
        "acceleration/jerk limits fall by extrapolation (Appendix B). Offline checker only.",
        "Slow the path down so that the flange centre stays below $MAX_SPD.",
    ),
]

ALARMS: dict[str, AlarmSpec] = {s.code: s for s in _SPECS}


@dataclass(frozen=True)
class AlarmEvent:
    """One posted alarm or warning, as the controller's alarm history keeps it."""

    code: str
    message: str  # the one-line form: code and formatted text
    time_s: float
    axis: int | None = None
    seq: int | None = None
    controller_time_ms: int | None = None  # the status packets' time stamp clock at the alarm

    @property
    def spec(self) -> AlarmSpec:
        return ALARMS[self.code]

    @property
    def warning(self) -> bool:
        return self.spec.warning


def format_alarm(code: str, axis: int | None = None, seq: int | None = None, pc: object = None,
                 rob: object = None) -> str:
    """The controller's one-line rendering of an alarm, starting with its code."""
    spec = ALARMS[code]
    return f"{code} " + spec.text.format(axis=axis, seq=seq, pc=pc, rob=rob)


def format_violation(v: Violation) -> str:
    """The controller's one-line rendering of a limit checker's record (CHK-001 names the flange speed
    and $MAX_SPD, every other code its axis and sequence number)."""
    if v.code == "CHK-001":
        return format_alarm(v.code, seq=v.seq, pc=round(v.value), rob=round(v.limit))
    return format_alarm(v.code, axis=v.axis, seq=v.seq)
