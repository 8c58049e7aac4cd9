"""What the servo process does with a trajectory plan between two statuses: the time it holds the cycle.

A plan reaches the servo process whole (``messages.Trajectory``: float32 FANUC deg, one row per cycle)
and is taken between two status packets: unpickled from the request pipe, checked
(``ServoCycle.check_replay``: shape, type, every value finite as float32) and handed to the player
(``ReplayPlayer``). Nothing answers the controller meanwhile, so at 4 ms this must stay well inside an
interval even for the largest plan (``MAX_SAMPLES``). Timed here with the caches cold, as after the
wait for a status packet (64 MB touched before each run): the first run (the process's first plan: its
arrays' memory is new, page faults included, as for a plan in a live servo process) and the median and
maximum of the ``--runs`` after it (memory the allocator kept from the run before).

    .venv/bin/python bench/plan_intake.py [--samples 100000] [--runs 15] [--no-write]
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section

from servo_app import messages as msg
from servo_app.motion.servo import ServoCycle
from servo_app.motion.trajectory import MAX_SAMPLES, ReplayPlayer
from servo_app.robots.profile import load_profile

HOME = np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0])


def intake(data: bytes, cycle: ServoCycle) -> ReplayPlayer:
    req = pickle.loads(data)
    q = cycle.check_replay(req.joints)
    return ReplayPlayer(q, req.ramp_steps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=MAX_SAMPLES)
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    plan = (HOME + np.cumsum(rng.normal(scale=1e-3, size=(args.samples, 6)), axis=0)).astype(np.float32)
    data = pickle.dumps(msg.Trajectory(joints=plan, ramp_steps=25), protocol=pickle.HIGHEST_PROTOCOL)
    cycle = ServoCycle(load_profile("lrmate200id"), 0.004)
    cycle.begin(HOME, None)
    junk = np.ones(8_000_000)
    times = []
    for _ in range(args.runs + 1):
        junk.sum()  # caches cold, as after the wait for a status packet
        t = time.perf_counter()
        player = intake(data, cycle)
        times.append((time.perf_counter() - t) * 1e3)
        assert player.total == args.samples
    first, p50, worst = times[0], float(np.median(times[1:])), max(times[1:])
    text = ("| samples | MB | first intake ms | then p50 ms | then max ms |\n|---|---|---|---|---|\n"
            f"| {args.samples} | {len(data) / 1e6:.1f} | {first:.2f} | {p50:.2f} | {worst:.2f} |")
    print(text)
    print(f"plan intake: {args.samples} samples, the first taken in {first:.2f} ms, then {p50:.2f} ms (p50)")
    if not args.no_write:
        write_section("plan_intake", command_line(__file__), text)


if __name__ == "__main__":
    main()
