"""``servo-app export FILE.srvlog --mcap OUT.mcap``: a session log as ROS 2-typed MCAP for Foxglove.

Every record of the session log becomes messages at its own time (the header's ``opened_unix`` plus
the record's monotonic offset), CDR-encoded with the ``ros2msg`` schemas embedded, so Foxglove and
``ros2 bag`` read the file without our code:

========================== ======================================== ===================================
topic                      type                                     from
========================== ======================================== ===================================
``/joint_states``          sensor_msgs/msg/JointState               status: the servo position (FANUC)
``/joint_commands``        sensor_msgs/msg/JointState               command: the commanded position,
                                                                    velocity by finite difference
``/tcp_pose``              geometry_msgs/msg/PoseStamped            status: flange pose (FANUC: forward
                                                                    kinematics; Janome: X Y Z R)
``/tcp_pose/commanded``    geometry_msgs/msg/PoseStamped            command, likewise
``/limit_usage``           servo_app_msgs/msg/LimitUsage            command: |v|, |a|, |j| in % of the
                                                                    controller's limits (FANUC)
``/status_bits``           servo_app_msgs/msg/StatusBits            status: the bits as received
``/diagnostics``           diagnostic_msgs/msg/DiagnosticArray      the alarms and warnings the
                                                                    controller's checks raise on the
                                                                    commands, and stream stops
========================== ======================================== ===================================

Limit usage and alarms come from :class:`ControllerLimitChecker`, the check the controller runs
(finite differences at the fixed interval, Appendix B limits at the flange speed and at the payload
the log records), as ``servo-app check`` reports them; each stream in the log (ended by
``last_data``) is checked afresh.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.writer import Writer

from servo_app.fanuc.alarms import format_violation
from servo_app.fanuc.packets import StatusBit
from servo_app.motion.cartesian import CartesianConverter
from servo_app.motion.checker import ControllerLimitChecker, Violation
from servo_app.motion.limit_tables import tables_from_rows
from servo_app.progress import Progress
from servo_app.robots.conventions import fanuc_deg_to_model_rad, xyzwpr_to_matrix
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import ProfileError, load_profile
from servo_app.ros import messages as ros
from servo_app.session_log import (
    KIND_COMMAND,
    KIND_NOTE,
    KIND_PAYLOAD,
    KIND_STATUS,
    SessionLogError,
    header_interval_ms,
    read_session_log,
)
from servo_app.stop_signals import stop_requested

TOPICS: dict[str, str] = {
    "/joint_states": ros.JOINT_STATE,
    "/joint_commands": ros.JOINT_STATE,
    "/tcp_pose": ros.POSE_STAMPED,
    "/tcp_pose/commanded": ros.POSE_STAMPED,
    "/limit_usage": ros.LIMIT_USAGE,
    "/status_bits": ros.STATUS_BITS,
    "/diagnostics": ros.DIAGNOSTIC_ARRAY,
}
DIAGNOSTIC_NAME = "servo_app/controller"


class ExportError(ValueError):
    """A log that cannot be exported; the message names the file and the reason."""


class ExportInterrupted(Exception):
    """The export was stopped (Ctrl-C, SIGTERM) before its end; nothing was written."""


@dataclass
class Message:
    topic: str
    t_ns: int  # nanoseconds since the Unix epoch
    message: Any


@dataclass
class ExportSummary:
    messages: dict[str, int] = field(default_factory=dict)
    alarms: list[str] = field(default_factory=list)
    no_solution: list[int] = field(default_factory=list)  # Sq. of Cartesian commands with no joints


def _janome_pose(values: np.ndarray) -> np.ndarray:
    """X Y Z (mm) and R (deg, about Z) as a 4x4 transform in metres."""
    t = np.eye(4)
    r = math.radians(float(values[3]))
    t[:2, :2] = [[math.cos(r), -math.sin(r)], [math.sin(r), math.cos(r)]]
    t[:3, 3] = np.asarray(values[:3], float) / 1000.0
    return t


class LogConverter:
    """One session log's records -> messages, a record at a time (an export, or a log being written).

    Pure: no I/O. The limit checker and the Cartesian conversion keep their state from record to
    record, as the controller's do over a stream."""

    def __init__(self, header: dict[str, Any], model: str | None = None) -> None:
        self.header = header
        self.opened_ns = round(float(header.get("opened_unix", 0.0)) * 1e9)
        self.janome = str(header.get("protocol", "")).startswith("janome")
        self.no_solution: list[int] = []  # Sq. of the Cartesian commands without a joint solution
        self._note_text = b""  # a note's pieces so far (KIND_NOTE records)
        if not self.janome:
            self._fanuc_setup(model)

    def feed(self, rec: np.void) -> list[Message]:
        t = self.opened_ns + round(float(rec["t"]) * 1e9)
        values = rec["values"].astype(float)
        if self.janome:
            return self._janome(rec, t, values)
        if rec["kind"] == KIND_STATUS:
            return self._fanuc_status(rec, t, values)
        if rec["kind"] == KIND_COMMAND:
            return self._fanuc_command(rec, t, values)
        if rec["kind"] == KIND_PAYLOAD:  # a tool change: the tables' payload from here on
            kg = float(values[0])
            self.checker.set_payload(None if math.isnan(kg) else kg)
        elif rec["kind"] == KIND_NOTE:
            self._note(rec)
        return []

    def _note(self, rec: np.void) -> None:
        """A note's piece; a whole ``limit_tables`` note (the controller's, read at the stream's start,
        before its first command) becomes the checker's tables."""
        self._note_text += rec.tobytes()[13:].rstrip(b"\0")
        if not self._note_text.endswith(b"\n"):
            return
        text, self._note_text = self._note_text, b""
        try:
            t = json.loads(text)["limit_tables"]
            tables = tables_from_rows(float(t["vmax"]), float(t["check_time_s"]), float(t["max_payload_kg"]),
                                      [[(a[0], a[1]) for a in per_type] for per_type in t["rows"]])
        except (KeyError, TypeError, ValueError, IndexError):
            return  # another note, or a damaged one: the tables stay
        old = self.checker
        self.checker = ControllerLimitChecker.for_profile(self.profile, self.kin.flange_xyz_mm_fanuc_deg,
                                                          tables=tables, interval_s=old.dt,
                                                          payload_kg=old.payload_kg)

    # ---- Janome: X Y Z R, no joints (the point job reports none) ---------------------------------

    @staticmethod
    def _janome(rec: np.void, t: int, values: np.ndarray) -> list[Message]:
        if rec["kind"] == KIND_STATUS:
            return [Message("/tcp_pose", t, ros.pose_stamped(t, _janome_pose(values))),
                    Message("/status_bits", t, ros.status_bits(t, int(rec["seq"]), int(rec["flags"]), int(rec["io"]),
                                                               [f"state={int(rec['flags'])}"]))]
        if rec["kind"] == KIND_COMMAND:
            return [Message("/tcp_pose/commanded", t, ros.pose_stamped(t, _janome_pose(values)))]
        return []

    # ---- FANUC J519 --------------------------------------------------------------------------------

    def _fanuc_setup(self, model: str | None) -> None:
        name = model or self.header.get("model")
        if not isinstance(name, str) or not name:
            raise ExportError("the session log's header names no model: give one with --model")
        try:
            profile = load_profile(name)
        except ProfileError as exc:
            raise ExportError(str(exc)) from exc
        self.profile = profile
        self.kin = ArmKinematics(profile)
        self.n = profile.dof
        self.j23 = profile.j23_factor
        try:
            dt = (header_interval_ms(self.header) or profile.interval_ms) / 1000.0
        except SessionLogError as exc:
            raise ExportError(str(exc).removeprefix("session log: ")) from None
        # At the payload the stream's tables were evaluated at (a light tool's limits are higher; a log
        # written before the payload was recorded: the maximum, as `servo-app check` judges it).
        payload = self.header.get("payload_kg")
        self.checker = ControllerLimitChecker.for_profile(
            profile, self.kin.flange_xyz_mm_fanuc_deg, interval_s=dt,
            payload_kg=float(payload) if isinstance(payload, (int, float)) else None)
        # X Y Z W P R commands: the controller checks the joints its IK makes of them, converted as
        # `servo-app check` and the simulator do (the first stream from the all-zero posture).
        self.cartesian = CartesianConverter.for_profile(profile)
        self.q_prev = np.zeros(self.n)
        self.names = ros.joint_names(self.n)
        self.hardware = f"{profile.name} ({self.header.get('protocol', 'fanuc-j519')})"
        self.streaming = False
        self.new_stream = True
        self.streams = 0

    def _fanuc_status(self, rec: np.void, t: int, values: np.ndarray) -> list[Message]:
        q_model = fanuc_deg_to_model_rad(values[: self.n], self.j23)
        bits = int(rec["flags"])
        out = [Message("/joint_states", t, ros.joint_state(t, q_model)),
               Message("/tcp_pose", t, ros.pose_stamped(t, self.kin.fk(q_model))),
               Message("/status_bits", t, ros.status_bits(t, int(rec["seq"]), bits, int(rec["io"]),
                                                          [b.name.lower() for b in StatusBit if bits & b]))]
        if self.streaming and not bits & StatusBit.WAITING_FOR_COMMAND:
            self.streaming = False
            out.append(Message("/diagnostics", t, ros.diagnostics(t, DIAGNOSTIC_NAME, self.hardware, [(
                ros.ERROR, "the controller stopped the stream (status bit 0 cleared): see its alarm history",
                {"seq": str(int(rec["seq"]))})])))
        return out

    def _fanuc_command(self, rec: np.void, t: int, values: np.ndarray) -> list[Message]:
        seq, flags = int(rec["seq"]), int(rec["flags"])  # flags = last_data | data_format << 1
        cartesian = not (flags >> 1) & 1
        if self.new_stream:
            self.checker.reset()
            if self.streams and cartesian:
                self.cartesian.reset(self.q_prev)
            self.new_stream = False
            self.streams += 1
        if cartesian:
            res = self.cartesian.convert(values[:6], self.q_prev)
            if res.joints_deg is None:  # the controller's alarm for this command; the rest is exported
                return self._no_solution(rec, t, values, res.code or "MOTN-018")
            q_deg = np.asarray(res.joints_deg, float)
        else:
            q_deg = values[: self.n]
        self.q_prev = q_deg
        self.streaming = True
        checker = self.checker
        found = checker.step(q_deg, seq)
        if flags & 1:  # last_data: the stream ends (bit 0 clears next); judge a window still open
            found += checker.finish(seq)
            self.new_stream, self.streaming = True, False
        q_model = fanuc_deg_to_model_rad(q_deg, self.j23)
        v_model = fanuc_deg_to_model_rad(checker.velocity, self.j23)  # linear: rates convert as positions do
        # Cartesian: the commanded pose itself; joints: the flange pose they put the arm in.
        pose = xyzwpr_to_matrix(values[:6]) if cartesian else self.kin.fk(q_model)
        vel, acc, jerk = checker.limits_at(checker.flange_speed)
        out = [Message("/joint_commands", t, ros.joint_state(t, q_model, v_model)),
               Message("/tcp_pose/commanded", t, ros.pose_stamped(t, pose)),
               Message("/limit_usage", t, ros.limit_usage(
                   t, self.names, 100.0 * np.abs(checker.velocity) / vel, 100.0 * np.abs(checker.acceleration) / acc,
                   100.0 * np.abs(checker.jerk) / jerk, checker.flange_speed))]
        if found:
            out.append(Message("/diagnostics", t, ros.diagnostics(t, DIAGNOSTIC_NAME, self.hardware, [
                (ros.WARN if v.warning else ros.ERROR, format_violation(v),
                 {"code": v.code, "kind": v.kind, "axis": "" if v.axis is None else f"J{v.axis}",
                  "seq": str(v.seq), "value": f"{v.value:.6g}", "limit": f"{v.limit:.6g}"})
                for v in found])))
        return out


    def _no_solution(self, rec: np.void, t: int, values: np.ndarray, code: str) -> list[Message]:
        """A Cartesian command the controller's IK cannot convert (MOTN-156 / MOTN-018, as
        ``servo-app check`` reports it): its commanded pose and the alarm on /diagnostics, no joints.
        The limit checker and the held configuration go on from the last command that converted (the
        controller never moves to this one), and a record of last data still ends the stream."""
        seq, flags = int(rec["seq"]), int(rec["flags"])
        self.no_solution.append(seq)
        v = Violation(code, "cartesian", None, seq, math.nan, math.nan, detected_seq=seq)
        pose = [round(float(x), 3) for x in values[:6]]
        found = [v]
        if flags & 1:
            found += self.checker.finish(seq)
            self.new_stream, self.streaming = True, False
        return [Message("/tcp_pose/commanded", t, ros.pose_stamped(t, xyzwpr_to_matrix(values[:6]))),
                Message("/diagnostics", t, ros.diagnostics(t, DIAGNOSTIC_NAME, self.hardware, [
                    (ros.ERROR, format_violation(x) + (f": X Y Z W P R {pose} has no joint solution in the "
                                                       "held configuration" if x is v else ""),
                     {"code": x.code, "kind": x.kind, "axis": "" if x.axis is None else f"J{x.axis}",
                      "seq": str(x.seq), "value": f"{x.value:.6g}", "limit": f"{x.limit:.6g}"})
                    for x in found]))]


class McapSink:
    """An MCAP file with the export's channels registered (ROS 2 profile, ``ros2msg`` schemas, CDR)."""

    def __init__(self, f: IO[bytes], header: dict[str, Any], chunk_size: int = 1024 * 1024) -> None:
        self.writer = Writer(f, chunk_size=chunk_size)
        self.writer.start(profile="ros2", library="servo_app")
        schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        for topic, typename in TOPICS.items():
            if typename not in schemas:
                schemas[typename] = self.writer.register_schema(name=typename, encoding="ros2msg",
                                                                data=ros.msgdef(typename).encode())
            self.channels[topic] = self.writer.register_channel(topic=topic, message_encoding="cdr",
                                                                schema_id=schemas[typename])
        self.writer.add_metadata("servo_app", {str(k): str(v) for k, v in header.items()})
        self.summary = ExportSummary()
        self._sequence = 0

    def write(self, messages: list[Message]) -> None:
        for m in messages:
            self.writer.add_message(channel_id=self.channels[m.topic], log_time=m.t_ns, publish_time=m.t_ns,
                                    sequence=self._sequence, data=ros.serialize(m.message, TOPICS[m.topic]))
            self._sequence += 1
            self.summary.messages[m.topic] = self.summary.messages.get(m.topic, 0) + 1
            if m.topic == "/diagnostics":
                self.summary.alarms += [s.message for s in m.message.status if s.level == ros.ERROR]

    def finish(self) -> None:
        self.writer.finish()


def export_mcap(src: Path, out: Path, model: str | None = None,
                progress: Callable[[int, int], None] | None = None,
                stop: threading.Event | None = None) -> ExportSummary:
    """Write ``src`` (a session log) as MCAP to ``out`` (whole, or not at all); what was written.
    ``progress(records done, records)`` is called every 1024 records; ``stop``, set, ends it there
    (ExportInterrupted, nothing written)."""
    try:
        log = read_session_log(src)
    except (SessionLogError, OSError) as exc:
        raise ExportError(str(exc)) from exc
    converter = LogConverter(log.header, model)
    tmp = out.with_name(out.name + ".partial")
    try:
        with open(tmp, "wb") as f:
            sink = McapSink(f, log.header)
            total = len(log.records)
            for i, rec in enumerate(log.records):
                if not i & 1023:
                    if stop is not None and stop.is_set():
                        raise ExportInterrupted(f"interrupted at record {i:,} of {total:,}")
                    if progress is not None:
                        progress(i, total)
                sink.write(converter.feed(rec))
            sink.finish()
            sink.summary.no_solution = list(converter.no_solution)
        tmp.replace(out)
    except OSError as exc:  # the output's fault (no such directory, no permission, the disk full)
        tmp.unlink(missing_ok=True)
        raise ExportError(f"cannot write {out}: {exc.strerror or exc}; give an --mcap path in a writable "
                          "directory with room for it (nothing was written)") from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return sink.summary


def run_export(args: argparse.Namespace) -> int:
    shown: list[Progress] = []

    def progress(done: int, total: int) -> None:
        if not shown:
            shown.append(Progress("servo-app export", total, "records"))
        shown[0].update(done)

    # Ctrl-C (or SIGTERM) is a request to stop, not a traceback from wherever the loop was: the
    # export ends at its next check, the partial file removed, and says so in one line.
    with stop_requested() as stop:
        try:
            summary = export_mcap(Path(args.file), Path(args.mcap), args.model, progress, stop)
        except (ExportError, ExportInterrupted) as exc:
            failed: ExportError | ExportInterrupted | None = exc
        else:
            failed = None
        finally:
            for p in shown:  # (its line erased before the report or the error)
                p.close()
    if isinstance(failed, ExportInterrupted):
        print(f"servo-app export: {failed}; nothing was written to {args.mcap}", file=sys.stderr)
        return 130
    if failed is not None:
        why = str(failed)  # (the session log's own errors name the file already)
        print(f"servo-app export: {why if why.startswith(str(args.file)) else f'{args.file}: {why}'}",
              file=sys.stderr)
        return 2
    counts = ", ".join(f"{topic} {n}" for topic, n in summary.messages.items())
    print(f"{args.mcap}: {sum(summary.messages.values())} messages ({counts})")
    if summary.alarms:
        print(f"alarms: {len(summary.alarms)} (on /diagnostics), first: {summary.alarms[0]}")
    if summary.no_solution:
        seqs = ", ".join(f"Sq.{q}" for q in summary.no_solution[:10])
        more = f" and {len(summary.no_solution) - 10} more" if len(summary.no_solution) > 10 else ""
        print(f"{len(summary.no_solution)} Cartesian command(s) have no joint solution: {seqs}{more}; exported "
              "with their commanded pose and the alarm, without joints (`servo-app check` reports the first)")
    return 0
