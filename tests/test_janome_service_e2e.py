"""`servo-app run --robot janome` as a process, with its embedded robot (the point-job simulator in a
process of its own): signals to the group and to the simulator, with real sockets on loopback."""

from __future__ import annotations

import os
import signal

import httpx
import pytest
from test_api_harness import AUTH
from test_fault_matrix_e2e import _serve, alive, children_of, eventually

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
