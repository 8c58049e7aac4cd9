"""What the FANUC servo process's per-cycle state publish costs, in process.

A real servo process object (``_ServoProcess``: its supervisor, servo cycle, state vector and
shared-memory slot) streams against the controller model on a simulated clock while joint jogs keep
it moving, then ``_publish`` (what the process runs after every status packet) is timed ``--calls``
times in two cases: a fresh stream, and a full latency window (4096 commands: after 16 s at 4 ms,
33 s at 8 ms), one more command per call as while streaming.

Prints a table; ``--write`` writes its section of bench/RESULTS.md. Works under ``bench/ab.py``.

    .venv/bin/python bench/publish.py --write
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from pathlib import Path

import numpy as np

from servo_app.fanuc.packets import StatusStart
from servo_app.fanuc.runner import StreamConfig, _ServoProcess
from servo_app.ipc import LatestValueSlot
from servo_app.messages import Jog, Start
from servo_app.sim.fanuc_model import ControllerConfig, FanucControllerModel
from servo_app.state import STATE_SIZE

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section

HEADER = "| run | interval ms | calls | p50 us | mean us | p99 us | max us |"
CLIENT = ("127.0.0.1", 50000)


def streaming_process(interval_ms: int) -> tuple[_ServoProcess, LatestValueSlot]:
    """A servo process object, streaming and jogging, its sockets unused."""
    slot = LatestValueSlot(STATE_SIZE)
    _, child = mp.Pipe()
    proc = _ServoProcess(StreamConfig(interval_ms=interval_ms), child, slot.name)
    proc._warm_up()
    ctrl = FanucControllerModel(proc.profile, ControllerConfig(interval_ms=interval_ms),
                                initial_joints=[0, 0, 0, 0, -90, 0], log=lambda line: None)
    t, dt = 0.0, interval_ms / 1000
    ctrl.on_datagram(StatusStart().encode(), t, CLIENT)
    proc.sup.request(Start(), t)
    for d in proc.sup._take():
        ctrl.on_datagram(d, t, CLIENT)
    for i in range(400):
        t += dt
        raw = ctrl.tick(t)
        if raw is None:
            continue
        out = proc.sup.on_datagram(raw, t)
        proc.sup.session.begin_motion()
        for d in out:
            for reply in ctrl.on_datagram(d, t, CLIENT):
                proc.sup.on_datagram(reply, t)
        record(proc)
        if i % 10 == 0 and proc.sup.state.mode.value == "streaming":
            proc.sup.request(Jog(joints=(5.0, 0, 0, 0, 0, 0), hold_s=0.2), t)
    if proc.sup.state.mode.value != "streaming":
        raise RuntimeError(f"not streaming: {proc.sup.describe()}")
    return proc, slot


def record(proc: _ServoProcess) -> None:
    """What _after_datagram keeps for publishing (no session log here)."""
    for sent in proc.sup.session.sent:
        if hasattr(proc.hist, "add"):
            proc.hist.add(sent.command.values)
        else:  # before the preallocated history
            proc.hist.append(np.array(sent.command.values[:6]))
        proc.latency.add(300.0, proc.late_us)
    proc.sup.session.sent = []


def time_publish(proc: _ServoProcess, calls: int, full: bool) -> np.ndarray:
    if full:
        for _ in range(4096):
            proc.latency.add(300.0, proc.late_us)
    ts = np.empty(calls)
    for k in range(calls):
        t0 = time.perf_counter()
        proc._publish()
        ts[k] = time.perf_counter() - t0
        proc.latency.add(300.0, proc.late_us)  # one command per cycle
    return ts * 1e6


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--calls", type=int, default=3000)
    p.add_argument("--interval-ms", type=int, choices=(4, 8), default=4)
    p.add_argument("--write", action="store_true", help="write this benchmark's section of bench/RESULTS.md")
    p.add_argument("--no-write", action="store_true", help="never write bench/RESULTS.md (bench/ab.py adds it)")
    args = p.parse_args(argv)
    rows = []
    for name, full in (("fresh stream", False), ("full latency window (4096)", True)):
        proc, slot = streaming_process(args.interval_ms)
        try:
            us = time_publish(proc, args.calls, full)
        finally:
            proc.sock.close()
            proc.cycle.late_command = None
            slot.close()
        rows.append(f"| {name} | {args.interval_ms} | {args.calls} | {np.percentile(us, 50):.1f} | {us.mean():.1f} "
                    f"| {np.percentile(us, 99):.1f} | {us.max():.0f} |")
    print(HEADER)
    print("\n".join(rows))
    print(f"_publish of a streaming FANUC servo process, {args.calls} calls per case, in process")
    if args.write and not args.no_write:
        cmd = command_line(__file__, argv)
        text = ("The FANUC servo process's per-cycle publish (`_publish`: the state vector into its shared-memory "
                "slot), in process, on a streaming and jogging servo process object (controller model on a "
                f"simulated clock).\n\n{HEADER}\n|---|---|---|---|---|---|---|\n" + "\n".join(rows))
        print("wrote", write_section("publish", cmd, text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
