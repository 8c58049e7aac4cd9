"""Real-time scheduling, best effort: SCHED_FIFO lets a cycle run ahead of ordinary load on the machine."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator
from typing import NoReturn


def make_realtime(priority: int | None, pid: int | None = None) -> str:
    """SCHED_FIFO at ``priority`` for every thread of process ``pid`` (None: the calling thread);
    ``priority`` None leaves the scheduling as it is, 0 keeps normal priority (as the options say).

    Threads and processes started later by such a thread begin at normal priority
    (``SCHED_RESET_ON_FORK``): a worker pool or a restarted servo process must ask for itself (the
    servo process warms up at normal priority first, so as not to starve its core).

    Returns what was achieved, for the logs and the state: without the privilege (or off Linux) the
    process stays at normal priority and says so.
    """
    if priority is None:
        return "not requested"
    if priority == 0:
        return "normal priority"
    try:
        policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
        tids = [0] if pid is None else [int(t) for t in os.listdir(f"/proc/{pid}/task")]
        for tid in tids:
            os.sched_setscheduler(tid, policy, os.sched_param(priority))
    except (OSError, AttributeError) as exc:  # PermissionError is an OSError
        return f"unavailable ({exc}); running at normal priority"
    return f"SCHED_FIFO {priority}"


class WakeLatencyHold:
    """Keeps the CPUs out of idle states slower to leave than ``max_us`` for as long as it is open
    (Linux PM QoS, ``/dev/cpu_dma_latency``; 0: only polling idle), as real-time control loops do.

    The servo cycle sleeps in ``recv`` for most of each interval. Woken from a deep idle state (on a
    virtual machine: a halted vCPU the host has descheduled), its first microseconds run slowly
    with cold caches: measured here, a cycle's compute after 7.5 ms asleep took about twice as long
    without the hold as with it. Best effort: without the privilege, ``status`` says so.
    """

    PATH = "/dev/cpu_dma_latency"

    def __init__(self, max_us: int | None) -> None:
        self._fd: int | None = None
        if max_us is None:
            self.status = "not requested"
            return
        try:
            self._fd = os.open(self.PATH, os.O_WRONLY)
            os.write(self._fd, int(max_us).to_bytes(4, sys.byteorder, signed=True))
        except OSError as exc:
            self.close()
            self.status = f"unavailable ({exc})"
        else:
            self.status = f"cpu wake-up latency held at {max_us} us"

    def close(self) -> None:
        """Release the hold (closing the file is what ends it)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Around starting a (spawned) real-time process: its numpy then does linear algebra in the
    calling thread. OpenBLAS otherwise starts worker threads at normal priority, and a cycle at
    SCHED_FIFO that hands a 6x6 SVD to one waits for it to be scheduled."""
    saved = {k: os.environ.get(k) for k in BLAS_THREAD_VARS}
    os.environ.update({k: "1" for k in BLAS_THREAD_VARS})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def exit_done_child(code: int = 0) -> NoReturn:
    """End a child process (the servo process, the embedded simulator) whose work is done, closed
    and flushed, without the interpreter's teardown: freeing numba's compiled kernels and every module
    took 0.3-0.9 s of CPU here, which the parent's shutdown, a reset's replacement, waited for."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)
