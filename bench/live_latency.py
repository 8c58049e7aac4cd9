"""The live path as users run it: `servo-app run` against its embedded simulator, Cartesian jogs over REST.

For each interval (``--interval-ms``, default 8 then 4) this starts the service in a process of its
own (``python -m servo_app.cli run --http-port P --token T --var-dir TMP --interval-ms I``: API, servo
process and simulator as a user gets them), takes the lease, starts a session and sends Cartesian jogs
(``POST /api/jog`` ±X at 40 mm/s in the base frame, ``hold_ms`` 200, renewed at 20 Hz, the direction
flipping every second) for ``--seconds``, ends the session and stops the service. From the stream's
session log (every status received and every command sent, time-stamped by the servo process):

- status -> command latency (the log's ``latency_us``: status receipt to the command's send) p50, p99,
  p99.9, max, and the commands later than half an interval (count and share);
- the first command's latency: from the ready status it answers (bit 0 set, bit 1 clear: the first
  status the servo process could start on) to its send;
- the servo process's CPU share over the jog window (``/proc/PID/stat`` utime + stime; its pid is in
  the session log's name);
- the cycle timings the servo process publishes (``/api/state``, sampled twice a second during the
  jog): the motion step per command (``solve_p50_us`` / ``solve_max_us``: IK, shaper, guards) and a
  status's whole handling in the servo process (``cycle_p50_us`` / ``cycle_max_us``: decode, safety,
  send, log, publish, requests), each a median and maximum over its last 256 cycles; their difference
  is what the live path costs beside the motion step. The IK solved ahead, between status packets
  (``solve_ahead_p50_us`` / ``solve_ahead_max_us``), is in neither and shown as "+ ahead". Other
  keys naming a solve, cycle or compute time with a unit are shown as they come; none: "-".

Prints a table (``--json``: a JSON document instead); ``--write`` writes its section of
bench/RESULTS.md with the command line. Works under ``bench/ab.py`` (table rows, then a verdict line).

    .venv/bin/python bench/live_latency.py --seconds 10 --write
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

import servo_app
from servo_app.fanuc.packets import StatusBit
from servo_app.session_log import SessionLog, read_session_log

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section

TOKEN = "bench-live-latency"
JOG_HZ = 20.0
SPEED_MM_S = 40.0
FLIP_S = 1.0
HEADER = ("| run | interval ms | commands | p50 us | p99 us | p99.9 us | max us | late (> T/2) | late % "
          "| first command us | solve us p50 / max | cycle us p50 / max | beside solve us p50 | servo CPU % |")
# /api/state keys that carry a per-cycle compute time, whatever the servo process calls them.
TIMING_KEY = re.compile(r"(solve|cycle|compute).*(_us|_ms|_s)$")
KNOWN_TIMING = {"solve_p50_us", "solve_max_us", "cycle_p50_us", "cycle_max_us", "solve_ahead_p50_us",
                "solve_ahead_max_us"}
BIT0, BIT1 = StatusBit.WAITING_FOR_COMMAND, StatusBit.COMMAND_RECEIVED


@dataclass
class Run:
    interval_ms: int
    seconds: float
    commands: int = 0
    p50_us: float = 0.0
    p99_us: float = 0.0
    p999_us: float = 0.0
    max_us: float = 0.0
    late: int = 0
    late_pct: float = 0.0
    first_us: float | None = None  # ready status -> first command
    first_seq: int | None = None
    start_ms: float | None = None  # first status with bit 0 in the log -> first command (limit tables first)
    status_lost: int = 0
    cpu_pct: float | None = None
    servo_pid: int | None = None
    jogs: int = 0
    jogs_refused: int = 0
    timing: dict[str, list[float]] = field(default_factory=dict)  # published cycle times, sampled
    state: str = ""
    fault: str | None = None
    alarms: list[str] = field(default_factory=list)

    def row(self) -> str:
        first = f"{self.first_us:.0f}" if self.first_us is not None else "-"
        cpu = f"{self.cpu_pct:.1f}" if self.cpu_pct is not None else "-"
        solve, cycle = self.window("solve"), self.window("cycle")
        beside = f"{cycle[0] - solve[0]:.0f}" if solve and cycle else "-"
        others = "; ".join(f"{k} {np.percentile(v, 50):.0f} / {max(v):.0f}" for k, v in self.timing.items()
                           if v and k not in KNOWN_TIMING)
        solve_col = f"{solve[0]:.0f} / {solve[1]:.0f}" if solve else (others or "-")
        ahead = self.window("solve_ahead")
        if ahead:  # the IK solved between status packets, outside the status -> command path
            solve_col += f" (+ ahead {ahead[0]:.0f} / {ahead[1]:.0f})"
        cycle_col = f"{cycle[0]:.0f} / {cycle[1]:.0f}" if cycle else "-"
        return (f"| jog ±X {SPEED_MM_S:g} mm/s, {self.seconds:g} s | {self.interval_ms} | {self.commands} "
                f"| {self.p50_us:.0f} | {self.p99_us:.0f} | {self.p999_us:.0f} | {self.max_us:.0f} | {self.late} "
                f"| {self.late_pct:.1f} | {first} | {solve_col} | {cycle_col} | {beside} | {cpu} |")

    def window(self, name: str) -> tuple[float, float] | None:
        """(median of the sampled medians, largest sampled maximum) of ``name``_p50_us / _max_us; None
        if the servo process does not publish them (or had not filled a window when sampled)."""
        p50 = [v for v in self.timing.get(f"{name}_p50_us", []) if v > 0]
        top = [v for v in self.timing.get(f"{name}_max_us", []) if v > 0]
        return (float(np.median(p50)), max(top)) if p50 and top else None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cpu_seconds(pid: int) -> float:
    """utime + stime of ``pid`` (s). Fields after the command name, which may hold spaces and parens."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2:].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def servo_pid(log_path: Path) -> int:
    """The servo process writing ``log_path``: its pid is in the name (session-DATE-TIME-PID-N.srvlog);
    checked against the file it has open."""
    pid = int(log_path.stem.split("-")[3])
    target = str(log_path.resolve())

    def link(fd: Path) -> str:
        try:
            return os.readlink(fd)
        except OSError:  # closed meanwhile
            return ""

    if not any(link(fd) == target for fd in Path(f"/proc/{pid}/fd").iterdir()):
        raise RuntimeError(f"pid {pid} does not write {log_path}")
    return pid


def wait_until(what: str, pred: Any, timeout: float, poll_s: float = 0.05) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        v = pred()
        if v:
            return v
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} within {timeout:g} s")
        time.sleep(poll_s)


def analyse(run: Run, log: SessionLog) -> None:
    interval_ms = float(log.header["interval_ms"])
    cmds, sts = log.commands, log.statuses
    lat = cmds["latency_us"].astype(float)
    run.commands = int(lat.size)
    if lat.size:
        run.p50_us, run.p99_us, run.p999_us = (float(v) for v in np.percentile(lat, [50, 99, 99.9]))
        run.max_us = float(lat.max())
        run.late = int(np.sum(lat > interval_ms * 500))
        run.late_pct = 100.0 * run.late / lat.size
        first = cmds[0]
        run.first_seq = int(first["seq"])
        # The first command carries the sequence number of the ready status it answers (J519).
        ready = sts[(sts["seq"] == first["seq"]) & (sts["t"] <= first["t"])]
        if ready.size and ready[-1]["flags"] & (BIT0 | BIT1) == BIT0:
            run.first_us = float((first["t"] - ready[-1]["t"]) * 1e6)
        bit0 = sts[(sts["flags"] & BIT0) != 0]
        if bit0.size:
            run.start_ms = float((first["t"] - bit0[0]["t"]) * 1e3)
    d = np.diff(sts["seq"].astype(np.int64))
    run.status_lost = int(np.sum(d[d > 1] - 1))


def jog(c: httpx.Client, headers: dict[str, str], run: Run, seconds: float) -> None:
    """Cartesian jogs at 20 Hz, the direction flipping every second; the state sampled twice a second."""
    t0 = time.monotonic()
    next_state = t0
    n = 0
    while (elapsed := time.monotonic() - t0) < seconds:
        sign = 1.0 if int(elapsed / FLIP_S) % 2 == 0 else -1.0
        r = c.post("/api/jog", headers=headers, json={"linear": [sign * SPEED_MM_S, 0, 0], "angular": [0, 0, 0],
                                                      "frame": "base", "hold_ms": 200})
        run.jogs += 1
        run.jogs_refused += r.status_code != 200
        n += 1
        if n % 40 == 0:
            c.post("/api/lease/renew", headers=headers)
        if time.monotonic() >= next_state:
            next_state += 0.5
            s = c.get("/api/state").json()
            for k, v in s.items():
                if TIMING_KEY.search(k) and isinstance(v, int | float) and not isinstance(v, bool):
                    run.timing.setdefault(k, []).append(float(v))
        time.sleep(max(0.0, t0 + n / JOG_HZ - time.monotonic()))


def one_interval(interval_ms: int, seconds: float, lead: int | None,
                 watch: Callable[[int], AbstractContextManager[Any]] | None = None) -> Run:
    """One run at ``interval_ms``; ``watch(servo pid)``, if given, is entered for the jog window
    (bench/servo_profile.py attaches its sampler so)."""
    run = Run(interval_ms=interval_ms, seconds=seconds)
    port = free_port()
    # The service runs the servo_app this script imported (a tree under test, e.g. from bench/ab.py).
    tree = str(Path(servo_app.__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([tree, *filter(None, [os.environ.get("PYTHONPATH")])])}
    with tempfile.TemporaryDirectory(prefix="live-latency-") as tmp:
        var = Path(tmp)
        cmd = [sys.executable, "-m", "servo_app.cli", "run", "--http-port", str(port), "--token", TOKEN,
               "--var-dir", str(var), "--interval-ms", str(interval_ms)]
        if lead is not None:
            cmd += ["--lead", str(lead)]
        out = open(var / "service.out", "w")  # noqa: SIM115 - closed below, after the service
        svc = subprocess.Popen(cmd, cwd=tmp, env=env, stdout=out, stderr=subprocess.STDOUT)
        try:
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=15.0) as c:
                def up() -> bool:
                    if svc.poll() is not None:
                        raise RuntimeError(f"the service exited ({svc.returncode}): "
                                           f"{(var / 'service.out').read_text()[-800:]}")
                    try:
                        return c.get("/api/health").status_code == 200
                    except httpx.TransportError:
                        return False

                wait_until("the API up", up, 60.0)
                auth = {"Authorization": f"Bearer {TOKEN}"}
                r = c.post("/api/lease", json={"client": "bench", "force": True}, headers=auth)
                r.raise_for_status()
                headers = {**auth, "X-Lease-Id": r.json()["lease_id"]}
                r = c.post("/api/session/start", headers=headers)
                if r.status_code != 200:
                    raise RuntimeError(f"start refused: {r.text}")
                logs = wait_until("the session log", lambda: sorted((var / "sessions").glob("*.srvlog")), 10.0)
                run.servo_pid = pid = servo_pid(logs[-1])
                with watch(pid) if watch is not None else contextlib.nullcontext():
                    cpu0, t0 = cpu_seconds(pid), time.monotonic()
                    jog(c, headers, run, seconds)
                    cpu1, t1 = cpu_seconds(pid), time.monotonic()
                run.cpu_pct = 100.0 * (cpu1 - cpu0) / (t1 - t0)
                c.post("/api/session/end", headers=headers)
                def ended() -> dict[str, Any] | None:
                    s = c.get("/api/state").json()
                    return s if s["state"] in ("ended", "fault") and s["link"] in ("closed", "fault") else None

                s = wait_until("the stream ended", ended, 30.0)
                run.state = s["state"]
                run.fault = (s.get("fault") or {}).get("message")
                run.alarms = [a.get("code", "?") for a in s.get("alarm_history") or []]
            analyse(run, read_session_log(logs[-1]))
        finally:
            if svc.poll() is None:
                svc.send_signal(signal.SIGINT)  # the service's own clean stop
                try:
                    svc.wait(30)
                except subprocess.TimeoutExpired:
                    svc.kill()
                    svc.wait(10)
            out.close()
    return run


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=10.0, help="jogging time per interval (default 10)")
    p.add_argument("--interval-ms", type=int, choices=(4, 8), nargs="+", default=[8, 4])
    p.add_argument("--lead", type=int, default=None, help="default: the service's")
    p.add_argument("--json", action="store_true", help="print the figures as JSON instead of the table")
    p.add_argument("--write", action="store_true", help="write this benchmark's section of bench/RESULTS.md")
    p.add_argument("--no-write", action="store_true", help="never write bench/RESULTS.md (bench/ab.py adds it)")
    args = p.parse_args(argv)

    runs = [one_interval(i, args.seconds, args.lead) for i in args.interval_ms]
    ok = all(r.state == "ended" and not r.alarms and r.jogs_refused == 0 for r in runs)
    verdict = "; ".join(
        f"{r.interval_ms} ms: stream {r.state}{f' ({r.fault})' if r.fault else ''}, "
        f"alarms {', '.join(r.alarms) or 'none'}, "
        f"{r.jogs} jogs ({r.jogs_refused} refused), {r.status_lost} status lost, first command seq {r.first_seq}"
        for r in runs)
    if args.json:
        print(json.dumps({"runs": [asdict(r) for r in runs], "ok": ok}, indent=1))
        return 0 if ok else 1
    rows = [r.row() for r in runs]
    print(HEADER)
    print("\n".join(rows))
    print(verdict)
    if args.write and not args.no_write:
        cmd = command_line(__file__, argv)
        text = (
            f"`servo-app run` against its embedded simulator (API, servo process and simulator each in their "
            f"own process), Cartesian jogs over REST: ±X at {SPEED_MM_S:g} mm/s in the base frame, renewed at "
            f"{JOG_HZ:g} Hz, flipping every {FLIP_S:g} s. Latency = status receipt to command send, from the "
            f"session log; first command = from the ready status it answers to its send; servo CPU = its "
            f"utime + stime over the jog window; solve = the motion step per command, cycle = a status's "
            f"whole handling in the servo process, as it publishes them (sampled from /api/state; '-': none "
            f"published; + ahead: the IK solved between status packets, in neither); beside solve = cycle - solve.\n\n"
            f"{HEADER}\n{'|---' * HEADER.count(' | ')}|---|\n" + "\n".join(rows) + f"\n\n{verdict}."
        )
        print("wrote", write_section("live_latency", cmd, text))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
