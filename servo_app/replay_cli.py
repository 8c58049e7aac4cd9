"""``servo-app replay FILE``: replay a path on a running service (``POST /api/trajectory``), printing
its progress.

FILE is a CSV in ``servo-app check``'s form (J1..J6 rows, or flange poses under an ``x,y,z,w,p,r``
header), a JSON body for POST /api/trajectory (``{"joints": [...], "times": [...]}``, ``{"joints": [...],
"blend": true}``, ``{"poses": ...}`` or ``{"log": NAME, "from_s": ..., "to_s": ...}``), or a session
log (.srvlog): one the service lists (same name and size) is replayed by name, any other is sent as
the CSV of its commands (joints, or a Cartesian log's flange poses under the header ``x,y,z,w,p,r``);
a Janome log is refused.

Exit code: 0 the replay ended at rest at its end; 1 it was stopped (from elsewhere too: the replay
then waits, paused, for a resume), ended short or the arm faulted;
2 refused (the message names the field and value) or the service is not reachable. Ctrl-C stops the
arm (a soft stop: it pauses along the path) and exits with 130.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

from servo_app.client import FaultError, RefusedError, ServoClient, ServoError, StoppedError
from servo_app.client import TimeoutError as ClientTimeout
from servo_app.stop_signals import stop_requested

_POLL_S = 0.2


def add_replay_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser("replay", help="replay waypoints, a CSV or a session log on a running service",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("file", help="CSV (as `servo-app check` reads), JSON body, or session log (.srvlog)")
    p.add_argument("--url", default="http://127.0.0.1:8000", help="the service (default: %(default)s)")
    p.add_argument("--token", default=None, help="bearer token (default: $SERVO_APP_TOKEN)")
    p.add_argument("--speed-scale", type=float, default=1.0, help="share of the joint speed limits, 0.001 to 1")
    p.add_argument("--pace", choices=("recorded", "limits"), default="recorded",
                   help="a CSV or log: no faster than recorded (default), or as fast as the limits allow")
    p.add_argument("--take-over", action="store_true", help="take the lease from another holder")
    p.add_argument("--timeout", type=float, default=600.0, help="give up waiting after this long (s)")
    p.set_defaults(handler=run_replay)
    return p


def _request(path: Path, client: ServoClient) -> dict[str, Any]:
    """The keyword arguments of ``ServoClient.replay`` for ``path``."""
    from servo_app.session_log import is_session_log

    if is_session_log(path):
        # By name only when it is the service's own (the same size): another file of the same name (a
        # log cut down or copied from elsewhere) replayed the service's instead of the one given.
        listed = {entry.get("name"): entry.get("bytes") for entry in client._call("GET", "/api/sessions")}
        if listed.get(path.name, -1) == path.stat().st_size:
            return {"log": path.name}
        from servo_app.check_cli import load_trajectory
        from servo_app.session_log import read_session_log

        if str(read_session_log(path).header.get("protocol", "")).startswith("janome"):
            raise ValueError(f"{path}: a Janome session log (X Y Z R targets): replay takes FANUC logs, of "
                             "joints or X Y Z W P R")
        traj = load_trajectory(path)
        # A Cartesian log's rows are flange poses: under check's header, not read as joints.
        head = "x,y,z,w,p,r\n" if traj.fmt == "xyzwpr" else ""
        return {"csv": head + "\n".join(",".join(f"{v:.6f}" for v in row) for row in traj.values) + "\n"}
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file nor a session log: give a CSV, a JSON body or a "
                         ".srvlog") from None
    if path.suffix.lower() == ".json":
        try:
            body = json.loads(text)
        except ValueError as exc:
            raise ValueError(f"{path}: not JSON ({exc}): give a POST /api/trajectory body, e.g. "
                             '{"joints": [[J1, ..., J6], ...]}') from None
        keys = ("joints", "poses", "times", "log", "from_s", "to_s", "blend")
        if not isinstance(body, dict) or not any(k in body for k in keys):
            raise ValueError(f"{path}: a JSON body needs one of joints, poses or log (an object such as "
                             '{"joints": [[J1, ..., J6], ...]}), not ' + json.dumps(body)[:60])
        return {k: body[k] for k in keys if k in body}
    return {"csv": text}


def run_replay(args: argparse.Namespace) -> int:
    path = Path(args.file)
    if not path.is_file():
        print(f"servo-app replay: {path}: no such file", file=sys.stderr)
        return 2
    try:
        # The handlers from the start: a signal between the replay's request and _follow (a replay already
        # playing) ended the command by SIGTERM's default (-15, seen under load), the arm left playing.
        with stop_requested() as interrupted, ServoClient(args.url, args.token, name="servo-app replay",
                                                           take_over=args.take_over) as arm:
            kwargs = _request(path, arm)
            arm.ensure_streaming()
            # A resume (after the take-over's stop) answers once streaming, and the arm may still count
            # as moving for a cycle: a trajectory sent at once was refused ("the arm is moving").
            arm.wait_settled()
            if interrupted.is_set():
                print("servo-app replay: interrupted before the replay was sent: nothing replayed",
                      file=sys.stderr)
                return 130
            summary = arm.replay(**kwargs, speed_scale=args.speed_scale, pace=args.pace, wait=False)
            print(f"replaying {summary.get('label', path.name)}: {summary.get('samples')} samples, "
                  f"{summary.get('duration_s')} s", flush=True)
            return _follow(arm, args.timeout, interrupted)
    except RefusedError as exc:
        print(f"servo-app replay: refused: {exc}", file=sys.stderr)
        return 2
    except FaultError as exc:
        print(f"servo-app replay: fault: {exc}", file=sys.stderr)
        return 1
    except (StoppedError, ClientTimeout) as exc:
        print(f"servo-app replay: {exc}", file=sys.stderr)
        return 1
    except (ServoError, OSError, ValueError) as exc:
        print(f"servo-app replay: {exc}", file=sys.stderr)
        return 2


def _follow(arm: ServoClient, timeout: float, interrupted: threading.Event) -> int:
    """Print progress until the replay is done at rest; Ctrl-C (or SIGTERM: ``interrupted``) stops the arm."""
    deadline = time.monotonic() + timeout
    last = ""
    while not interrupted.is_set():
        s = arm.state()
        t = s.trajectory
        if s.state == "fault":
            raise arm._fault_of(s)
        if t is not None:
            share = 100.0 * t.index / max(1, t.total - 1)
            line = f"{t.state:8s} {share:5.1f} %  {t.time_s:7.2f} / {t.total_s:.2f} s"
            if line != last:
                print(line, flush=True)
                last = line
            if t.state == "done" and s.at_rest:
                return 0
            if t.state == "ended":
                print("servo-app replay: the replay was ended before its end (a fast stop or another "
                      "command)", file=sys.stderr)
                return 1
            if t.state == "paused" and s.state == "stopped" and s.at_rest:
                # Stopped from elsewhere (a stop request, the lease taken): not done, and nothing here
                # resumes it (it waited out --timeout, 10 min by default).
                print(f"servo-app replay: the arm was stopped ({s.stop_reason or 'a stop'}) with the replay "
                      f"paused at {share:.1f} %: POST /api/session/resume continues it", file=sys.stderr)
                return 1
        if time.monotonic() > deadline:
            print(f"servo-app replay: not done within {timeout:g} s", file=sys.stderr)
            return 1
        interrupted.wait(_POLL_S)
    arm.stop(fast=False, wait=False)
    print("servo-app replay: interrupted: the arm pauses along the path (POST /api/session/resume "
          "continues it)", file=sys.stderr)
    return 130
