"""Real-time scheduling, best effort: SCHED_FIFO lets a cycle run ahead of ordinary load on the machine."""

from __future__ import annotations

import os


def make_realtime(priority: int | None, pid: int | None = None) -> str:
    """SCHED_FIFO at ``priority`` for every thread of process ``pid`` (None: the calling thread).

    Returns what was achieved, for the logs and the state: without the privilege (or off Linux) the
    process stays at normal priority and says so.
    """
    if priority is None:
        return "not requested"
    try:
        tids = [0] if pid is None else [int(t) for t in os.listdir(f"/proc/{pid}/task")]
        for tid in tids:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:  # PermissionError is an OSError
        return f"unavailable ({exc}); running at normal priority"
    return f"SCHED_FIFO {priority}"
