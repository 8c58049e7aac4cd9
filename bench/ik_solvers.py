"""Benchmark: the diff-IK QP built and solved by us (persistent OSQP, DAQP) and by mink.solve_ik (OSQP, DAQP).

Same inputs for every solver: the LR Mate 200iD diff-IK problem (TCP frame task + posture task, all
limits incl. collisions) at teleop states of two kinds:

- ``stream``: consecutive cycles of a random twist stream (what the servo cycle sees; warm starts help);
- ``random``: independent random poses, previous velocities and twists (no continuity).

Reported per solver: time per cycle p50/p99, building the problem included on both sides (mink's
``solve_ik`` builds its tasks' and limits' objects every call; ours is ``DifferentialIK.qp_problem``,
what the servo cycle builds, timed on its own row as well), and the largest difference from the exact
reference (DAQP through mink) in rad/s (p99 and max). Each state's solvers run in a rotating order
(ours, mink DAQP, mink OSQP; then starting with the next): the first to run after a state was made
meets caches the state's making left cold (random states: mink's objective and the condition number;
stream states: the IK's own step, which warms ours), and each solver comes first equally often.
The last lines give the speed-up of our build plus solve over ``mink.solve_ik`` (ratio of the p50s).
The table is printed and written to bench/RESULTS.md under "## ik_solvers" (other sections are kept).

    .venv/bin/python bench/ik_solvers.py [--states 2000] [--seed 0] [--no-write] [--section NAME]
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
import warnings
from pathlib import Path

import mink
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
from results import command_line, write_section  # noqa: E402

# servo_app from PYTHONPATH (or the installed package), not from this file's tree: bench/ab.py runs this
# script in the base revision's tree too, with that tree on PYTHONPATH.
from servo_app.motion.commands import Twist  # noqa: E402
from servo_app.motion.diffik import DifferentialIK  # noqa: E402
from servo_app.motion.qp import PersistentQP  # noqa: E402
from servo_app.robots.profile import load_profile  # noqa: E402

DT = 0.008
SECTION = "## ik_solvers"


def stream_states(ik: DifferentialIK, n: int, rng: np.random.Generator):
    """The IK's own QP along a random teleop stream (twists held for ~0.3 s, then changed)."""
    q = np.radians([0.0, 10.0, 10.0, 0.0, -70.0, 0.0])
    ik.reset(q)
    cmd = None
    for k in range(n):
        if k % 40 == 0:
            cmd = Twist(linear=tuple(rng.uniform(-400, 400, 3)), angular=tuple(rng.uniform(-60, 60, 3)),
                        source="bench", stamp=0.0)
        q_next = ik.step(q, cmd).q_next
        target = ik.frame_target
        assert target is not None
        ik.frame_task.set_target(mink.SE3(target))  # mink's problem: the same target
        yield [ik.frame_task, ik.posture_task], target  # the step left configuration and limits at its state
        q = q_next


def random_states(ik: DifferentialIK, n: int, rng: np.random.Generator):
    """Independent states: pose, last cycle's increment and a commanded twist, all random."""
    lo, hi = np.radians(ik.profile.joint_min_deg), np.radians(ik.profile.joint_max_deg)
    made = 0
    while made < n:
        q = rng.uniform(lo * 0.85, hi * 0.85)
        if ik.condition_number(q) > 80.0:
            continue
        ik.reset(q)
        ik.configuration.update(q)
        ik.accel_limit.set_previous(rng.uniform(-1, 1, 6) * ik.vel * DT * rng.uniform(0, 0.6))
        tcp = ik.configuration.get_transform_frame_to_world(ik.site, "site")
        xi = np.concatenate([rng.uniform(-0.8, 0.8, 3), np.radians(rng.uniform(-90, 90, 3))])
        target = tcp @ mink.SE3.exp(xi * DT)
        ik.frame_task.set_target(target)
        tasks = [ik.frame_task, ik.posture_task]
        p, c = ik.objective(tasks)
        ik.path_braking.set_direction(np.linalg.solve(p, -c))
        made += 1
        yield tasks, target.wxyz_xyz.copy()


def timed(fn, *args):
    """fn(*args) and its wall time in microseconds."""
    t0 = time.perf_counter_ns()
    out = fn(*args)
    return out, (time.perf_counter_ns() - t0) / 1000.0


def run(kind: str, n: int, seed: int) -> dict[str, dict[str, float]]:
    rng = np.random.default_rng(seed)
    ik = DifferentialIK(load_profile("lrmate200id"), DT, collision=True)
    gen = stream_states(ik, n, rng) if kind == "stream" else random_states(ik, n, rng)
    ours_osqp: PersistentQP | None = None
    ours_daqp: PersistentQP | None = None
    times: dict[str, list[float]] = {k: [] for k in ("build (ours)", "build + persistent OSQP",
                                                     "build + persistent DAQP", "mink.solve_ik osqp",
                                                     "mink.solve_ik daqp")}
    diffs: dict[str, list[float]] = {k: [] for k in times}
    fails: dict[str, int] = dict.fromkeys(times, 0)
    m = 0

    Timings = dict[str, float]
    Answers = dict[str, np.ndarray | None]

    def ours(tasks, target: np.ndarray) -> tuple[Timings, Answers]:
        # The cycle's order: build, then solve. Both persistent solvers get the same build.
        assert ours_osqp is not None and ours_daqp is not None
        t0 = time.perf_counter_ns()
        p, c, g, h = ik.qp_problem(target)
        build = (time.perf_counter_ns() - t0) / 1000.0
        sd, t_sd = timed(ours_daqp.solve, p, c, g, h)
        so, t_so = timed(ours_osqp.solve, p, c, g, h)
        return ({"build (ours)": build, "build + persistent DAQP": build + t_sd,
                 "build + persistent OSQP": build + t_so},
                {"build + persistent DAQP": sd.x if sd.ok else None,
                 "build + persistent OSQP": so.x if so.ok else None})

    def mink_daqp(tasks, target: np.ndarray) -> tuple[Timings, Answers]:
        x, t = timed(_mink, ik, tasks, "daqp")
        return {"mink.solve_ik daqp": t}, {"mink.solve_ik daqp": x}

    def mink_osqp(tasks, target: np.ndarray) -> tuple[Timings, Answers]:
        x, t = timed(_mink, ik, tasks, "osqp")
        return {"mink.solve_ik osqp": t}, {"mink.solve_ik osqp": x}

    gc.disable()
    try:
        for k, (tasks, target) in enumerate(gen):
            if ours_osqp is None or ours_daqp is None:
                m = ik.qp_problem(target)[2].shape[0]
                ours_osqp = PersistentQP(6, m, "osqp", var_scale=DT)
                ours_daqp = PersistentQP(6, m, "daqp", var_scale=DT)
            # Each state's solvers in a rotating order: whichever runs first after the state was made
            # (by other code) meets colder caches, and each solver comes first equally often.
            units = (ours, mink_daqp, mink_osqp)
            units = units[k % 3:] + units[:k % 3]
            spent: dict[str, float] = {}
            answers: dict[str, np.ndarray | None] = {}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                for unit in units:
                    t, x = unit(tasks, target)
                    spent.update(t)
                    answers.update(x)
            ref = answers["mink.solve_ik daqp"]
            for name, t in spent.items():
                times[name].append(t)
                if name == "build (ours)":
                    continue
                x = answers[name]
                if x is None:
                    fails[name] += 1
                elif ref is not None:
                    diffs[name].append(float(np.max(np.abs(x - ref))) / DT)
    finally:
        gc.enable()
    out = {}
    for name, ts in times.items():
        d = diffs[name]
        out[name] = {"p50": float(np.percentile(ts, 50)), "p99": float(np.percentile(ts, 99)),
                     "maxdiff": max(d) if d else float("nan"),
                     "p99diff": float(np.percentile(d, 99)) if d else float("nan"),
                     "fails": fails[name], "n": len(ts), "m": m}
    return out


def _mink(ik: DifferentialIK, tasks, solver: str) -> np.ndarray | None:
    try:
        return mink.solve_ik(ik.configuration, tasks, DT, solver, damping=ik.settings.damping, limits=ik.limits) * DT
    except mink.NoSolutionFound:
        return None


def table(results: dict[str, dict[str, dict[str, float]]]) -> str:
    lines = ["| states | solver | p50 us | p99 us | diff vs exact p99 / max (rad/s) | failed |",
             "|---|---|---|---|---|---|"]
    for kind, rows in results.items():
        for name, r in rows.items():
            diff = ("-" if name == "build (ours)" or name == "mink.solve_ik daqp"
                    else f"{r['p99diff']:.1e} / {r['maxdiff']:.1e}")
            fails = "-" if name == "build (ours)" else str(r["fails"])
            lines.append(f"| {kind} ({r['n']}, {r['m']} rows) | {name} | {r['p50']:.0f} | {r['p99']:.0f} "
                         f"| {diff} | {fails} |")
    lines.append("")
    for kind, rows in results.items():
        ours = rows["build + persistent DAQP"]["p50"]
        lines.append(f"- {kind}: build + persistent DAQP is {rows['mink.solve_ik daqp']['p50'] / ours:.1f} times "
                     f"faster than mink.solve_ik daqp, {rows['mink.solve_ik osqp']['p50'] / ours:.1f} times "
                     "faster than mink.solve_ik osqp (p50)")
    return "\n".join(lines)


def write_results(text: str, command: str, section: str = SECTION.removeprefix("## ")) -> Path:
    body = ("Diff-IK QP (LR Mate 200iD, 6 variables, collisions on).\n\n"
            f"{text}\n\n"
            "Every row includes building the problem: mink's `solve_ik` builds its tasks and limits each call; "
            "ours is `DifferentialIK.qp_problem` (what the servo cycle builds), also on its own row. "
            "\"failed\": no solution accepted (infeasible states are "
            "counted for every solver). Reference for the differences: DAQP through `mink.solve_ik`.")
    return write_section(section, command, body)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--states", type=int, default=2000, help="states per kind (stream and random)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-write", action="store_true", help="print only, leave bench/RESULTS.md alone")
    ap.add_argument("--section", default=SECTION.removeprefix("## "), help="bench/RESULTS.md section to write")
    args = ap.parse_args(argv)
    results = {kind: run(kind, args.states, args.seed) for kind in ("stream", "random")}
    text = table(results)
    print(text)
    if not args.no_write:
        command = command_line(__file__, argv)
        print(f"written to {write_results(text, command, args.section)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
