"""What being asleep between status packets costs the same work: the machine's floor under the servo CPU.

The servo process sleeps for most of each interval. On these shared virtual machines the host runs
other work meanwhile and the process wakes to caches, TLB and branch predictors emptied, so the same
instructions take several times longer than in a tight loop. This times the servo cycle's motion step
for a Cartesian jog (``ServoCycle.solve_ahead``, the IK solved between packets, and ``next_command``,
the command made on the packet: shaper, guards) in this process alone, scheduled as the live servo
process (SCHED_FIFO 20, CPU wake-up latency held at 0 us), asleep for each of ``--gaps-ms`` before each
cycle (0: a tight loop), then the command and at once the IK ahead, as the live loop runs them on a
status, with nothing else running here. The jog is live_latency's (+-X 40 mm/s,
flipped every second of cycles).

Reports the p50 of each call in us, and of both together (the motion's CPU per status) with its ratio
to the tight loop. A ratio that grows with the gap while nothing else runs in the process is the host's
doing: no change to the cycle's code lowers it, only less code and data touched per status. Under
``bench/ab.py`` a tree without the IK solved ahead (before issue 15) solves it in the command.

    .venv/bin/python bench/sleep_cold.py [--cycles 600] [--gaps-ms 0 0.5 2 4 8] [--no-write]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from servo_app.fanuc.packets import Status
from servo_app.motion.commands import Twist
from servo_app.motion.servo import ServoCycle, ServoSettings
from servo_app.robots.profile import load_profile

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section
from servo_loop import FLIP_S, scheduled_as_live

HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])
SPEED_MM_S = 40.0


def run(cycles: int, gap_s: float, dt: float = 0.008) -> tuple[float | None, float, float]:
    """p50 (us) of the IK solved ahead (None: a tree without it), of the command and of the two, each
    cycle after ``gap_s`` asleep."""
    cycle = ServoCycle(load_profile("lrmate200id"), dt, ServoSettings())
    cycle.begin(HOME, None)
    status = Status(seq=1)
    flip = round(FLIP_S / dt)
    solve_ahead = getattr(cycle, "solve_ahead", None)
    ahead, command, both = [], [], []
    for k in range(cycles + 100):  # the first 100: the jog gets going, lazy set-up is paid
        if k % flip == 0:
            sign = 1.0 if (k // flip) % 2 == 0 else -1.0
            cycle.twist(Twist(source="bench", stamp=k * dt, linear=(sign * SPEED_MM_S, 0.0, 0.0)))
        if gap_s:
            time.sleep(gap_s)
        t0 = time.perf_counter()
        cycle.next_command(status)
        t1 = time.perf_counter()
        if solve_ahead is not None:
            solve_ahead()
        t2 = time.perf_counter()
        if k >= 100:
            command.append(t1 - t0)
            ahead.append(t2 - t1)
            both.append(t2 - t0)
    p50 = lambda xs: float(np.median(xs)) * 1e6  # noqa: E731
    return (p50(ahead) if solve_ahead is not None else None), p50(command), p50(both)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=600, help="timed cycles per gap")
    ap.add_argument("--gaps-ms", type=float, nargs="+", default=[0.0, 0.5, 2.0, 4.0, 8.0])
    ap.add_argument("--no-write", action="store_true", help="print only, leave bench/RESULTS.md alone")
    args = ap.parse_args(argv)
    with scheduled_as_live() as hold:
        rows = [(gap, *run(args.cycles, gap / 1000)) for gap in args.gaps_ms]
    tight = next((b for gap, _, _, b in rows if gap == 0.0), None)
    lines = ["| asleep before each cycle ms | IK ahead p50 us | command p50 us | both p50 us | x tight |",
             "|---|---|---|---|---|"]
    for gap, a, c, b in rows:
        ahead = "-" if a is None else f"{a:.0f}"
        ratio = f"{b / tight:.1f}" if tight else "-"
        lines.append(f"| {gap:g} | {ahead} | {c:.0f} | {b:.0f} | {ratio} |")
    text = "\n".join(lines)
    print(text)
    print(f"sleep cold: the motion step alone in this process, scheduled as the live servo process ({hold.status})")
    if not args.no_write:
        print(f"written to {write_section('sleep_cold', command_line(__file__, argv), text)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
