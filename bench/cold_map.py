"""Where a status packet's time goes in the servo process, with caches cold and warm: a map for choosing
what to make cheaper next.

Live, the servo process sleeps 8 ms between status packets while the API, the simulator and the host's
other guests run, so each status finds its code and data evicted: the IK kernel's step takes 7 us in
a tight loop and ~50 us live. This runs bench/servo_loop.py's harness (the servo process's own loop
against the controller model over loopback UDP, Cartesian jogs as live_latency's) twice: as that bench
runs it (asleep between statuses), then with 64 MB written and read before each status, which evicts
every cache level (an upper bound of the live cost). Each piece of a status is timed inclusively
around its call (a wrapper's two clock reads, ~0.1 us warm, are in every figure):

- ``status``: the whole loop iteration (``_io_step`` + ``_housekeeping``);
- ``receive, answer, log``: ``_io_step``, and in it the socket's receive (the datagram is waiting:
  the system call alone, not the wake-up of a process asleep in it), the supervisor's handling
  (``on_datagram``: the decode, the safety checks before the command, the command,
  ``StreamSession._command``, with the motion step in it, ``ServoCycle.next_command``), the socket's
  send, and the log record and state fields (``_after_datagram``);
- ``housekeeping``: ``_housekeeping``, and in it the publish and the IK solved ahead.

Prints the p50 of each, in us, and each piece's share of the status's p50.

    .venv/bin/python bench/cold_map.py [--statuses 600] [--no-write]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import servo_loop
from results import command_line, write_section

from servo_app.fanuc.runner import _ServoProcess

EVICT_BYTES = 64 << 20  # twice the largest L3 of these machines
HEADER = "| piece | warm p50 us | share | cold p50 us | share |"

# (label, path to the object from the servo process, method): inclusive timings, nested by indent.
PIECES: tuple[tuple[str, str, str], ...] = (
    ("receive, answer, log", "", "_io_step"),
    ("  socket receive", "sock", "recv"),
    ("  supervisor (on_datagram)", "sup", "on_datagram"),
    ("    decode", "sup.session", "decode"),
    ("    safety before the command", "sup", "_on_status_before"),
    ("    command", "sup.session", "_command"),
    ("      motion step (next_command)", "cycle", "next_command"),
    ("  socket send", "sock", "send"),
    ("  log record, state fields", "", "_after_datagram"),
    ("housekeeping", "", "_housekeeping"),
    ("  publish", "", "_publish"),
    ("  IK solved ahead", "cycle", "solve_ahead"),
)


def _timed(times: dict[str, list[float]], label: str, method: Callable[..., Any]) -> Callable[..., Any]:
    def timed(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            times[label].append(time.perf_counter() - t)
    return timed


class _TimedSocket:
    """The servo process's socket with recv and send timed (a socket's own methods cannot be replaced)."""

    def __init__(self, sock: Any) -> None:
        self._sock = sock
        self.recv, self.send = sock.recv, sock.send

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sock, name)


def measure(statuses: int, cold: bool) -> dict[str, float]:
    """p50 per piece (us) over ``statuses`` timed statuses, and the status's own p50 (``status``)."""
    times: dict[str, list[float]] = defaultdict(list)
    buffer = np.ones(EVICT_BYTES // 8) if cold else None

    def prepare(proc: _ServoProcess) -> None:
        proc.sock = _TimedSocket(proc.sock)  # type: ignore[assignment]
        for label, path, name in PIECES:
            owner: Any = proc
            for attr in filter(None, path.split(".")):
                owner = getattr(owner, attr)
            setattr(owner, name, _timed(times, label, getattr(owner, name)))

    def evict() -> None:
        assert buffer is not None
        buffer[::8] += 1.0  # one store per 64-byte line: every line dirty, then read back
        float(buffer.sum())

    def start_window() -> None:  # only what the timed statuses do is kept
        for v in times.values():
            v.clear()

    marks = {"n": 0}

    def before_status() -> None:
        if marks["n"] == servo_loop.WARM_STATUSES:
            start_window()
        marks["n"] += 1
        if cold:
            evict()

    r = servo_loop.run(statuses, 8, prepare=prepare, before_status=before_status)
    out = {label: float(np.median(times[label])) * 1e6 for label, _, _ in PIECES if times[label]}
    out["status"] = r["p50"]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--statuses", type=int, default=600, help="timed status packets per run")
    ap.add_argument("--no-write", action="store_true", help="print only, leave bench/RESULTS.md alone")
    args = ap.parse_args(argv)
    warm, cold = measure(args.statuses, cold=False), measure(args.statuses, cold=True)
    lines = [HEADER, "|---|---|---|---|---|", f"| status (8 ms) | {warm['status']:.0f} | 100 % | {cold['status']:.0f} "
             "| 100 % |"]
    for label, _, _ in PIECES:
        if label in warm and label in cold:
            w, c = warm[label], cold[label]
            lines.append(f"| {label.replace('  ', '· ')} | {w:.0f} | {100 * w / warm['status']:.0f} % | {c:.0f} "
                         f"| {100 * c / cold['status']:.0f} % |")
    text = "\n".join(lines)
    print(text)
    print("cold map: p50 of each piece, inclusive; cold = 64 MB written and read before each status")
    if not args.no_write:
        print(f"written to {write_section('cold_map', command_line(__file__, argv), text)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
