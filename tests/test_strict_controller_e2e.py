"""Streams start at 4 ms against a strict controller, again and again, without an alarm.

A strict controller (issue 15) takes a stream's first command only as the answer to the latest status:
one that leaves after the next status (4 ms later) is MOTN-600. Real processes on loopback: the
simulator in a process of its own (its tick thread must not share a GIL with this test), the servo
process as the service starts it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from servo_app.fanuc.packets import StatusBit
from servo_app.fanuc.runner import StreamConfig, StreamProcess
from servo_app.messages import End, Start
from servo_app.session_log import read_session_log
from servo_app.sim.fanuc_model import ControllerConfig
from servo_app.sim.process import SimulatorProcess

pytestmark = pytest.mark.e2e

HOME = [0.0, 0.0, 0.0, 0.0, -90.0, 0.0]
STARTS = 6
INTERVAL_MS = 4


def wait_state(sp: StreamProcess, pred: object, what: str, timeout: float = 10.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        s = sp.state()
        if pred(s):  # type: ignore[operator]
            return s
        time.sleep(0.005)
    raise AssertionError(f"{what} not reached; state {sp.state()}; events {sp.events[-4:]}")


@pytest.fixture
def strict_rig(tmp_path: Path) -> Iterator[tuple[SimulatorProcess, StreamProcess]]:
    sim = SimulatorProcess(port=0, interval_ms=INTERVAL_MS, initial_joints=HOME,
                           config=ControllerConfig(strict_first_seq=True)).start()
    host, port = sim.address
    sp = StreamProcess(StreamConfig(host=host, port=port, interval_ms=INTERVAL_MS, log_dir=str(tmp_path), lead=2))
    try:
        sp.start()
        yield sim, sp
    finally:
        sp.shutdown()
        sim.stop()


def test_streams_start_at_4ms_against_a_strict_controller_every_time(
        strict_rig: tuple[SimulatorProcess, StreamProcess], tmp_path: Path) -> None:
    sim, sp = strict_rig
    for k in range(STARTS):
        sp.request(Start(), timeout=10.0)  # answered once the stream runs (or refused with the reason)
        wait_state(sp, lambda s: s["state"] == "streaming" and s["commands_sent"] > 10, f"start {k} streaming")
        assert sim.events() == [], f"start {k}: {sim.events()}"
        sp.request(End())
        wait_state(sp, lambda s: s["state"] == "ended", f"start {k} ended")
    assert sim.events() == []
    # Every stream's first command answered the very status it was made for: the ready one, the latest.
    logs = sorted(tmp_path.glob("*.srvlog"))
    assert len(logs) == STARTS
    for path in logs:
        log = read_session_log(path)
        first, sts = log.commands[0], log.statuses
        answered = sts[(sts["seq"] == first["seq"]) & (sts["t"] <= first["t"])]
        assert answered.size == 1 and answered[0]["flags"] & (StatusBit.WAITING_FOR_COMMAND
                                                              | StatusBit.COMMAND_RECEIVED) \
            == StatusBit.WAITING_FOR_COMMAND
        # ... and left well inside the interval the strict controller allows it (the log's own times).
        assert (first["t"] - answered[0]["t"]) * 1000 < INTERVAL_MS / 2
