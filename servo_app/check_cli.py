"""``servo-app check FILE [--model MODEL]``: validate a trajectory as the controller would.

A session log names its robot model in its header, so ``--model`` is needed only for a CSV (or to
check a log against another model). A Janome session log (header ``protocol`` ``janome-...``) is
checked as the Janome robot would take its target frames: each move target within the strokes and,
for a SCARA, reachable in the arm configuration (a line move all along its path); each step no
longer than the link's ``max_step_mm`` / ``max_step_deg`` (what a stop may still travel).
``--payload``, ``--interval-ms``, ``--format`` and ``--warn-lim`` (the FANUC limit tables') are
refused for it (exit 2).

Input: a CSV (comma, semicolon, tab or space separated; ``#`` comments; an optional header row)
with one row per communication interval: J1..J6 in FANUC convention degrees (extra columns, e.g.
extended axes, are ignored), or X Y Z W P R of the flange centre (mm, deg, FANUC world). ``--format
auto`` decides from the header (``x,y,z,w,p,r`` -> xyzwpr; otherwise joints); without a header it
assumes joints. Cartesian rows are converted as the simulator converts them
(servo_app.motion.cartesian): the first row takes the solution nearest the all-zero posture, later
rows the solution nearest the previous one, which must keep the first row's configuration (turn
numbers included: MOTN-156 otherwise); no solution at all is MOTN-018.

A session log is judged against the limit tables its stream moved within: the controller's own,
when it published them (the log records them as a note), else the profile's; a log of several
streams follows its notes in order (a controller may publish other tables at a later start). The acceleration and
jerk tables are evaluated at a payload (Appendix B): a session log's, as the live service streamed
at (the header's ``payload_kg`` and the payload records of tool changes); ``--payload`` instead;
for a CSV, or a log written before the payload was recorded, the maximum payload (the controller's
assumption), with a note. The report names the payload it judged at.

The first row is taken as the controller's command position (no MOTN-617 check on it). Output:
the first violation (code, axis, row, value, limit), then peak usage per axis in % of each limit.
Exit code: 0 no violation (warnings allowed), 1 violation, 2 bad input, 130 stopped (Ctrl-C, SIGTERM:
one line saying where, no report). A long log's progress goes to
stderr (on a terminal: one line, from the first second; elsewhere: a line every 10 s after 3 s).

``load_trajectory(path)`` dispatches on the file type: a servo_app session log (``SERVOLOG`` magic,
any suffix) gives its command records with their wire sequence numbers, each stream (up to a
command with last data) checked on its own; anything else is read as CSV.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import math
import re
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from servo_app.fanuc.alarms import format_violation
from servo_app.motion.checker import ControllerLimitChecker, Usage, Violation
from servo_app.progress import Progress
from servo_app.stop_signals import stop_requested

FORMATS = ("auto", "joints", "xyzwpr")
CSV_SUFFIXES = {".csv", ".txt", ".tsv", ".dat", ""}


class TrajectoryError(ValueError):
    """A file that is not a usable trajectory; the message names the file, the line and the value."""


class CheckInterrupted(Exception):
    """The check was stopped (Ctrl-C, SIGTERM) before its end: no verdict."""


class NothingSent(TrajectoryError):
    """A session log in which no command left (a start that never streamed): nothing the controller
    could refuse, so it passes; not an error."""


def _nothing_sent(p: Path, log: Any, what: str) -> str:
    from servo_app.session_log import end_of_log

    n_status = len(log.statuses)
    packets = "1 status packet" if n_status == 1 else f"{n_status} status packets"
    why = end_of_log(log)  # the log's own word on why its start was given up (logs since it was written)
    return (f"{p}: no {what} were sent in this session ({packets} logged; a start that "
            f"never streamed{': ' + why if why else ''}): nothing the controller could refuse")


@dataclass
class Trajectory:
    """Rows of one stream, one per interval: ``values`` (N, 6); ``lines[i]`` = source line of row i."""

    values: np.ndarray
    fmt: str  # "joints" (FANUC deg) or "xyzwpr" (mm, deg)
    lines: list[int]
    source: Path
    meta: dict[str, Any] = field(default_factory=dict)
    seqs: np.ndarray | None = None  # wire sequence numbers (session logs); None: rows count from 1
    stream_ends: list[int] = field(default_factory=list)  # row indices that carried last data

    def row_of_seq(self, seq: int) -> int | None:
        """0-based row of a violation's sequence number."""
        if self.seqs is None:
            return seq - 1 if 1 <= seq <= len(self.lines) else None
        hits = np.flatnonzero(self.seqs == seq)
        return int(hits[0]) if len(hits) else None


def load_trajectory(path: str | Path, fmt: str = "auto") -> Trajectory:
    """Read a trajectory file; the type decides the reader (CSV today; session logs later)."""
    p = Path(path)
    if not p.is_file():
        raise TrajectoryError(f"{p}: no such file")
    if fmt not in FORMATS:
        raise TrajectoryError(f"format {fmt!r} is not one of {', '.join(FORMATS)}")
    if _is_session_log(p):
        return _load_session_log(p, fmt)
    if p.suffix.lower() in CSV_SUFFIXES:
        return _load_csv(p, fmt)
    raise TrajectoryError(f"{p}: unknown file type {p.suffix!r} (supported: CSV of joints or X Y Z W P R)")


def _is_session_log(p: Path) -> bool:
    try:
        from servo_app.session_log import is_session_log
    except ImportError:
        return False
    try:
        return is_session_log(p)
    except OSError as exc:
        raise TrajectoryError(f"{p}: cannot read: {exc}") from exc


def _load_session_log(p: Path, fmt: str) -> Trajectory:
    from servo_app.session_log import SessionLogError, header_interval_ms, read_session_log

    try:
        log = read_session_log(p)
    except (SessionLogError, OSError) as exc:
        raise TrajectoryError(str(exc)) from exc
    try:
        interval_ms, interval_problem = header_interval_ms(log.header, p), None
    except SessionLogError as exc:  # (--interval-ms still checks it: run_check decides)
        interval_ms, interval_problem = None, str(exc)
    cmds = log.commands
    if len(cmds) == 0:
        raise NothingSent(_nothing_sent(p, log, "commands"))
    formats = set(((cmds["flags"] >> 1) & 1).tolist())  # flags = last_data | data_format << 1
    if len(formats) > 1:
        raise TrajectoryError(f"{p}: the log mixes joint and Cartesian commands")
    logged = "joints" if formats == {1} else "xyzwpr"
    if fmt != "auto" and fmt != logged:
        raise TrajectoryError(f"{p}: the log holds {logged} commands, not {fmt}")
    ends = np.flatnonzero(cmds["flags"] & 1).tolist()
    return Trajectory(cmds["values"][:, :6].astype(float), logged, list(range(1, len(cmds) + 1)), p,
                      {"header": log.header, "interval_ms": interval_ms, "interval_problem": interval_problem,
                       "payload_changes": log.payload_changes(), "tables": _logged_tables(log)},
                      seqs=cmds["seq"].astype(np.int64), stream_ends=ends)


def _logged_tables(log: Any) -> list[tuple[int, Any]]:
    """(commands before it, tables) for each of the controller's limit tables the log's notes record,
    in order: each holds from there on, as the stream at that point moved within it (one log spans
    several streams; a controller may publish other tables at a later start). Empty: the profile's."""
    from servo_app.motion.limit_tables import tables_from_rows

    out: list[tuple[int, Any]] = []
    for row, note in log.notes():
        t = note.get("limit_tables")
        if isinstance(t, dict):
            # A damaged note is skipped: the tables before it hold (none before it: the profile's).
            with contextlib.suppress(KeyError, TypeError, ValueError, IndexError):
                out.append((row, tables_from_rows(float(t["vmax"]), float(t["check_time_s"]),
                                                  float(t["max_payload_kg"]),
                                                  [[(a[0], a[1]) for a in per_type] for per_type in t["rows"]])))
    return out


_SPLIT = re.compile(r"[,;\t ]+")


def _load_csv(p: Path, fmt: str) -> Trajectory:
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise TrajectoryError(f"{p}: cannot read: {exc}") from exc
    rows: list[list[float]] = []
    lines: list[int] = []
    header: list[str] | None = None
    width: int | None = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if "," in line:
            cells = [c.strip() for c in next(csv.reader(io.StringIO(line)))]
        else:
            cells = [c for c in _SPLIT.split(line) if c]
        try:  # NaN / inf parse and are kept: the checker reports them as the controller does (605)
            vals = [float(c) for c in cells]
        except ValueError:
            if not rows and header is None:
                header = [c.lower() for c in cells]
                continue
            raise TrajectoryError(f"{p}:{lineno}: not a number in {raw.strip()!r}") from None
        if len(vals) < 6:
            raise TrajectoryError(f"{p}:{lineno}: {len(vals)} values, need at least 6")
        if width is None:
            width = len(vals)
        elif len(vals) != width:
            raise TrajectoryError(f"{p}:{lineno}: {len(vals)} values, the rows above have {width}")
        rows.append(vals[:6])
        lines.append(lineno)
    if not rows:
        raise TrajectoryError(f"{p}: no data rows")
    if fmt == "auto":
        fmt = "xyzwpr" if header is not None and header[:6] == ["x", "y", "z", "w", "p", "r"] else "joints"
    return Trajectory(np.array(rows, dtype=float), fmt, lines, p, {"header": header})


def cartesian_to_joints(traj: Trajectory, profile: Any) -> tuple[np.ndarray, Violation | None]:
    """FANUC joints (deg) for the X Y Z W P R rows, converted as the simulator does
    (:mod:`servo_app.motion.cartesian`); stops at the first row that has none (MOTN-156 / MOTN-018).

    The start position of the first stream is unknown: its first row takes the solution nearest the
    all-zero posture and sets the held configuration. A later stream of a session log starts from
    the last row of the one before (the controller's command position at its IBGN start)."""
    from servo_app.motion.cartesian import CartesianConverter

    conv = CartesianConverter.for_profile(profile)
    out = np.zeros((len(traj.values), 6))
    prev = np.zeros(6)
    starts = {e + 1 for e in traj.stream_ends}
    for i, row in enumerate(traj.values):
        if i in starts:
            conv.reset(prev)
        res = conv.convert(row, prev)
        if res.joints_deg is None:
            assert res.code is not None
            seq = int(traj.seqs[i]) if traj.seqs is not None else i + 1
            return out[:i], RowViolation(res.code, "cartesian", None, seq, math.nan, math.nan, detected_seq=seq,
                                         row=i, detected_row=i)
        out[i] = prev = res.joints_deg
    return out, None


@dataclass(frozen=True)
class RowViolation(Violation):
    """A violation with the rows it names (0-based, among the rows checked): a log's sequence numbers
    restart at 1 with each stream (the controller's), so a number alone named a row of the first."""

    row: int | None = None
    detected_row: int | None = None


def _located(found: list[Violation], seqs: list[int], start: int, end: int) -> list[Violation]:
    """``found`` (in the stream of rows start..end-1) with the rows their sequence numbers name there."""
    row_of = {seqs[i]: i for i in range(end - 1, start - 1, -1)}  # (the first, were one repeated)
    return [RowViolation(**{f: getattr(v, f) for f in Violation.__dataclass_fields__},
                         row=row_of.get(v.seq) if v.seq is not None else None,
                         detected_row=row_of.get(v.detected_seq) if v.detected_seq is not None else None)
            for v in found]


@dataclass
class CheckReport:
    violations: list[Violation]  # alarms (and CHK-001), in stream order
    warnings: list[Violation]
    usage: Usage
    rows: int
    vmax: float


def check_joints(joints: np.ndarray, checker: ControllerLimitChecker, seqs: np.ndarray | None = None,
                 stream_ends: list[int] | None = None,
                 payload_changes: list[tuple[int, float | None]] | None = None,
                 table_changes: list[tuple[int, Any]] | None = None,
                 progress: Callable[[int], None] | None = None) -> CheckReport:
    """Check the rows; each stream (ending at a row in ``stream_ends``) starts the checker afresh.
    ``payload_changes``: (row, kg or None) from that row on the tables are the payload's, as the live
    service's were after a tool change; ``table_changes``: (row, LimitTables) from that row on, the
    controller's tables of the stream there. Violations carry ``seqs[row]`` (default: the 1-based row).
    ``progress(rows done)`` is called every 1024 rows."""
    seq_list = [int(s) for s in seqs] if seqs is not None else list(range(1, len(joints) + 1))
    bounds = sorted({e + 1 for e in (stream_ends or []) if e + 1 < len(joints)} | {len(joints)})
    payload_at = dict(payload_changes or [])  # (a tool change comes at rest: no window spans it)
    tables_at = dict(table_changes or [])  # (read at a stream's start, before its first command)
    found: list[Violation] = []
    usage = None
    start = 0
    for end in bounds:
        checker.reset()
        stream: list[Violation] = []
        for i in range(start, end):
            if i in tables_at:
                checker.set_tables(tables_at[i])
            if i in payload_at:
                checker.set_payload(payload_at[i])
            if progress is not None and not i & 1023:
                progress(i)
            stream.extend(checker.step(joints[i], seq_list[i]))
        stream.extend(checker.finish(seq_list[end - 1] if end > start else None))
        found.extend(_located(stream, seq_list, start, end))
        usage = _merge_usage(usage, checker.usage)
        start = end
    assert usage is not None
    return CheckReport([v for v in found if not v.warning], [v for v in found if v.warning],
                       usage, len(joints), checker.vmax)


def _merge_usage(a: Usage | None, b: Usage) -> Usage:
    if a is None:
        return Usage(b.ratio.copy(), b.peak.copy(), b.ratio_seq.copy(), b.max_flange_speed, b.steps)
    take = b.ratio > a.ratio
    return Usage(np.where(take, b.ratio, a.ratio), np.maximum(a.peak, b.peak),
                 np.where(take, b.ratio_seq, a.ratio_seq), max(a.max_flange_speed, b.max_flange_speed),
                 a.steps + b.steps)


def add_check_parser(sub: Any) -> argparse.ArgumentParser:
    """Register ``check`` on the ``servo-app`` subparsers."""
    p = sub.add_parser("check", help="validate a trajectory as the controller would (J519 limits)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", help="CSV of J1..J6 (FANUC deg) or X Y Z W P R rows, one per interval")
    p.add_argument("--model", default=None,
                   help="robot profile name or TOML path (default: the model in a session log's header; "
                        "required for a CSV)")
    p.add_argument("--interval-ms", type=float, default=None, help="interval (default: the profile's)")
    p.add_argument("--payload", type=float, default=None,
                   help="payload kg (default: a session log's, as streamed; else the maximum payload)")
    p.add_argument("--format", choices=FORMATS, default="auto", dest="fmt")
    p.add_argument("--warn-lim", type=float, default=None, help="$WARN_LIM %% (default 80)")
    p.set_defaults(handler=run_check)
    return p


def model_for(traj_header: dict[str, Any] | None, given: str | None, source: Path) -> str:
    """The model to check against: ``--model`` if given, else the session log's header's."""
    if given:
        return given
    model = (traj_header or {}).get("model")
    if isinstance(model, str) and model:
        return model
    if traj_header is None:
        raise TrajectoryError(f"{source}: a CSV names no robot model: give one with --model "
                              f"(see `servo-app profiles`)")
    raise TrajectoryError(f"{source}: the session log's header names no model: give one with --model")


def _log_header(path: str) -> dict[str, Any] | None:
    """A session log's header (None for any other file)."""
    p = Path(path)
    # (a .srvlog that is no log, e.g. empty, is read as one: its error says what it is, not "a CSV")
    if not p.is_file() or not (_is_session_log(p) or p.suffix.lower() == ".srvlog"):
        return None
    from servo_app.session_log import SessionLogError, read_session_log

    try:
        return read_session_log(p).header
    except (SessionLogError, OSError) as exc:
        raise TrajectoryError(str(exc)) from exc


def run_check(args: argparse.Namespace) -> int:
    # Ctrl-C (or SIGTERM) is a request to stop, not a traceback from wherever the checker was: the
    # check ends at its next look at the request (every 1024 rows) and says so in one line.
    with stop_requested() as stop:
        try:
            return _run_check(args, stop)
        except CheckInterrupted as exc:
            print(f"servo-app check: {args.file}: {exc}: no verdict (run the check again to its end)",
                  file=sys.stderr)
            return 130


def _run_check(args: argparse.Namespace, stop: threading.Event) -> int:
    from servo_app.robots.profile import ProfileError, load_profile

    try:
        if not Path(args.file).is_file():  # (before the model: a missing log is no CSV without one)
            raise TrajectoryError(f"{args.file}: no such file")
        header = _log_header(args.file)
        if header is not None and str(header.get("protocol", "")).startswith("janome"):
            _refuse_fanuc_options(args)
            return run_janome_check(Path(args.file), model_for(header, args.model, Path(args.file)), stop)
        profile = load_profile(model_for(header, args.model, Path(args.file)))
        traj = load_trajectory(args.file, args.fmt)
        if args.interval_ms is not None and not (math.isfinite(args.interval_ms) and args.interval_ms > 0):
            raise TrajectoryError(f"--interval-ms {args.interval_ms} must be > 0")
        if args.interval_ms is None and traj.meta.get("interval_problem"):
            raise TrajectoryError(f"{traj.meta['interval_problem']}: give the interval with --interval-ms")
        payload, changes, tables_note = _payload_of(args.payload, header, traj, profile.max_payload_kg)
    except NothingSent as exc:
        print(f"{exc}\nOK: no violation")
        return 0
    except (ProfileError, TrajectoryError) as exc:
        print(f"servo-app check: {exc}", file=sys.stderr)
        return 2
    if header is not None and args.model and header.get("model") not in (None, args.model):
        print(f"note: the log was written for {header.get('model')}; checking against {args.model}",
              file=sys.stderr)
    flange = None
    try:
        from servo_app.robots.kinematics import ArmKinematics

        flange = ArmKinematics(profile).flange_xyz_mm_fanuc_deg
    except ImportError:
        print("note: no kinematics, acceleration/jerk judged at the Vmax/20 (stage 1) limits only",
              file=sys.stderr)
    interval_ms = args.interval_ms or traj.meta.get("interval_ms") or profile.interval_ms
    interval_s = float(interval_ms) / 1000.0
    logged = list(traj.meta.get("tables") or [])
    # The profile's tables until the first note (a stream before it had none from the controller).
    tables = logged.pop(0)[1] if logged and logged[0][0] == 0 else None
    if tables is not None or logged:
        starts = [row + 1 for row, _ in traj.meta["tables"]]
        before = "" if tables is not None else f"the profile's tables to command {starts[0] - 1}, then "
        tables_note += f"; {before}the controller's tables, as streamed"
        if len(starts) > 1 or before:
            tables_note += f" (published at command{'s' * (len(starts) > 1)} " + \
                ", ".join(map(str, starts[:-1])) + " and " * (len(starts) > 1) + f"{starts[-1]})"
    checker = ControllerLimitChecker.for_profile(profile, flange, interval_s=interval_s, tables=tables,
                                                 payload_kg=payload,
                                                 warn_lim_pct=80.0 if args.warn_lim is None else args.warn_lim)
    ik_failure = None
    joints = traj.values
    if traj.fmt == "xyzwpr":
        joints, ik_failure = cartesian_to_joints(traj, profile)
    n = len(joints)
    progress = Progress("servo-app check", n, "commands")

    def step(done: int) -> None:
        if stop.is_set():
            raise CheckInterrupted(f"interrupted at command {done:,} of {n:,}")
        progress.update(done)

    try:
        report = check_joints(joints, checker, None if traj.seqs is None else traj.seqs[:n],
                              [e for e in traj.stream_ends if e < n], changes, logged, step)
    finally:
        progress.close()  # (its line erased before the report or the interruption's)
    if ik_failure is not None:
        report.violations.append(ik_failure)
    print(render_report(report, traj, float(interval_ms), tables_note))
    return 1 if report.violations else 0


def _refuse_fanuc_options(args: argparse.Namespace) -> None:
    """A Janome log is checked by its move targets against the strokes, the arm configuration and the
    step limits: the FANUC limit tables' options do nothing to it. Refused, naming them, rather than
    taken in silence (a check "at --payload 12" that never looked at any payload)."""
    given = [name for name, value in (("--payload", args.payload), ("--interval-ms", args.interval_ms),
                                      ("--format", None if args.fmt == "auto" else args.fmt),
                                      ("--warn-lim", args.warn_lim)) if value is not None]
    if given:
        verb = "does" if len(given) == 1 else "do"
        raise TrajectoryError(f"{args.file}: a Janome log: {', '.join(given)} {verb} not apply (its move targets are "
                              "checked against the robot's strokes, arm configuration and step limits, not "
                              f"FANUC's limit tables): run the check without {' and '.join(given)}")


def _kg(payload: float | None, max_kg: float) -> str:
    return f"the maximum payload, {max_kg:g} kg" if payload is None else f"payload {payload:g} kg"


def _payload_of(given: float | None, header: dict[str, Any] | None, traj: Trajectory, max_kg: float
                ) -> tuple[float | None, list[tuple[int, float | None]], str]:
    """The payload to judge at first (None: the maximum), the log's later changes (row, kg) and a line
    saying which tables and why. ``--payload`` wins; else the payload the live service streamed at,
    as the log records it (header ``payload_kg``, then its payload records). A log written before
    the payload was recorded, and a CSV, are judged at the maximum (the controller's assumption
    without a PAYLOAD), with a note saying how to give the tool's payload."""
    if given is not None:
        if not (math.isfinite(given) and 0.0 <= given <= max_kg):  # (the tables would be clamped, or NaN)
            raise TrajectoryError(f"--payload {given:g} must be between 0 and the robot's maximum payload, "
                                  f"{max_kg:g} kg: give the tool's weight in kg")
        if header is not None and "payload_kg" in header and header["payload_kg"] != given:
            print(f"note: the log was streamed at {_kg(header['payload_kg'], max_kg)}; checking at "
                  f"--payload {given:g} kg", file=sys.stderr)
        return given, [], f"limit tables at {_kg(given, max_kg)} (--payload)"
    if header is None:
        return None, [], f"limit tables at {_kg(None, max_kg)} (a CSV names none: --payload KG for a lighter tool)"
    if "payload_kg" not in header:
        print("note: this session log does not record the payload (written before servo_app logged it): "
              f"judged at {_kg(None, max_kg)}; with a lighter tool fitted the controller's limits were higher: "
              "give the tool's payload with --payload KG", file=sys.stderr)
        return None, [], f"limit tables at {_kg(None, max_kg)} (the log does not record its payload)"
    payload = header["payload_kg"]
    if payload is not None and (not isinstance(payload, (int, float)) or not 0.0 <= payload <= max_kg):
        raise TrajectoryError(f"{traj.source}: header payload_kg={payload!r} is not a payload of this robot "
                              f"(0 to {max_kg:g} kg): give the payload with --payload KG")
    changes = traj.meta.get("payload_changes") or []
    tool = f", tool {header['tool']!r}" if header.get("tool") else ""
    note = f"limit tables at {_kg(payload, max_kg)} as streamed{tool}"
    if changes:
        note += "; changed by tool changes to " + ", ".join(
            f"{_kg(kg, max_kg)} from command {row + 1}" for row, kg in changes)
    return payload, changes, note


_UNITS = {"velocity": "deg/s", "acceleration": "deg/s^2", "jerk": "deg/s^3", "position": "deg",
          "discontinuity": "deg", "flange_speed": "mm/s", "non_finite": "", "cartesian": ""}


def _row_of(v: Violation, seq: int | None, traj: Trajectory, detected: bool = False) -> int | None:
    if isinstance(v, RowViolation):
        return v.detected_row if detected else v.row
    return None if seq is None else traj.row_of_seq(seq)


def _row_text(v: Violation, traj: Trajectory) -> str:
    row = _row_of(v, v.seq, traj)
    if row is None:
        return "row ?"
    if traj.seqs is not None:
        return f"command {row + 1} of the log (Sq.{v.seq})"
    return f"row {row + 1} (line {traj.lines[row]})"


def describe(v: Violation, traj: Trajectory) -> str:
    where = _row_text(v, traj)
    axis = f"axis J{v.axis}, " if v.axis is not None else ""
    unit = _UNITS.get(v.kind, "")
    text = f"{format_violation(v)}\n  {axis}{where}"
    if math.isfinite(v.value) and math.isfinite(v.limit) and v.kind not in ("non_finite", "cartesian"):
        text += f": {v.kind} {v.value:.6g} {unit}, limit {v.limit:.6g} {unit}"
        if v.kind in ("velocity", "acceleration", "jerk"):
            text += f" ({100 * v.excess:.1f} %)"
    if v.flange_speed is not None:
        text += f", judged at Vpeak {v.flange_speed:.0f} mm/s"
    if v.detected_seq is not None and v.detected_seq != v.seq:
        row = _row_of(v, v.detected_seq, traj, detected=True)
        if row is not None:
            text += f", detected at row {row + 1}"
    return text


def render_report(report: CheckReport, traj: Trajectory, interval_ms: float, tables: str = "") -> str:
    out = [f"{traj.source}: {report.rows} rows ({traj.fmt}) at {interval_ms:g} ms = "
           f"{report.rows * interval_ms / 1000.0:.3f} s"]
    if tables:
        out.append(tables)
    if report.violations:
        first = report.violations[0]  # in detection order (IK failures come last: they end the rows)
        out.append(f"FIRST VIOLATION: {describe(first, traj)}")
        out.append(f"violations: {len(report.violations)}, warnings: {len(report.warnings)}")
    else:
        out.append(f"OK: no violation ({len(report.warnings)} warnings)")
        if report.warnings:
            out.append(f"first warning: {describe(report.warnings[0], traj)}")
    u = report.usage
    out.append("peak usage in % of the limit (acc/jerk: of the limit the controller judged against)")
    out.append("axis   velocity  acceleration      jerk")
    for i in range(u.ratio.shape[1]):
        out.append(f"J{i + 1}   {100 * u.ratio[0, i]:9.1f}  {100 * u.ratio[1, i]:12.1f}  {100 * u.ratio[2, i]:8.1f}")
    out.append(f"peak flange speed {u.max_flange_speed:.0f} mm/s ($MAX_SPD {report.vmax:.0f})")
    return "\n".join(out)


# --------------------------------------------------------------------------------- Janome logs


@dataclass(frozen=True)
class JanomeFinding:
    row: int  # 0-based index among the log's command records
    seq: int  # the target frame's sequence number
    text: str


@dataclass
class JanomeReport:
    violations: list[JanomeFinding]
    moves: int  # move targets checked
    peak_step: np.ndarray  # per axis X Y Z R: the longest step (mm, mm, mm, deg)
    lo: np.ndarray  # per axis: the smallest and largest target value
    hi: np.ndarray


def check_janome_targets(values: np.ndarray, cmds: np.ndarray, seqs: np.ndarray, start: np.ndarray | None,
                         profile: Any) -> JanomeReport:
    """Check a Janome log's target frames (X Y Z R, cmd) as the robot takes them. Pure.

    ``start``: the robot's position before the first target (its first status), if logged."""
    from servo_app.janome.kinematics import AXES, UNITS
    from servo_app.janome.protocol import Cmd

    ws = profile.workspace()
    arm = int(profile.elbow)
    prev = None if start is None else np.asarray(start, float)
    found: list[JanomeFinding] = []
    peak = np.zeros(4)
    moves = [i for i, c in enumerate(cmds) if int(c) in (Cmd.LINE, Cmd.PTP)]
    for i in moves:
        p = np.asarray(values[i], float)
        why = ws.check(p, arm)
        if why is None and prev is not None and int(cmds[i]) == Cmd.LINE:
            why = ws.check_path(prev, p, arm)
        if why is not None:
            axis = f"axis {AXES[why.axis - 1]}, " if why.axis else ""
            found.append(JanomeFinding(i, int(seqs[i]), f"{why.code.name} (robot error {int(why.code)}): "
                                                      f"{axis}{why.message}"))
        if prev is not None:
            step = np.abs(p - prev)
            peak = np.maximum(peak, step)
            lin = float(np.linalg.norm(step[:3]))
            if lin > profile.max_step_mm + 1e-6:
                found.append(JanomeFinding(i, int(seqs[i]), f"STEP: a {lin:.3f} mm step, longer than max_step_mm "
                                                          f"{profile.max_step_mm:g} (a stop may travel a whole step)"))
            if step[3] > profile.max_step_deg + 1e-6:
                found.append(JanomeFinding(i, int(seqs[i]), f"STEP: a {step[3]:.3f} {UNITS[3]} R step, longer than "
                                                          f"max_step_deg {profile.max_step_deg:g}"))
        prev = p
    targets = values[moves] if moves else np.zeros((0, 4))
    lo = targets.min(axis=0) if len(targets) else np.full(4, np.nan)
    hi = targets.max(axis=0) if len(targets) else np.full(4, np.nan)
    return JanomeReport(found, len(moves), peak, lo, hi)


def run_janome_check(path: Path, model: str, stop: threading.Event | None = None) -> int:
    from servo_app.janome.kinematics import AXES, UNITS
    from servo_app.janome.profile import load_janome_profile
    from servo_app.robots.profile import ProfileError
    from servo_app.session_log import read_session_log

    try:
        profile = load_janome_profile(model)
    except ProfileError as exc:
        print(f"servo-app check: {exc}", file=sys.stderr)
        return 2
    log = read_session_log(path)
    cmds = log.commands
    if len(cmds) == 0:
        print(f"{_nothing_sent(path, log, 'target frames')}\nOK: no violation")
        return 0
    statuses = log.statuses
    first_cmd_t = float(cmds["t"][0])
    before = statuses[statuses["t"] <= first_cmd_t]
    start = before["values"][-1, :4].astype(float) if len(before) else None
    report = check_janome_targets(cmds["values"][:, :4].astype(float), (cmds["flags"] >> 1) & 0x7F,
                                  cmds["seq"].astype(np.int64), start, profile)
    if stop is not None and stop.is_set():  # (a check of target frames is short: looked at once, here)
        raise CheckInterrupted(f"interrupted after {len(cmds):,} target frames")
    out = [f"{path}: {len(cmds)} target frames, {report.moves} moves, {profile.display_name} ({profile.name})"]
    if report.violations:
        v = report.violations[0]
        out.append(f"FIRST VIOLATION: {v.text}\n  target {v.row + 1} of the log (seq {v.seq})")
        out.append(f"violations: {len(report.violations)}")
    else:
        out.append("OK: no violation")
    out.append("axis  range of targets              stroke                  longest step  max step")
    for i in range(4):
        cap = profile.max_step_deg if i == 3 else profile.max_step_mm
        out.append(f"{AXES[i]}  {report.lo[i]:10.3f} .. {report.hi[i]:10.3f}  {profile.axis_min[i]:9.3f} .. "
                   f"{profile.axis_max[i]:9.3f} {UNITS[i]:3s}  {report.peak_step[i]:10.3f}  {cap:g}")
    print("\n".join(out))
    return 1 if report.violations else 0
