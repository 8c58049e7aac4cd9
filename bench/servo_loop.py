"""The FANUC servo process's own work per status packet, in one process: a steadier figure than the live run.

``bench/live_latency.py`` is the figure users get, but on these shared machines its CPU share swings by
a third from one minute to the next (the host evicts caches over the 8 ms between packets; the same
cycle costs 124 us in a tight loop and 300 us with 8 ms between). This runs the servo process's loop
itself (``_ServoProcess._io_step`` + ``_housekeeping``: decode, safety, IK ahead and on the status,
shaper, guards, send, session log, publish) against the simulator's controller model over real
loopback UDP, one status every ``--interval-ms`` with the process asleep in between as it is live, and
Cartesian jogs (+-X 40 mm/s, renewed at 20 Hz, flipped every second) as in live_latency, each renewal
a request on the process's pipe as the API sends it (its reply read back untimed, as the API's reader
thread does), and, once
warm, scheduled as the live process is (SCHED_FIFO 20, CPU wake-up latency held at 0 us). No API
process and no simulator process share the cores, so two trees compared alternately (``bench/ab.py``)
differ by their code more than by the moment.

Reports per status: the whole loop iteration (p50, p99, mean: the servo process's CPU per status
while jogging) and the part beside the motion step and the IK solved ahead (``beside``), in us.

    .venv/bin/python bench/servo_loop.py [--statuses 1000] [--interval-ms 8] [--no-write]
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import multiprocessing as mp
import os
import select
import socket
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from servo_app import messages as msg
from servo_app.fanuc.runner import StreamConfig, _ServoProcess
from servo_app.ipc import LatestValueSlot
from servo_app.realtime import WakeLatencyHold, make_realtime
from servo_app.sim.fanuc_model import ControllerConfig, FanucControllerModel
from servo_app.state import STATE_SIZE

sys.path.insert(0, str(Path(__file__).parent))
from results import command_line, write_section

WARM_STATUSES = 300  # the stream starts, the jog gets going, lazy set-up is paid
JOG_EVERY_S = 0.05  # 20 Hz renewals, as live_latency
FLIP_S = 1.0
HEADER = "| interval ms | statuses | per status p50 us | p99 us | mean us | beside motion p50 us |"


def run(statuses: int, interval_ms: int, prepare: Callable[[_ServoProcess], None] | None = None,
        before_status: Callable[[], None] | None = None) -> dict[str, float]:
    """The figures of ``statuses`` timed statuses; ``prepare`` is given the servo process's object before
    its warm-up, ``before_status`` runs before each status, untimed (bench/cold_map.py's hooks)."""
    dt = interval_ms / 1000
    controller_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    controller_sock.bind(("127.0.0.1", 0))
    controller_sock.setblocking(False)
    slot = LatestValueSlot(STATE_SIZE)
    parent_end, child_end = mp.Pipe()
    with tempfile.TemporaryDirectory() as log_dir:
        proc = _ServoProcess(StreamConfig(port=controller_sock.getsockname()[1], interval_ms=interval_ms,
                                          log_dir=log_dir, realtime_priority=None, wake_latency_us=None),
                             child_end, slot.name)
        if prepare is not None:
            prepare(proc)
        try:
            return _measure(proc, controller_sock, parent_end, statuses, dt, before_status)
        finally:
            gc.unfreeze()  # (frozen objects outlive the interpreter's teardown: ruckig's would be "leaked")
            proc.cycle.late_command = None
            proc._close_log()
            proc.sock.close()
            controller_sock.close()
            parent_end.close()
            slot.close()


@contextlib.contextmanager
def scheduled_as_live() -> Iterator[WakeLatencyHold]:
    """This process scheduled as the live servo process is once warm (``_ServoProcess.run`` with
    StreamConfig's defaults: SCHED_FIFO 20, the CPU wake-up latency held at 0 us) until the block ends,
    then back to SCHED_OTHER with the hold released. Without them a status cost up to a third more here."""
    cfg = StreamConfig()
    make_realtime(cfg.realtime_priority)
    hold = WakeLatencyHold(cfg.wake_latency_us)
    try:
        yield hold
    finally:
        hold.close()
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def _measure(proc: _ServoProcess, controller_sock: socket.socket, parent_end: Connection, statuses: int, dt: float,
             before_status: Callable[[], None] | None = None) -> dict[str, float]:
    proc._warm_up()  # as run() does before serving
    proc.wake = WakeLatencyHold(None)
    ctrl = FanucControllerModel(proc.profile, ControllerConfig(interval_ms=round(dt * 1000)),
                                initial_joints=[0, 0, 0, 0, -90, 0], log=lambda line: None)
    addr = proc.sock.getsockname()

    def answer(now: float) -> None:  # the controller model's replies to whatever the servo loop sent
        while True:
            try:
                data = controller_sock.recv(1024)
            except BlockingIOError:
                return
            for reply in ctrl.on_datagram(data, now, addr):
                controller_sock.sendto(reply, addr)

    proc._open_stream_log()
    proc.sup.request(msg.Start(), time.monotonic())
    for datagram in proc.sup._take():
        ctrl.on_datagram(datagram, time.monotonic(), addr)
    gc.collect()
    gc.freeze()
    per_status, beside = [], []
    t_ctrl = time.monotonic()
    renew_every, flip_every = round(JOG_EVERY_S / dt), round(FLIP_S / dt)
    with contextlib.ExitStack() as live:
        for i in range(WARM_STATUSES + statuses):
            if i == WARM_STATUSES:
                proc.wake.close()
                proc.wake = live.enter_context(scheduled_as_live())
            t_ctrl += dt
            raw = ctrl.tick(t_ctrl)
            if raw is not None:
                controller_sock.sendto(raw, addr)
            if i % renew_every == 0 and proc.sup.state.mode.value == "streaming":
                # The direction by the time elapsed, as live_latency's: +X the first second, then flipping.
                # (Flipped only at renewals that were also a multiple of flip_every, it had flipped every
                # 6 s: a one-way jog far enough to slow for the elbow's singularity.)
                sign = 1.0 if (i // flip_every) % 2 == 0 else -1.0
                parent_end.send(msg.Envelope(i, msg.Twist(linear=(40.0 * sign, 0.0, 0.0))))
            n_solve, n_ahead = proc.solve_time.count, proc.ahead_time.count
            if before_status is not None:
                before_status()
            t0 = time.perf_counter()
            proc._io_step()
            proc._housekeeping()
            spent = (time.perf_counter() - t0) * 1e6
            solve = proc.solve_time.ring[n_solve % 256] if proc.solve_time.count > n_solve else 0.0
            ahead = proc.ahead_time.ring[n_ahead % 256] if proc.ahead_time.count > n_ahead else 0.0
            answer(t_ctrl)
            while parent_end.poll(0):  # the replies and events, as the API's reader thread takes them
                reply = parent_end.recv()
                if isinstance(reply, msg.Reply) and not reply.ok:
                    raise RuntimeError(f"a jog was refused: {reply.error}")
            while select.select([proc.sock], [], [], 0.0)[0]:  # the stream's start-up exchanges, untimed
                proc._io_step()
                proc._housekeeping()
                answer(t_ctrl)
            if i >= WARM_STATUSES and raw is not None:
                per_status.append(spent)
                beside.append(spent - solve - ahead)
            time.sleep(dt)  # asleep between packets, as the live process is
    if proc.sup.state.mode.value != "streaming":
        raise RuntimeError(f"the stream did not hold: {proc.sup.describe()}")
    return {"n": len(per_status), "p50": float(np.median(per_status)), "p99": float(np.percentile(per_status, 99)),
            "mean": float(np.mean(per_status)), "beside": float(np.median(beside))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--statuses", type=int, default=1000, help="timed status packets per interval")
    ap.add_argument("--interval-ms", type=int, action="append", choices=(4, 8),
                    help="8 and/or 4 (repeatable; default: 8 then 4)")
    ap.add_argument("--no-write", action="store_true", help="print only, leave bench/RESULTS.md alone")
    args = ap.parse_args(argv)
    lines = [HEADER, "|---|---|---|---|---|---|"]
    for interval_ms in args.interval_ms or [8, 4]:
        r = run(args.statuses, interval_ms)
        lines.append(f"| {interval_ms} | {r['n']:.0f} | {r['p50']:.0f} | {r['p99']:.0f} | {r['mean']:.0f} "
                     f"| {r['beside']:.0f} |")
    text = "\n".join(lines)
    print(text)
    print("servo loop: per status while jogging, asleep between statuses")
    if not args.no_write:
        command = command_line(__file__, argv)
        print(f"written to {write_section('servo_loop', command, text)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
