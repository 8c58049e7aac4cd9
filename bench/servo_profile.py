"""Where the live servo process's CPU goes: by machine code (perf) and by Python function (bytecodes).

1. **By machine code.** ``servo-app run`` as ``bench/live_latency.py`` runs it (Cartesian jogs over REST,
   ±X 40 mm/s at 20 Hz renewals, 8 ms), with ``perf record -e cpu-clock`` attached to the servo process
   for the jog window: the share of samples by the code they fell in (the CPython interpreter, numba's
   compiled kernels, the Linux kernel, numpy, ruckig, numba's dispatch, MuJoCo, the C and C++ runtime).
   The sampling itself costs the process CPU, so its CPU share here is above live_latency's.
2. **By Python function.** ``bench/servo_loop.py``'s harness (the servo process's own loop in this
   process, asleep between statuses) with every bytecode executed within its two steps (``_io_step``,
   ``_housekeeping``) counted over ``--statuses`` statuses (the harness's controller model and pipe
   excluded): bytecodes per status and the functions that execute the most. Counts only: tracing
   makes its timings meaningless.

Needs ``perf`` (Linux) for part 1; without it part 1 says so and part 2 still runs.

    .venv/bin/python bench/servo_profile.py [--seconds 8] [--statuses 200] [--no-write]
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))
import live_latency
import servo_loop
from results import command_line, write_section

# Where a sample's code lives, by its shared object's name (perf's "dso"); first match wins.
GROUPS: tuple[tuple[str, str], ...] = (
    ("libpython", "CPython interpreter (libpython)"),
    ("[kernel", "Linux kernel (system calls, wake-ups, the network stack)"),
    ("[JIT]", "numba's compiled kernels"),
    ("_dispatcher", "numba's dispatch (typing and unboxing arguments)"),
    ("_nrt_python", "numba's dispatch (typing and unboxing arguments)"),
    ("_helperlib", "numba's dispatch (typing and unboxing arguments)"),
    ("_multiarray", "numpy"),
    ("ruckig", "ruckig"),
    ("libmujoco", "MuJoCo"),
    ("libc.", "C and C++ runtime (libc, libm, libstdc++, loader)"),
    ("libm.", "C and C++ runtime (libc, libm, libstdc++, loader)"),
    ("libstdc++", "C and C++ runtime (libc, libm, libstdc++, loader)"),
    ("ld-linux", "C and C++ runtime (libc, libm, libstdc++, loader)"),
    ("[vdso]", "C and C++ runtime (libc, libm, libstdc++, loader)"),
)
OTHER = "other extension modules (struct, socket, pickle, math, ...)"
_DSO_LINE = re.compile(r"^\s*([\d.]+)%\s+(\S.*?)\s*$")


def group_of(dso: str) -> str:
    return next((name for key, name in GROUPS if key in dso), OTHER)


def perf_shares(report: str) -> dict[str, float]:
    """``perf report --sort dso --stdio`` text -> share of samples (%) per group, largest first."""
    shares: dict[str, float] = collections.defaultdict(float)
    for line in report.splitlines():
        m = _DSO_LINE.match(line)
        if m and not line.lstrip().startswith("#"):
            shares[group_of(m.group(2))] += float(m.group(1))
    return dict(sorted(shares.items(), key=lambda kv: -kv[1]))


def by_machine_code(seconds: float) -> tuple[dict[str, float], live_latency.Run] | str:
    """Part 1: the shares, and the run they came from; or why there are none."""
    perf = shutil.which("perf")
    if perf is None:
        return "perf is not installed"
    with tempfile.TemporaryDirectory(prefix="servo-profile-") as tmp:
        data = Path(tmp) / "perf.data"

        @contextlib.contextmanager
        def sampled(pid: int) -> Iterator[None]:
            rec = subprocess.Popen([perf, "record", "-q", "-e", "cpu-clock", "-F", "10000", "-p", str(pid),
                                    "-o", str(data)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            try:
                yield
            finally:
                rec.send_signal(signal.SIGINT)  # perf's own clean stop: it writes the file and exits
                _, err = rec.communicate(timeout=60)
                if rec.returncode not in (0, -signal.SIGINT):
                    raise RuntimeError(f"perf record failed ({rec.returncode}): {err.decode()[-400:]}")

        run = live_latency.one_interval(8, seconds, None, watch=sampled)
        report = subprocess.run([perf, "report", "-i", str(data), "--sort", "dso", "--stdio", "--no-children",
                                 "-g", "none"], capture_output=True, text=True, check=False)
    if report.returncode != 0 or not (shares := perf_shares(report.stdout)):
        return f"perf report gave nothing ({report.stderr.strip()[-300:]})"
    return shares, run


def by_python_function(statuses: int) -> tuple[float, list[tuple[str, float]]]:
    """Part 2: bytecodes per status on the servo side, and (function, bytecodes per status), most first."""
    counts: collections.Counter[str] = collections.Counter()
    n = 0

    def servo_side(frame: FrameType) -> bool:  # within the loop's two steps, not the harness around them
        f: FrameType | None = frame
        while f is not None:
            code = f.f_code
            if "/sim/" in code.co_filename or code.co_filename.endswith("servo_loop.py"):
                return False
            if code.co_name in ("_io_step", "_housekeeping") and "/servo_app/" in code.co_filename:
                return True
            f = f.f_back
        return False

    def trace(frame: FrameType, event: str, arg: Any) -> Any:
        if not servo_side(frame):
            return None
        frame.f_trace_opcodes, frame.f_trace_lines = True, False
        if event == "opcode":
            code = frame.f_code
            counts[f"{Path(code.co_filename).name}:{code.co_qualname}"] += 1
        return trace

    def before_status() -> None:  # the last ``statuses`` of the run, its warm-up left out
        nonlocal n
        n += 1
        if n == 1 + servo_loop.WARM_STATUSES:
            sys.settrace(trace)

    try:
        servo_loop.run(statuses, 8, before_status=before_status)
    finally:
        sys.settrace(None)
    total = sum(counts.values()) / statuses
    return total, [(name, c / statuses) for name, c in counts.most_common()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=8.0, help="jogging time of the sampled live run")
    ap.add_argument("--statuses", type=int, default=200, help="statuses whose bytecodes are counted")
    ap.add_argument("--top", type=int, default=20, help="functions listed")
    ap.add_argument("--no-write", action="store_true", help="print only, leave bench/RESULTS.md alone")
    args = ap.parse_args(argv)

    part1 = by_machine_code(args.seconds)
    if isinstance(part1, str):
        text1 = f"By machine code: not measured ({part1})."
    else:
        shares, run = part1
        rows = "\n".join(f"| {name} | {share:.1f} |" for name, share in shares.items())
        text1 = (f"By machine code (live, 8 ms, jogging {args.seconds:g} s; servo CPU {run.cpu_pct:.1f} % with the "
                 f"sampler attached, status -> command p50 {run.p50_us:.0f} us):\n\n"
                 f"| where the servo process's samples fell | share % |\n|---|---|\n{rows}")
    total, funcs = by_python_function(args.statuses)
    top = funcs[: args.top]
    rows = "\n".join(f"| `{name}` | {c:.0f} |" for name, c in top)
    rest = total - sum(c for _, c in top)
    text2 = (f"By Python function (servo_loop's harness, {args.statuses} statuses while jogging): "
             f"{total:.0f} bytecodes per status in {len(funcs)} functions.\n\n"
             f"| function | bytecodes per status |\n|---|---|\n{rows}\n| the other {len(funcs) - len(top)} | "
             f"{rest:.0f} |")
    text = f"{text1}\n\n{text2}"
    print(text)
    if not args.no_write:
        print(f"written to {write_section('servo_profile', command_line(__file__, argv), text)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
