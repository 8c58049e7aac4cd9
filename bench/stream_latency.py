"""Status-to-command latency of the servo process against the FANUC simulator, each in its own process.

The service starts both (as `servo-app run` does), streams at the given interval for ``--seconds``
while joint targets keep the arm moving, ends the stream, and reads the session log: its
``latency_us`` column is the time from a status packet's receipt to each command's send. Reports
p50/p99/p99.9/max, commands later than half an interval, lost status packets and the simulator's alarms.

Prints a table and writes its section of bench/RESULTS.md with the command line.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from servo_app.messages import End, JointTarget, LogClosed, LogOpened, Ready, Start
from servo_app.service import ServiceConfig, ServoService
from servo_app.session_log import SessionLog, read_session_log

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section

POSES = ([0.0, 10.0, -10.0, 0.0, -70.0, 0.0], [40.0, 30.0, -25.0, 60.0, -40.0, 90.0],
         [-35.0, -5.0, 5.0, -60.0, -95.0, -90.0])
HEADER = "| run | interval ms | lead | commands | p50 us | p99 us | p99.9 us | max us | late (> T/2) | status lost |"


def latency_row(name: str, log: SessionLog, lead: int) -> str:
    interval_ms = float(log.header["interval_ms"])
    lat = log.commands["latency_us"].astype(float)
    seq = log.statuses["seq"].astype(np.int64)
    d = np.diff(seq)
    lost = int(np.sum(d[d > 1] - 1))
    p50, p99, p999 = np.percentile(lat, [50, 99, 99.9])
    late = int(np.sum(lat > interval_ms * 500))
    return (f"| {name} | {interval_ms:g} | {lead} | {lat.size} | {p50:.0f} | {p99:.0f} | {p999:.0f} | {lat.max():.0f} "
           f"| {late} | {lost} |")


def wait_for(service: ServoService, pred: Any, timeout: float) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while True:
        s = service.state()
        if pred(s):
            return s
        if time.monotonic() > deadline:
            raise TimeoutError(f"state {s['state']}, fault {s.get('fault')}")
        time.sleep(0.01)


def closed_log(service: ServoService, timeout: float = 10.0) -> SessionLog:
    """The log of the stream that just ended, once the servo process has closed it."""
    deadline = time.monotonic() + timeout
    while True:
        opened, closed = service.last_event(LogOpened), service.last_event(LogClosed)
        if isinstance(opened, LogOpened) and isinstance(closed, LogClosed) and opened.path == closed.path:
            return read_session_log(Path(closed.path))
        if time.monotonic() > deadline:
            raise TimeoutError("the session log was not closed")
        time.sleep(0.02)


def move_through_poses(service: ServoService, seconds: float) -> int:
    """Joint targets one after another until ``seconds`` have passed; returns how many were reached."""
    end = time.monotonic() + seconds
    n = 0
    while time.monotonic() < end:
        service.request(JointTarget(joints=tuple(POSES[n % len(POSES)]), speed_scale=0.5))
        time.sleep(0.05)
        s = wait_for(service, lambda s: s["at_rest"] or s["state"] != "streaming", 30.0)
        if s["state"] != "streaming":  # a fault: report it with the figures up to it
            break
        n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=60.0, help="streaming time (default 60)")
    p.add_argument("--interval-ms", type=int, choices=(4, 8), default=4)
    p.add_argument("--lead", type=int, default=ServiceConfig.lead)
    p.add_argument("--no-write", action="store_true", help="print only; leave bench/RESULTS.md as it is")
    args = p.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        service = ServoService(ServiceConfig(var_dir=Path(tmp), interval_ms=args.interval_ms, lead=args.lead))
        service.open()
        try:
            service.request(Start())
            wait_for(service, lambda s: s["state"] == "streaming", 15.0)
            moves = move_through_poses(service, args.seconds)
            if service.state()["state"] == "streaming":
                service.request(End())
            s = wait_for(service, lambda s: s["state"] in ("ended", "fault"), 30.0)
            fault = (s.get("fault") or {}).get("message")
            log = closed_log(service)
            alarms = [e["code"] for e in service.sim_call("events")]
            ready = service.last_event(Ready)
            realtime = ready.realtime if isinstance(ready, Ready) else "?"
            sim_scheduling = service.sim_scheduling
        finally:
            service.close()

    row = latency_row(f"{args.seconds:g} s, {moves} joint moves", log, args.lead)
    print(HEADER)
    print(row)
    print(f"stream {s['state']}{f' ({fault})' if fault else ''}; simulator alarms: {alarms or 'none'}; "
          f"servo process scheduling: {realtime}, simulator: {sim_scheduling}")
    text = (
        f"Servo process vs the simulator (each its own process, loopback UDP), {args.interval_ms} ms, joint "
        f"targets through three poses at half speed. Latency = status receipt to command send, from the "
        f"session log's `latency_us` (every command).\n\n{HEADER}\n|---|---|---|---|---|---|---|---|---|---|\n{row}\n\n"
        f"Stream {s['state']}{f' ({fault})' if fault else ''}; simulator alarms: {', '.join(alarms) or 'none'}; "
        f"scheduling: servo process {realtime}, simulator {sim_scheduling}."
    )
    if not args.no_write:
        cmd = command_line(__file__, argv)
        print("wrote", write_section("stream_latency", cmd, text))
    return 0 if s["state"] == "ended" and not alarms else 1


if __name__ == "__main__":
    sys.exit(main())
