"""Before and after on the same machine, in one run: a benchmark script at a base revision and here.

The machines this runs on are shared and differ by about three times from one to the next, so a
figure from another day says little. This checks the base revision out into a temporary git worktree,
then runs the same benchmark command alternately in both trees (base first, ``--rounds`` times each),
with each tree's own code on the path. It prints the table rows each run printed (lines starting
with ``| `` and a digit or letter after the header) plus the run's last line, and writes its section of
bench/RESULTS.md.

    .venv/bin/python bench/ab.py --base 82c2b26 --rounds 3 -- bench/stream_latency.py --seconds 8 --interval-ms 4
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section

ROOT = Path(__file__).resolve().parents[1]


def run_in(tree: Path, command: list[str], timeout: float) -> tuple[list[str], str]:
    """The table rows the benchmark printed, and its last line (its verdict), run inside ``tree``.

    A benchmark the base revision does not have yet runs from this tree, on the base's code (its
    ``servo_app`` comes from ``PYTHONPATH``): a new benchmark measures the code before its change too."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    script = Path(command[0])
    if not script.is_absolute() and not (tree / script).exists() and (ROOT / script).exists():
        command = [str(ROOT / script), *command[1:]]
    r = subprocess.run([sys.executable, *command], cwd=tree, env=env, capture_output=True, text=True,
                       timeout=timeout)
    lines = [line for line in r.stdout.splitlines() if line.strip()]
    last = lines[-1] if lines else f"(no output; exit {r.returncode}: {r.stderr.strip()[-300:]})"
    return table_rows(lines), last


def table_rows(lines: list[str]) -> list[str]:
    """The data rows of the tables in ``lines``: not a header (the line above a ``|---`` separator, or
    one starting ``| run`` where a table has none), not a separator."""
    return [line for i, line in enumerate(lines)
            if line.startswith("| ") and not line.startswith("| run")
            and not (i + 1 < len(lines) and lines[i + 1].startswith("|-"))]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--base", required=True, help="the revision to compare with (a commit, tag or branch)")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--timeout", type=float, default=600.0, help="per run, seconds")
    p.add_argument("--name", default=None, help="RESULTS.md section (default: ab <script name>)")
    p.add_argument("--no-write", action="store_true")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- SCRIPT [ARGS]: the benchmark, as run from the root")
    args = p.parse_args(argv)
    command = [a for a in args.command if a != "--"]
    if not command:
        p.error("give the benchmark command after --")
    if "--no-write" not in command:
        command.append("--no-write")  # the benchmark must not write its own section from either tree
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    results: list[tuple[str, int, list[str], str]] = []
    with tempfile.TemporaryDirectory(prefix="servo-ab-") as tmp:
        base_tree = Path(tmp) / "base"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(base_tree), args.base], cwd=ROOT, check=True)
        try:
            for i in range(1, args.rounds + 1):
                for label, tree in ((f"before ({args.base})", base_tree), (f"after ({head})", ROOT)):
                    rows, last = run_in(tree, command, args.timeout)
                    results.append((label, i, rows, last))
                    print(f"{label} round {i}:", *rows, last, sep="\n  ", flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base_tree)], cwd=ROOT, check=False)
    table = "\n".join(f"| {label} | {i} | {row.removeprefix('| ')}" for label, i, rows, _ in results for row in rows)
    notes = "\n".join(f"- {label}, round {i}: {last}" for label, i, _, last in results)
    text = (f"Before and after on this machine, alternating, base first: `{' '.join(command)}` in each tree.\n\n"
            f"| tree | round | (the benchmark's columns) |\n|---|---|---|\n{table}\n\n{notes}")
    if not args.no_write:
        cmd = command_line(__file__, argv)
        name = args.name or f"ab {Path(command[0]).stem}"
        print("wrote", write_section(name, cmd, text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
