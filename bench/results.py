"""Write one benchmark's section of bench/RESULTS.md, keeping the other sections."""

from __future__ import annotations

import platform
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"


def command_line(script: str, argv: Sequence[str] | None = None) -> str:
    """The command that reproduces a run, as a section quotes it: ``.venv/bin/python bench/NAME.py ARGS``
    (``script``: the benchmark's ``__file__``; ``argv``: its arguments, by default this process's)."""
    args = sys.argv[1:] if argv is None else argv
    return " ".join([".venv/bin/python", f"bench/{Path(script).name}", *map(shlex.quote, args)])


def write_section(name: str, command: str, text: str) -> Path:
    header = f"## {name}"
    body = (f"{header}\n\n{time.strftime('%Y-%m-%d')}, {platform.python_implementation()} "
            f"{platform.python_version()} on {platform.machine()}, 2 shared cores (tails include other load).\n\n"
            f"Command: `{command}`\n\n{text}\n")
    old = RESULTS.read_text() if RESULTS.exists() else "# Benchmark results\n"
    start = old.find(header + "\n")
    if start < 0:
        new = old.rstrip("\n") + "\n\n" + body
    else:
        nxt = old.find("\n## ", start + len(header))
        new = old[:start] + body + ("\n" + old[nxt + 1:] if nxt >= 0 else "")
    RESULTS.write_text(new)
    return RESULTS
