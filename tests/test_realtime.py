"""Real-time scheduling helpers: best effort, and saying what they got."""

from __future__ import annotations

import os
import threading

from servo_app.realtime import BLAS_THREAD_VARS, WakeLatencyHold, make_realtime, single_threaded_blas

RESET_ON_FORK = getattr(os, "SCHED_RESET_ON_FORK", 0)


def test_a_realtime_thread_starts_its_own_threads_at_normal_priority() -> None:
    seen: dict[str, object] = {}

    def child() -> None:
        seen["child"] = os.sched_getscheduler(0)

    def parent() -> None:
        seen["status"] = make_realtime(3)
        seen["parent"] = os.sched_getscheduler(0)
        t = threading.Thread(target=child)
        t.start()
        t.join()

    t = threading.Thread(target=parent)
    t.start()
    t.join()
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # only the thread that asked
    if seen["status"] == "SCHED_FIFO 3":
        assert seen["parent"] == os.SCHED_FIFO | RESET_ON_FORK
    else:
        assert str(seen["status"]).startswith("unavailable")
    assert seen["child"] == os.SCHED_OTHER  # a worker it starts competes like any other thread
    assert make_realtime(None) == "not requested"
    assert make_realtime(0) == "normal priority" and os.sched_getscheduler(0) == os.SCHED_OTHER


def test_wake_latency_hold_says_what_it_got_and_releases_on_close() -> None:
    hold = WakeLatencyHold(0)
    try:
        assert hold.status == "cpu wake-up latency held at 0 us" or hold.status.startswith("unavailable")
    finally:
        hold.close()
        hold.close()  # idempotent
    assert WakeLatencyHold(None).status == "not requested"


def test_single_threaded_blas_only_while_starting_a_process() -> None:
    before = {k: os.environ.get(k) for k in BLAS_THREAD_VARS}
    with single_threaded_blas():
        assert all(os.environ[k] == "1" for k in BLAS_THREAD_VARS)
    assert {k: os.environ.get(k) for k in BLAS_THREAD_VARS} == before
