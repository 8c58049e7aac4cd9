"""A third robot backend plugged in from outside servo_app (tests/toy_backend.py), end to end.

The real service and a real uvicorn, the generic supervisor and servo-process host, a spawned toy servo
process and a spawned toy controller, UDP on loopback: nothing in servo_app knows the toy.
"""

from __future__ import annotations

import importlib.util
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_api_harness import AUTH, Rig, assert_came_to_rest, assert_log_complete, running_rig

from servo_app import backends
from servo_app.backends import register_backend

pytestmark = pytest.mark.e2e

HERE = Path(__file__).resolve().parent
JOG_X = [60.0, 0.0]  # mm/s


@pytest.fixture
def toy_registered() -> Iterator[None]:
    """Register the toy for one test, and leave the registry as the core has it."""
    assert "toy" not in backends.BACKENDS  # only this test adds it
    register_backend("toy", "toy_backend:ToyBackend")
    try:
        yield
    finally:
        del backends.BACKENDS["toy"]


def wait_for(pred: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while not (value := pred()):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.005)
    return value


def jog_moves(rig: Rig, h: dict[str, str], seconds: float = 0.4) -> None:
    x0 = rig.state()["q_cmd"][0]
    assert rig.jog_for(h, JOG_X, seconds) > 0
    s = rig.wait(lambda s: s["q_cmd"][0] - x0 > 5.0, timeout=2.0, what="the jog to move X")
    assert s["state"] == "streaming" and s["fault"] is None, s


def rests(rig: Rig) -> dict[str, Any]:
    """Stopped, and stays put while statuses keep coming (waited for by status count, not by time)."""
    s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], what="stopped at rest")
    later = rig.wait(lambda t: t["status_received"] >= s["status_received"] + 10, what="ten more statuses")
    assert later["q_cmd"] == s["q_cmd"] and later["state"] == "stopped", (s, later)
    return later


def no_children_left() -> None:
    wait_for(lambda: not mp.active_children(), 5.0, f"the service's processes to exit: {mp.active_children()}")


def test_the_core_registry_knows_only_fanuc_and_janome() -> None:
    assert "toy" not in backends.BACKENDS
    out = subprocess.run([sys.executable, "-c", "from servo_app.backends import BACKENDS; print(sorted(BACKENDS))"],
                         capture_output=True, text=True, check=True, cwd=HERE.parent)
    assert out.stdout.strip() == "['fanuc', 'janome']"
    # Spawned children get this sys.path (multiprocessing passes it): toy_backend is importable there too.
    spec = importlib.util.find_spec("toy_backend")
    assert spec is not None and Path(str(spec.origin)).resolve() == HERE / "toy_backend.py"
    assert str(HERE) in sys.path


def test_toy_streams_stops_resumes_and_ends(toy_registered: None, tmp_path: Path) -> None:
    with running_rig(tmp_path, robot="toy") as rig:
        assert rig.http.get("/api/robot").json()["backend"] == "toy"
        assert rig.http.get("/api/limits").json()["axes"] == ["X", "Y"]
        h = rig.lease()
        rig.post("/api/session/start", h)  # answered once streaming, not before
        s = rig.state()
        assert (s["state"], s["link"], s["backend"], s["model"]) == ("streaming", "streaming", "toy", "toy1"), s

        jog_moves(rig, h)
        rig.post("/api/session/stop", AUTH)  # soft: ramps down and holds
        stopped = rests(rig)
        assert stopped["stop_reason"] == "stop requested" and stopped["resumable"]

        rig.post("/api/session/resume", h)
        assert rig.state()["state"] == "streaming"
        jog_moves(rig, h)

        rig.end_and_wait(h)
        log = rig.latest_log()
    assert log.header["protocol"] == "toy-udp-v1"
    assert_log_complete(log, ended=True)  # consecutive command numbers, last data last
    assert_came_to_rest(log, interval_s=0.008)
    assert np.all(log.statuses["seq"][1:] > log.statuses["seq"][:-1])
    # The first command holds where the status it answers says the table is.
    recs = log.records
    first = int(np.flatnonzero(recs["kind"] == 1)[0])
    assert recs["kind"][first - 1] == 0 and np.array_equal(recs["values"][first], recs["values"][first - 1])
    no_children_left()


def test_killed_toy_servo_process_is_a_fault_and_reset_recovers(toy_registered: None, tmp_path: Path) -> None:
    with running_rig(tmp_path, robot="toy") as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG_X, 0.2)
        assert rig.state()["state"] == "streaming"
        pid = rig.service.stream.pid  # type: ignore[union-attr]
        assert pid is not None
        t_kill = time.monotonic()
        os.kill(pid, signal.SIGKILL)  # mid-jog
        s = rig.wait_state("fault", timeout=2.0)
        assert time.monotonic() - t_kill < 0.5
        assert "signal 9" in s["fault"]["message"] and s["servo_process"].startswith("ended by signal 9"), s
        assert rig.post("/api/jog", h, json={"joints": JOG_X}, expect=409).json()["detail"].endswith(
            "reset the fault to start a new servo process: POST /api/reset")

        rig.post("/api/reset", h)  # a new toy servo process
        s = rig.wait_state("disconnected", "connected", "ready")
        assert s["fault"] is None and s["servo_starts"] == 2 and rig.service.stream.pid != pid  # type: ignore[union-attr]
        rig.post("/api/session/start", h)
        assert rig.state()["state"] == "streaming"
        jog_moves(rig, h)
        rig.end_and_wait(h)
    no_children_left()
