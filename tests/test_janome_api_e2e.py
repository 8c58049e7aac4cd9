"""Janome through the REST API (a running uvicorn): link loss mid-motion and bad frames.

The robot's point job is the simulator in this test process, so the test can cut its link or corrupt
its frames; servo_app listens in its own servo process, as in production.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_api_harness import TOKEN, LiveServer, Rig

from servo_app.api.app import create_app
from servo_app.service import ServiceConfig, ServoService
from servo_app.sim.janome_sim import JanomeSimulator

pytestmark = pytest.mark.e2e


@pytest.fixture
def janome(tmp_path: Path) -> Iterator[tuple[Rig, JanomeSimulator]]:
    service = ServoService(ServiceConfig(robot="janome:127.0.0.1:0", model="jr3000", var_dir=tmp_path))
    service.open()
    server = LiveServer(create_app(service, TOKEN)).start()
    rig = Rig(service, server, tmp_path)
    assert service.robot_address is not None
    sim = JanomeSimulator(service.robot_address, "jr3000").start()
    try:
        yield rig, sim
    finally:
        sim.stop()
        server.stop()
        service.close()


def jog_x(rig: Rig, headers: dict[str, str], seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rig.http.post("/api/jog", json={"joints": [40.0, 0.0, 0.0, 0.0], "hold_ms": 500}, headers=headers)
        time.sleep(0.1)


def test_link_loss_mid_motion_is_a_fault_with_the_reason(janome: tuple[Rig, JanomeSimulator]) -> None:
    rig, sim = janome
    hdr = rig.lease()
    rig.wait_state("ready")
    rig.start_streaming(hdr)
    jog_x(rig, hdr, 0.4)
    assert rig.state()["state"] == "streaming"
    sim.kill_link()  # the cable: a reset, mid-motion
    s = rig.wait_state("fault", timeout=10)
    assert "connection lost" in s["fault"]["message"]
    # Motion is refused until reset; the API stays up and says why.
    r = rig.http.post("/api/jog", json={"joints": [10.0, 0, 0, 0]}, headers=hdr)
    assert r.status_code == 409 and "fault" in r.text


def test_bad_frames_are_rejected_with_a_clear_error_and_the_arm_keeps_safe(
        janome: tuple[Rig, JanomeSimulator]) -> None:
    rig, sim = janome
    hdr = rig.lease()
    rig.wait_state("ready")
    rig.start_streaming(hdr)
    sim.corrupt_next_status()  # a status with a bad checksum: counted, answered with HOLD
    jog_x(rig, hdr, 0.5)
    s = rig.state()
    assert s["malformed"] >= 1
    assert s["state"] in ("streaming", "stopped", "stopping")
    rig.post("/api/session/stop", {"Authorization": f"Bearer {TOKEN}"})
    s = rig.wait_state("stopped")
    assert s["fault"] is None
    rig.post("/api/session/end", {"Authorization": f"Bearer {TOKEN}"})
    rig.wait_state("ended")
