"""Plan a trajectory replay for the running service: inputs (joint or Cartesian waypoints, a CSV in
``servo-app check``'s form, a window of a recorded session log) -> a checked, timed
:class:`~servo_app.messages.Trajectory` for the servo process.

Runs in the API process, in a worker thread (the FastAPI route's thread pool): the timing
(:mod:`servo_app.motion.trajectory`, TOPP-RA) takes tens to hundreds of milliseconds, never in the
servo cycle. Refusals: :class:`InvalidRequest` (422, names the field and value) for the request
itself, :class:`CommandRejected` (409, ends with the next step) for the state.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from servo_app import messages as msg
from servo_app.errors import CommandRejected, InvalidRequest
from servo_app.motion.commands import check_speed_scale
from servo_app.motion.limit_tables import default_tables
from servo_app.motion.trajectory import TimedTrajectory, TrajectoryPlanner, TrajectoryRefused

# States a replay may be planned in: the stream runs (stopped: the servo's gate says what to do).
_PLANNABLE = ("streaming", "stopped")


@dataclass(frozen=True)
class TrajectoryInput:
    """One request's path, validated for shape: exactly one of joints, poses, csv_text, log."""

    joints: Sequence[Sequence[float]] | None = None
    poses: Sequence[Sequence[float]] | None = None
    times: Sequence[float] | None = None
    csv_text: str | None = None
    log: str | None = None
    from_s: float | None = None
    to_s: float | None = None
    from_unix: float | None = None  # the same window in wall-clock time (ServoClient.record)
    to_unix: float | None = None
    speed_scale: float = 1.0
    # A CSV or a log (one row per interval): "recorded" replays no faster than it was recorded (times
    # speed_scale), "limits" as fast as the limits allow.
    pace: str = "recorded"
    # Joint waypoints: one motion through them all, at rest only at the start and the last (not at each).
    blend: bool = False


def _rows(name: str, values: Sequence[Sequence[float]], width: int) -> np.ndarray:
    if len(values) == 0:
        raise InvalidRequest(f"{name} is empty: give at least one row")
    for i, row in enumerate(values):
        if len(row) != width:
            raise InvalidRequest(f"{name}[{i}] has {len(row)} values, expected {width}")
        for a, v in enumerate(row):
            if not math.isfinite(float(v)):
                raise InvalidRequest(f"{name}[{i}][{a}]={v} is not a finite number")
    return np.array(values, dtype=float)


def _times(times: Sequence[float] | None, count: int) -> list[float] | None:
    if times is None:
        return None
    if len(times) != count:
        raise InvalidRequest(f"times has {len(times)} values, expected one per waypoint ({count})")
    for i, t in enumerate(times):
        if not math.isfinite(float(t)) or (i and float(t) <= float(times[i - 1])):
            raise InvalidRequest(f"times[{i}]={t} must be a finite number greater than times[{i - 1}]"
                                 if i else f"times[0]={t} is not a finite number")
    return [float(t) for t in times]


def read_csv_rows(text: str) -> tuple[np.ndarray, str]:
    """A CSV body in ``servo-app check``'s form: (rows, "joints" or "xyzwpr")."""
    from servo_app.check_cli import TrajectoryError, load_trajectory

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "body.csv"
        p.write_text(text)
        try:
            traj = load_trajectory(p)
        except TrajectoryError as exc:
            # The checker names its file ("PATH:3: ...", "PATH: no data rows"): here the body's lines.
            why = str(exc).removeprefix(f"{p}:")
            if why[:1].isdigit():
                raise InvalidRequest(f"csv line {why}") from None
            raise InvalidRequest(f"csv:{why}; send rows of 6 numbers: J1..J6 in deg, or X Y Z mm W P R deg under "
                                 "the header x,y,z,w,p,r") from None
    bad = np.argwhere(~np.isfinite(traj.values))
    if bad.size:
        i, a = (int(x) for x in bad[0])
        raise InvalidRequest(f"csv: row {i + 1} (line {traj.lines[i]}) value {a + 1} = {traj.values[i, a]} "
                             "is not a finite number")
    return traj.values, traj.fmt


def read_log_window(path: Path, name: str, from_s: float | None, to_s: float | None,
                    from_unix: float | None = None, to_unix: float | None = None) -> np.ndarray:
    """The commanded joints of a session log between ``from_s`` and ``to_s`` (s after its first command),
    or between the wall-clock times ``from_unix`` and ``to_unix`` (the header's ``opened_unix`` maps them)."""
    from servo_app.session_log import SessionLogError, read_session_log

    try:
        log = read_session_log(path)
    except (SessionLogError, OSError) as exc:
        raise InvalidRequest(f"log={name!r}: {exc}") from None
    if str(log.header.get("protocol", "")).startswith("janome"):
        raise InvalidRequest(f"log={name!r} is a Janome log: replay takes FANUC joint logs")
    cmds = log.commands
    if len(cmds) == 0:
        raise InvalidRequest(f"log={name!r} holds no command records")
    if not np.all((cmds["flags"] >> 1) & 1):
        raise InvalidRequest(f"log={name!r} holds Cartesian commands: replay takes joint-format logs")
    t = cmds["t"] - cmds["t"][0]
    if from_unix is not None or to_unix is not None:
        opened = float(log.header.get("opened_unix", 0.0))
        offset = opened + float(cmds["t"][0])  # wall clock of the first command
        from_s = None if from_unix is None else max(0.0, float(from_unix) - offset)
        to_s = None if to_unix is None else float(to_unix) - offset
    lo = 0.0 if from_s is None else float(from_s)
    hi = float(t[-1]) if to_s is None else float(to_s)
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo < 0 or hi <= lo:
        raise InvalidRequest(f"from_s={from_s}, to_s={to_s}: need 0 <= from_s < to_s (the log spans "
                             f"0..{t[-1]:.3f} s)")
    pick = (t >= lo) & (t <= hi)
    if pick.sum() < 2:
        raise InvalidRequest(f"from_s={lo:g}..to_s={hi:g} holds {int(pick.sum())} commands of log={name!r} "
                             f"(it spans 0..{t[-1]:.3f} s); widen the window to hold two or more")
    return cmds["values"][pick, :6].astype(float)


def _log_moves(path: Path) -> tuple[float, float, float] | None:
    """When a FANUC joint log's commands move: (first, last) change, s after its first command, and its
    span; None if they never change (or the log cannot be read: its refusal came earlier)."""
    from servo_app.session_log import SessionLogError, read_session_log

    try:
        cmds = read_session_log(path).commands
    except (SessionLogError, OSError):
        return None
    if len(cmds) < 2:
        return None
    t = cmds["t"] - cmds["t"][0]
    changed = np.flatnonzero(np.any(np.diff(cmds["values"][:, :6], axis=0) != 0.0, axis=1))
    if changed.size == 0:
        return None
    return float(t[changed[0]]), float(t[changed[-1] + 1]), float(t[-1])


def _nothing_to_do(req: TrajectoryInput, rows: np.ndarray | None, path: Path | None, q_now: np.ndarray) -> str:
    """Why a request that does not move the arm is refused, naming what was given and what to do
    ("nothing to do: the path does not move" named neither the window nor a way on)."""
    at = [round(float(v), 3) for v in q_now]
    if req.log is not None and path is not None and rows is not None:
        if req.from_unix is not None or req.to_unix is not None:
            window = f"from_unix={req.from_unix}..to_unix={req.to_unix}"
        else:
            window = f"from_s={req.from_s or 0.0:g}..to_s={'end' if req.to_s is None else f'{req.to_s:g}'}"
        why = (f"log={req.log!r} {window}: nothing to replay: the arm was at rest at {at} through the window's "
               f"{len(rows)} commands, and rests there now")
        moves = _log_moves(path)
        if moves is None:
            return why + "; the log never moves: pick another log (GET /api/sessions lists them)"
        first, last, span = moves
        return (why + f"; the log moves between {first:.3f} and {last:.3f} s (of 0..{span:.3f} s): give a "
                f"window that overlaps them (from_s, to_s)")
    what = "csv rows" if req.csv_text is not None else "poses" if req.poses is not None else "joints"
    return (f"{what}: nothing to do: every one is where the arm rests now ({at}); give a path that goes "
            "somewhere else")


def _log_interval_s(path: Path) -> float | None:
    """The interval a session log was recorded at (its header's ``interval_ms``), None if it does not
    say: a log of a 4 ms stream replayed on an 8 ms one keeps its own pace (it was timed at the
    stream's interval: twice as slow, or twice as fast the other way round)."""
    from servo_app.session_log import SessionLogError, parse_header

    try:
        with open(path, "rb") as f:
            parsed = parse_header(f.read(64 * 1024), path)
    except (OSError, SessionLogError):
        return None
    ms = parsed[0].get("interval_ms") if parsed is not None else None
    return float(ms) / 1000.0 if isinstance(ms, (int, float)) and math.isfinite(ms) and ms > 0 else None


def _check_poses(backend: Any, poses: np.ndarray, what: str, tool_xyzwpr: tuple[float, ...] | None) -> None:
    """The backend's check of each pose (units, reach), naming the first bad one: a pose in metres
    would otherwise be refused as having no joint solution."""
    for i, pose in enumerate(poses):
        try:
            backend.check_pose(tuple(float(v) for v in pose), tool_xyzwpr)
        except InvalidRequest as exc:
            where = f"poses[{i}]" if what == "poses" else f"{what} {i + 1}"
            raise InvalidRequest(f"{where}: {exc}") from None


def plan_trajectory(service: Any, req: TrajectoryInput) -> tuple[msg.Trajectory, dict[str, Any]]:
    """Validate, plan and check a replay for the arm as it rests now; the request and a summary."""
    if service.backend.name != "fanuc":
        raise InvalidRequest(f"not supported by the {service.backend.name.capitalize()} backend: trajectory "
                             "replay streams planned joint positions (FANUC J519); move through points with "
                             "POST /api/target")
    given = [k for k in ("joints", "poses", "csv_text", "log") if getattr(req, k) is not None]
    if len(given) != 1:
        raise InvalidRequest(f"give exactly one of joints, poses, a CSV body or log (got {given or 'none'})")
    check_speed_scale(req.speed_scale)
    if req.pace not in ("recorded", "limits"):
        raise InvalidRequest(f"pace={req.pace!r} must be 'recorded' or 'limits'")
    profile = service.profile
    dof = profile.dof
    # The request's own values first (422), before the state (409).
    joints = poses = rows = None
    path: Path | None = None
    row_dt: float | None = None  # a log's own interval (a CSV: one row per stream interval)
    fmt = "joints"
    if req.blend and req.joints is None:
        raise InvalidRequest("blend=true: only with joints (a joint spline through the waypoints); poses are "
                             "straight TCP lines and a CSV or a log one dense path already: send their joints, "
                             "or drop blend")
    if req.blend and req.times is not None:
        raise InvalidRequest("times: not with blend=true (a blended path is one motion, timed as fast as the "
                             "limits allow); drop times, or send blend=false to reach each waypoint at its time")
    if req.joints is not None:
        joints = _rows("joints", req.joints, dof)
        times = _times(req.times, len(joints))
    elif req.poses is not None:
        poses = _rows("poses", req.poses, 6)
        times = _times(req.times, len(poses))
    else:
        if req.times is not None:
            raise InvalidRequest("times: only with joints or poses (a CSV or a log is timed within the limits); "
                                 "drop times")
        times = None
        if req.csv_text is not None:
            rows, fmt = read_csv_rows(req.csv_text)
        else:
            try:
                path = service.session_log_path(str(req.log))
            except FileNotFoundError:
                raise InvalidRequest(f"log={req.log!r}: no such session log (GET /api/sessions lists them)") from None
            rows = read_log_window(path, str(req.log), req.from_s, req.to_s, req.from_unix, req.to_unix)
            row_dt = _log_interval_s(path)
    tool = service.tools.active
    if poses is not None:  # the active tool's TCP
        _check_poses(service.backend, poses, "poses", None if tool.is_flange else tool.xyzwpr)
    elif rows is not None and fmt == "xyzwpr":  # the flange, as servo-app check reads them
        _check_poses(service.backend, rows, "csv row", None)
    s = service.state()
    if s["state"] not in _PLANNABLE:
        raise CommandRejected(f"trajectory refused in {s['state']}: the plan starts where the arm rests in a "
                              "running stream; start a session first: POST /api/session/start")
    if not s.get("at_rest"):
        raise CommandRejected("trajectory refused: the arm is moving; wait until GET /api/state shows at_rest, "
                              "then send it again")
    q_now = np.array(s["q_cmd"][:dof], dtype=float)
    cfg = service.cfg
    dt = (cfg.interval_ms or profile.interval_ms) / 1000.0
    # The limits the controller checks: its own tables when this stream read them (they may be tighter
    # than the profile's), at the active tool's payload; Cartesian waypoints are that tool's TCP.
    received = service.last_event(msg.LimitTablesReceived) if s.get("tables_from_controller") else None
    tables = received.tables if isinstance(received, msg.LimitTablesReceived) else default_tables(profile)
    planner = TrajectoryPlanner.for_stream(profile, dt, tables, q_now,
                                           cap=cfg.flange_speed_cap, payload_kg=tool.payload_kg,
                                           limit_fraction=cfg.limit_fraction, speed_scale=req.speed_scale,
                                           tool_xyzwpr=None if tool.is_flange else tool.xyzwpr)
    try:
        if joints is not None:
            segments = planner.joint_segments(q_now, joints, times, blend=req.blend)
            label = f"{len(joints)} joint waypoints" + (", blended" if req.blend else "")
        elif poses is not None:
            segments, _ = planner.cartesian_segments(q_now, poses, times)
            label = f"{len(poses)} poses"
        elif fmt == "xyzwpr":
            assert rows is not None
            segments = planner.dense_pose_segments(q_now, rows, "csv", recorded_pace=req.pace == "recorded")
            label = f"{len(rows)} CSV poses"
        else:
            assert rows is not None
            what = "csv" if req.csv_text is not None else "log"
            segments = planner.dense_segments(q_now, rows, what, recorded_pace=req.pace == "recorded",
                                              row_dt=row_dt)
            label = f"{len(rows)} rows of " + ("a CSV" if what == "csv" else f"log {req.log}")
        if not segments:
            raise TrajectoryRefused(_nothing_to_do(req, rows, path, q_now))
        timed: TimedTrajectory = planner.plan(segments)
    except TrajectoryRefused as exc:
        raise InvalidRequest(str(exc)) from None
    summary = {"samples": len(timed.samples), "duration_s": round(timed.duration_s, 4),
               "ramp_s": round(timed.ramp_steps * dt, 4), "label": label,
               "approach": not np.allclose(timed.samples[0], timed.samples[min(1, len(timed.samples) - 1)])}
    return msg.Trajectory(joints=timed.samples, ramp_steps=timed.ramp_steps, label=label), summary
