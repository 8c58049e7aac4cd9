"""Per-cycle cost of the servo pipeline and stop quality.

1. command -> diff-IK -> shaper -> encoded command packet, over N cycles of mixed teleop input (twists
   in base and tool frame changing every 50-500 ms, pose targets, joint jogs, stops): p50/p99/p99.9/max.
2. Stop from full speed: cycles until the commanded position stops changing, divided by the
   time-optimal stop time from the same state (ruckig's profile at the same limits).

Cycles are also reported by the kind of the live command (twist, pose target, joint jog, stop), with
the diff-IK's own share (``DifferentialIK.step``, timed inside the same cycles) and the rest of each
cycle without it (shaper, guards, conversions, packet): twist cycles are what a Cartesian jog costs,
joint cycles mostly skip the IK.

Prints a table and writes its section of bench/RESULTS.md with the command line.
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from pathlib import Path

import numpy as np

from servo_app.fanuc.packets import Command, Status
from servo_app.motion.commands import PoseTarget, Twist
from servo_app.motion.servo import ServoCycle, ServoSettings
from servo_app.robots.conventions import matrix_to_xyzwpr
from servo_app.robots.profile import load_profile

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section

HOME = np.array([0.0, 10.0, -10.0, 0.0, -70.0, 0.0])


KINDS = ("twist", "pose", "jog", "stop")


def pipeline(cycles: int, interval_ms: int, solver: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cycle: wall time (us), the kind of live command (index into KINDS) and the time spent in
    the diff-IK's step (us; 0 when the cycle did not call it)."""
    profile = load_profile("lrmate200id")
    dt = interval_ms / 1000
    cycle = ServoCycle(profile, dt, ServoSettings(ik_solver=solver))
    ik_us = 0.0
    step = cycle.ik.step_owned  # (step and step_again call it)

    def timed_step(*args, **kwargs):  # the IK's share of the cycle, measured inside it
        nonlocal ik_us
        t = time.perf_counter()
        try:
            return step(*args, **kwargs)
        finally:
            ik_us += time.perf_counter() - t

    cycle.ik.step_owned = timed_step  # type: ignore[method-assign]
    rng = np.random.default_rng(seed)
    status = Status(seq=1, status=7)
    times = np.empty(cycles)
    kinds = np.zeros(cycles, dtype=int)
    ik_times = np.zeros(cycles)
    kind_now = 0
    cycle.begin(HOME, None)
    # As the servo process does: the first calls (lazy set-up) happen before streaming, and start-up
    # objects are frozen out of the garbage collector's scans.
    for _ in range(200):
        cycle.twist(Twist(source="warm-up", stamp=0.0, linear=(50.0, 0.0, 0.0)))
        cycle.next_command(status)
    cycle.begin(HOME, None)
    gc.collect()
    gc.freeze()
    next_change = 0
    seq = 1
    for k in range(cycles):
        ik_us = 0.0
        t0 = time.perf_counter()
        if k >= next_change:
            next_change = k + int(rng.integers(int(0.05 / dt), int(0.5 / dt)))
            kind = rng.random()
            kind_now = 0 if kind < 0.55 else 1 if kind < 0.7 else 2 if kind < 0.9 else 3
            if kind < 0.55:
                cycle.twist(Twist(source="bench", stamp=k * dt, frame=str(rng.choice(["base", "tool"])),
                                  linear=tuple(rng.uniform(-150, 150, 3)), angular=tuple(rng.uniform(-20, 20, 3))))
            elif kind < 0.7:
                home = matrix_to_xyzwpr(cycle.kin.fk_fanuc_deg(HOME))
                cycle.pose_target(PoseTarget(source="bench", stamp=k * dt, xyzwpr=tuple(home + rng.uniform(-60, 60, 6)
                                                                                      * [1, 1, 1, 0.2, 0.2, 0.2]),
                                             linear_speed=200.0, angular_speed=40.0))
            elif kind < 0.9:
                cycle.jog_joints(rng.uniform(-30, 30, 6))
            else:
                cycle.stop(fast=bool(rng.random() < 0.3))
        q = cycle.next_command(status)
        Command(seq=seq, values=tuple(float(v) for v in q)).encode()
        seq += 1
        times[k] = time.perf_counter() - t0
        kinds[k] = kind_now
        ik_times[k] = ik_us
    return times * 1e6, kinds, ik_times * 1e6


def stop_ratio(interval_ms: int, fast: bool) -> tuple[float, float]:
    """(measured stop time, time-optimal stop time) from a full-speed joint jog, seconds."""
    profile = load_profile("lrmate200id")
    dt = interval_ms / 1000
    cycle = ServoCycle(profile, dt)
    cycle.begin(HOME, None)
    cycle.jog_joints(np.array([400.0, 0, 0, 0, 0, 0]))  # J1 toward +170, at the speed limit
    status = Status(seq=1, status=7)
    for _ in range(int(0.5 / dt)):
        cycle.next_command(status)
    assert cycle.shaper is not None
    optimal = cycle.shaper.optimal_stop_duration("fast" if fast else "soft")
    cycle.stop(fast=fast)
    prev = cycle.next_command(status)
    n = 1
    while True:
        q = cycle.next_command(status)
        n += 1
        if np.array_equal(q, prev):
            break
        prev = q
    return (n - 1) * dt, optimal


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--cycles", type=int, default=50_000)
    ap.add_argument("--interval-ms", type=int, default=8, choices=(4, 8))
    ap.add_argument("--solver", default="daqp", choices=("daqp", "osqp"))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    us, kinds, ik_us = pipeline(args.cycles, args.interval_ms, args.solver, args.seed)
    lines = [
        f"Pipeline (command -> IK ({args.solver}) -> shaper -> packet), {args.cycles} cycles at {args.interval_ms} ms:",
        "",
        "| cycles | n | p50 us | p99 us | p99.9 us | max us | over 1 ms | IK step p50 us | IK step p99 us "
        "| non-IK p50 us |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups = [("all", np.ones(len(us), dtype=bool))] + [(name, kinds == i) for i, name in enumerate(KINDS)]
    for name, sel in groups:
        if not sel.any():
            continue
        t, ik = us[sel], ik_us[sel]
        p50, p99, p999 = np.percentile(t, [50, 99, 99.9])
        stepped = ik[ik > 0.0]
        ik50, ik99 = np.percentile(stepped, [50, 99]) if len(stepped) else (float("nan"), float("nan"))
        rest50 = np.percentile(t - ik, 50)  # the cycle without the IK's step, per cycle
        lines.append(f"| {name} | {int(sel.sum())} | {p50:.0f} | {p99:.0f} | {p999:.0f} | {t.max():.0f} "
                     f"| {int(np.sum(t > 1000))} | {ik50:.0f} | {ik99:.0f} | {rest50:.0f} |")
    lines += [
        "",
        "Stop from full J1 speed (joint jog), stop time / time-optimal stop time at the same limits:",
        "",
        "| stop | measured s | optimal s | ratio |",
        "|---|---|---|---|",
    ]
    for fast in (False, True):
        measured, optimal = stop_ratio(args.interval_ms, fast)
        lines.append(f"| {'fast' if fast else 'soft'} | {measured:.3f} | {optimal:.3f} | {measured / optimal:.3f} |")
    text = "\n".join(lines)
    print(text)
    if not args.no_write:
        write_section("cycle", command_line(__file__), text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
