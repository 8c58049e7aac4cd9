"""`servo-app run --robot janome` as a process, with its embedded robot (the point-job simulator in a
process of its own): signals to the group and to the simulator, with real sockets on loopback."""

from __future__ import annotations

import os
import signal

import httpx
import pytest
from test_api_harness import AUTH, running_rig
from test_fault_matrix_e2e import _serve, alive, children_of, eventually, no_children_left

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

JOG = {"joints": [40.0, 0.0, 0.0, 0.0], "hold_ms": 2000}


def test_ctrl_c_ends_the_janome_stream_cleanly(tmp_path: os.PathLike[str]) -> None:
    """Ctrl-C (SIGINT to the whole process group) mid-motion: the embedded robot keeps answering while
    the servo process stops, sends END and gets BYE; the stream ends (no fault) and nothing is left.
    (The simulator process used to die of KeyboardInterrupt first: "stream fault, link fault".)"""
    proc, base, err = _serve(["--robot", "janome"], tmp_path)  # type: ignore[arg-type]
    try:
        with httpx.Client(base_url=base, timeout=5) as c:
            assert eventually(lambda: c.get("/api/state").json()["state"] == "ready", timeout=30)
            h = {**AUTH, "X-Lease-Id": c.post("/api/lease", json={"client": "ops"}, headers=AUTH).json()["lease_id"]}
            assert c.post("/api/session/start", headers=h).status_code == 200
            assert c.post("/api/jog", json=JOG, headers=h).status_code == 200
            assert eventually(lambda: c.get("/api/state").json()["q_cmd"][0] > 5.0, timeout=10)
        kids = children_of(proc.pid)
        os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C in its terminal
        code = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)
    assert proc.stdout is not None
    out = proc.stdout.read()
    assert code == 0, out + "".join(err)
    assert "stream ended, link closed, servo process exit code 0" in out, out + "".join(err)
    assert "Traceback" not in "".join(err), "".join(err)
    assert eventually(lambda: not any(alive(p) for p in kids), timeout=5.0)


def test_embedded_robot_killed_then_reset_brings_it_back(tmp_path: os.PathLike[str]) -> None:
    """SIGKILL to the embedded robot's process mid-motion: a named fault; reset starts the robot again
    (as its operator would start the point job), it connects, and a new stream moves. (It used to stay
    "disconnected" for good: only a restart of servo_app brought the embedded robot back.)"""
    with running_rig(tmp_path, robot="janome") as rig:  # type: ignore[arg-type]
        h = rig.lease()
        rig.wait_state("ready", timeout=30)
        rig.start_streaming(h)
        rig.jog_for(h, [40.0, 0.0, 0.0, 0.0], 0.4, hold_ms=500)
        killed = rig.service.sim.process.pid
        os.kill(killed, signal.SIGKILL)
        s = rig.wait_state("fault", timeout=10)
        assert s["fault"]["message"].startswith("connection lost while"), s["fault"]
        last = s["q_servo"][:4]  # where the robot last said it was
        rig.post("/api/reset", h)
        s = rig.wait_state("ready", timeout=30)
        assert s["fault"] is None and s["robot_connected"], s
        # The new robot stands where the killed one stopped, not at its home (a jump no arm makes).
        assert s["q_servo"][:4] == pytest.approx(last, abs=1e-3), (last, s["q_servo"])
        assert rig.service.sim.process.pid != killed and not alive(killed)
        s0 = rig.start_streaming(h)
        rig.jog_for(h, [40.0, 0.0, 0.0, 0.0], 0.6, hold_ms=500)
        s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 10.0, "hold-to-run stop")
        assert s["q_cmd"][0] > s0["q_cmd"][0] + 2.0, (s0["q_cmd"], s["q_cmd"])
    no_children_left()
