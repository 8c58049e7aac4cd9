"""How much of the live servo process's CPU is the motion itself: a floor for any rework of the rest.

Each round runs two things one after the other on this machine:

- **floor**: a process that answers a status packet every ``--interval-ms`` over UDP on loopback with the
  live path's motion, and with the least anything else could cost. The motion is the same
  ``ServoCycle.next_command`` on the packet and ``solve_ahead`` after the send, with the same twist
  renewals: ±X at 40 mm/s, 20 Hz, flipping every second, handed over in process rather than over the
  pipe. Beside it there is only one decode, one pack, the send, one ``os.write`` of a log record and one
  compiled write into a state vector with its shared-memory slot write. It is scheduled as the live servo
  process is (SCHED_FIFO 20, the CPU wake-up latency held at 0 us, the gc's start-up objects frozen:
  without them it cost up to a third more here). There is no session, safety
  supervision, request handling or publishing. That is what a compiled fast path around today's motion
  could come down to, at best.
- **live**: ``bench/live_latency.py``'s run at the same interval: the service as users run it.

For both it reports the process's CPU share over the run (``/proc/PID/stat`` utime + stime) and the CPU
time per status. The floor's share of the live figure is what the motion costs; the rest is the most
a rework of everything beside the motion could save.

    .venv/bin/python bench/motion_floor.py --rounds 3 --seconds 8
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import multiprocessing as mp
import os
import socket
import struct
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))
from live_latency import FLIP_S, JOG_HZ, SPEED_MM_S, cpu_seconds, free_port, one_interval
from results import command_line, write_section

WARM_STATUSES = 100  # answered at normal priority first: the first solves fill caches (the live process warms up so)


def _floor_servo(port: int, interval_ms: int, ready: Any) -> None:  # (ready: an mp Event)
    import numba
    import numpy as np
    from servo_loop import scheduled_as_live

    from servo_app.fanuc.packets import decode_from_robot, pack_command
    from servo_app.ipc import LatestValueSlot
    from servo_app.motion.commands import Twist
    from servo_app.motion.servo import ServoCycle, ServoSettings
    from servo_app.robots.profile import load_profile
    from servo_app.state import STATE_SIZE

    @numba.njit(cache=False)
    def into_state(d: np.ndarray, joints: np.ndarray, lat_us: float) -> None:  # (a dozen stores, as the live one)
        for i in range(6):
            d[10 + i] = joints[i]
            d[20 + i] = joints[i]
        d[30] = lat_us
        d[31] += 1.0

    dt = interval_ms / 1000
    cycle = ServoCycle(load_profile("lrmate200id"), dt, ServoSettings())
    cycle.begin(np.array([0.0, 0.0, 0.0, 0.0, -90.0, 0.0]), None)
    slot = LatestValueSlot(STATE_SIZE)
    state = np.zeros(STATE_SIZE)
    into_state(state, np.zeros(6), 0.0)
    record = struct.Struct("<dIId6fdIId6f")  # a status and its command, as the session log's pair
    with tempfile.TemporaryDirectory(prefix="motion-floor-") as tmp, contextlib.ExitStack() as live:
        log = os.open(Path(tmp) / "floor.log", os.O_WRONLY | os.O_CREAT)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", port))
        ready.set()
        renew_every, flip_every = round(1 / (JOG_HZ * dt)), round(FLIP_S / dt)
        n = 0
        while True:
            data, addr = sock.recvfrom(1024)
            if data == b"q":
                break
            t_recv = time.monotonic()
            if n % renew_every == 0:
                sign = 1.0 if (n // flip_every) % 2 == 0 else -1.0  # by the time elapsed, as live_latency's
                cycle.twist(Twist(source="bench", stamp=t_recv, frame="base", linear=(SPEED_MM_S * sign, 0.0, 0.0)))
            status = decode_from_robot(data)
            q = cycle.next_command(status)
            values = q.tolist()
            sock.sendto(pack_command(status.seq, values), addr)
            t_sent = time.monotonic()
            lat_us = (t_sent - t_recv) * 1e6
            os.write(log, record.pack(t_recv, status.seq, status.status, 0.0, *status.joints[:6], t_sent, status.seq,
                                      0, lat_us, *values))
            into_state(state, q, lat_us)
            slot.write(state)
            cycle.solve_ahead()
            n += 1
            if n == WARM_STATUSES:  # then scheduled as the live servo process is once warm, start-up objects
                # out of the gc's scans
                live.enter_context(scheduled_as_live())
                gc.collect()
                gc.freeze()
        os.close(log)
    slot.close()


def floor_run(interval_ms: int, seconds: float) -> tuple[float, float]:
    """The floor process's CPU share (%) and CPU time per status (us) over ``seconds`` of statuses."""
    from servo_app.fanuc.packets import Status

    port = free_port()
    ctx = mp.get_context("spawn")
    ready = ctx.Event()
    proc = ctx.Process(target=_floor_servo, args=(port, interval_ms, ready), daemon=True)
    proc.start()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.settimeout(2.0)
    try:
        if not ready.wait(120):
            raise RuntimeError("the floor process did not start")
        dt, seq = interval_ms / 1000, 0
        for measured in (False, True):  # 2 s of warm-up (the first solves compile and fill caches), then the run
            t0, cpu0, n = time.monotonic(), cpu_seconds(proc.pid), 0
            due = t0
            while time.monotonic() - t0 < (seconds if measured else 2.0):
                due += dt
                time.sleep(max(0.0, due - time.monotonic()))
                seq += 1
                joints = (0.0, 0.0, 0.0, 0.0, -90.0, 0.0, 0.0, 0.0, 0.0)
                client.sendto(Status(seq=seq, status=0b1111, joints=joints).encode(), ("127.0.0.1", port))
                client.recv(1024)
                n += 1
            elapsed, used = time.monotonic() - t0, cpu_seconds(proc.pid) - cpu0
        return 100.0 * used / elapsed, used / n * 1e6
    finally:
        client.sendto(b"q", ("127.0.0.1", port))
        proc.join(10)
        if proc.is_alive():
            proc.kill()
        client.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--seconds", type=float, default=8.0)
    p.add_argument("--interval-ms", type=int, default=8)
    p.add_argument("--name", default=None, help="RESULTS.md section (default: motion_floor at INTERVAL ms)")
    p.add_argument("--no-write", action="store_true")
    args = p.parse_args(argv)
    header = ("| round | floor CPU % | floor us per status | live CPU % | live us per status | floor / live |\n"
              "|---|---|---|---|---|---|")
    print(header, flush=True)
    rows, floors, lives = [], [], []
    for r in range(1, args.rounds + 1):
        floor_pct, floor_us = floor_run(args.interval_ms, args.seconds)
        live = one_interval(args.interval_ms, args.seconds, None)
        if live.cpu_pct is None:
            raise RuntimeError("the live run gave no CPU figure")
        live_us = live.cpu_pct / 100 * args.interval_ms * 1000
        floors.append(floor_pct)
        lives.append(live.cpu_pct)
        row = (f"| {r} | {floor_pct:.1f} | {floor_us:.0f} | {live.cpu_pct:.1f} | {live_us:.0f} | "
               f"{floor_pct / live.cpu_pct:.2f} |")
        rows.append(row)
        print(row, flush=True)
    verdict = (f"{args.interval_ms} ms: the motion alone is {sum(floors) / sum(lives):.0%} of the live servo "
               f"process's CPU over {args.rounds} rounds (from the sums)")
    print(verdict)
    if not args.no_write:
        text = f"{header}\n" + "\n".join(rows) + f"\n\n{verdict}."
        name = args.name or f"motion_floor at {args.interval_ms} ms"
        print("wrote", write_section(name, command_line(__file__, argv), text))
    return 0


if __name__ == "__main__":
    sys.exit(main())
