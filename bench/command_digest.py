"""A digest of the commands the servo cycle makes over a fixed mix of motions: the same digest means the
same commands, bit for bit. Run it in two trees to show a rework changed no command.

For each interval (8 then 4 ms) a ``ServoCycle`` (LR Mate 200iD) starts at J5 = -90 deg and runs
``--cycles`` cycles as the servo process does (``next_command`` on each status, ``solve_ahead`` after it),
under a seeded sequence of segments of 20-200 cycles each: twists in the base and tool frames (some
turning), pose targets 10-30 mm off the current pose, joint jogs, joint targets, soft and fast stops
with a resume. One segment in ten changes its command between the ahead solve and the next status, so
the dropped and re-solved paths run too. The digest covers every commanded position's bytes, each
IK result's flags and scale, and every refusal's message.

Prints one table row per interval. Two trees side by side, in one run:

    .venv/bin/python bench/ab.py --base REV --rounds 1 --no-write -- bench/command_digest.py
"""

from __future__ import annotations

import argparse
import hashlib

import numpy as np

from servo_app.errors import CommandRejected
from servo_app.motion.commands import PoseTarget, Twist
from servo_app.motion.servo import ServoCycle, ServoSettings
from servo_app.robots.conventions import matrix_to_xyzwpr
from servo_app.robots.profile import load_profile

HEADER = "| interval ms | cycles | commands digest | refused | ahead used | ahead dropped |"


def run(interval_ms: int, cycles: int, seed: int) -> tuple[str, int, int, int]:
    profile = load_profile("lrmate200id")
    dt = interval_ms / 1000
    cycle = ServoCycle(profile, dt, ServoSettings())
    q0 = np.zeros(profile.dof)
    q0[4] = -90.0
    cycle.begin(q0, None)
    rng = np.random.default_rng(seed)
    h = hashlib.sha256()
    refused = 0
    q = q0.copy()
    left, late = 0, False
    t = 0.0

    def command() -> None:
        nonlocal refused
        kind = int(rng.integers(7))
        try:
            if kind in (0, 1):  # a twist, base or tool frame, some turning
                linear = tuple(float(x) for x in rng.uniform(-60, 60, 3))
                angular = tuple(float(x) for x in rng.uniform(-10, 10, 3)) if kind else (0.0, 0.0, 0.0)
                cycle.twist(Twist(source="digest", stamp=t, frame="tool" if kind else "base", linear=linear,
                                  angular=angular))
            elif kind == 2:  # a pose target near the current pose
                pose = np.array(matrix_to_xyzwpr(cycle.kin.fk_fanuc_deg(q)))
                pose[:3] += rng.uniform(-30, 30, 3)
                cycle.pose_target(PoseTarget(source="digest", stamp=t, xyzwpr=tuple(float(x) for x in pose),
                                             linear_speed=80.0))
            elif kind == 3:
                cycle.jog_joints(rng.uniform(-8, 8, profile.dof))
            elif kind == 4:
                cycle.set_joint_target(q + rng.uniform(-5, 5, profile.dof), float(rng.uniform(0.1, 1.0)))
            elif kind == 5:
                cycle.stop(fast=bool(rng.integers(2)))
            else:
                cycle.resume()
        except (CommandRejected, ValueError) as exc:
            refused += 1
            h.update(str(exc).encode())

    for _ in range(cycles):
        if left == 0:
            command()
            left, late = int(rng.integers(20, 200)), rng.random() < 0.1
        q = cycle.next_command(None)
        h.update(np.ascontiguousarray(q, dtype=np.float64).tobytes())
        ik = cycle.last_ik if cycle.ik_active else None
        if ik is not None:
            h.update(np.array([float(int(ik.flags)), ik.scale]).tobytes())
        cycle.solve_ahead()
        left -= 1
        if late and left == 1:
            command()  # between the ahead solve and the next status
        t += dt
    return h.hexdigest()[:16], refused, cycle.ahead_used, cycle.ahead_dropped


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cycles", type=int, default=3000)
    p.add_argument("--seed", type=int, default=15)
    p.add_argument("--no-write", action="store_true", help="(nothing is written either way: for bench/ab.py)")
    args = p.parse_args(argv)
    print(HEADER)
    print("|---|---|---|---|---|---|")
    for interval_ms in (8, 4):
        digest, refused, used, dropped = run(interval_ms, args.cycles, args.seed)
        print(f"| {interval_ms} | {args.cycles} | {digest} | {refused} | {used} | {dropped} |")
    print("command digest: the same digest, the same commands")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
