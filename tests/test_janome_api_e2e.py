"""Janome through the REST API (a running uvicorn): link loss mid-motion and bad frames.

The robot's point job is the simulator in this test process, so the test can cut its link or corrupt
its frames; servo_app listens in its own servo process, as in production.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import websockets.sync.client
from test_api_harness import TOKEN, Rig, running_janome_rig

from servo_app.sim.janome_sim import JanomeSimulator

pytestmark = pytest.mark.e2e


@pytest.fixture
def janome(tmp_path: Path) -> Iterator[tuple[Rig, JanomeSimulator]]:
    with running_janome_rig(tmp_path) as rig_and_robot:
        yield rig_and_robot


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
    assert r.json()["detail"].endswith("reset the fault: POST /api/reset"), r.text


def test_twist_and_pose_target_map_to_x_y_z_r(janome: tuple[Rig, JanomeSimulator]) -> None:
    """A twist jogs X Y Z and R (its rotation about Z); a pose target goes to X Y Z R. What a SCARA or
    Cartesian robot cannot do is refused as not supported by the Janome backend, and changes nothing."""
    rig, _sim = janome
    hdr = rig.lease()
    rig.wait_state("ready")
    s0 = rig.start_streaming(hdr)
    x0 = s0["q_cmd"][0]
    for body, words in (({"linear": [10.0, 0, 0], "angular": [5.0, 0, 0]}, ["angular", "only about Z"]),
                        ({"linear": [10.0, 0, 0], "frame": "tool"}, ["frame='tool'"]),
                        ({"linear": [0, 0, 0], "angular": [0, 0, 5000.0]},
                         ["angular[2]=5000 deg/s", "R's speed limit 200 deg/s"]),
                        ({"joints": [900.0, 0, 0, 0]}, ["joints[0]=900 mm/s", "X's speed limit 100 mm/s"]),
                        ({"joints": [10.0, 0, 0]}, ["joints has 3 values, expected 4"])):
        r = rig.http.post("/api/jog", json=body, headers=hdr)
        assert r.status_code == 422, (body, r.text)
        for w in words:
            assert w in r.json()["detail"], (w, r.json())
        if "angular" in body and body["angular"][0]:
            assert r.json()["detail"].startswith("not supported by the Janome backend: ")
    # A twist along +X and about Z moves X and R.
    end = time.monotonic() + 0.6
    while time.monotonic() < end:
        r = rig.http.post("/api/jog", json={"linear": [40.0, 0, 0], "angular": [0, 0, 20.0], "hold_ms": 500},
                          headers=hdr)
        assert r.status_code == 200, r.text
        time.sleep(0.1)
    s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 10.0, "hold-to-run stop")
    assert s["q_cmd"][0] > x0 + 2.0 and s["q_cmd"][3] > s0["q_cmd"][3] + 1.0, s["q_cmd"]
    # A pose target: tilting is refused; X Y Z R is reached (and resumes the hold-to-run stop).
    r = rig.http.post("/api/target", json={"xyzwpr": [100.0, 100.0, 20.0, 10.0, 0.0, 30.0]}, headers=hdr)
    assert r.status_code == 422 and r.json()["detail"].startswith("not supported by the Janome backend: W=10"), r.text
    r = rig.http.post("/api/target", json={"xyzwpr": [100.0, 400.0, 20.0, 0.0, 0.0, 30.0]}, headers=hdr)
    assert r.status_code == 422 and "Y=400" in r.json()["detail"], r.text
    assert rig.state()["state"] == "stopped"  # nothing changed
    goal = [100.0, 100.0, 20.0, 30.0]
    rig.post("/api/target", hdr, {"xyzwpr": [100.0, 100.0, 20.0, 0.0, 0.0, 30.0], "linear_speed": 200.0,
                                  "angular_speed": 90.0})
    s = rig.wait(lambda s: (s["at_rest"] and abs(s["q_cmd"][0] - goal[0]) < 1e-3) or s["state"] != "streaming",
                 15.0, "the pose reached")
    assert s["state"] == "streaming" and s["q_cmd"][:4] == pytest.approx(goal, abs=1e-3), s["q_cmd"]


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
    rig.post("/api/session/end", hdr)  # ending needs the lease (stopping does not)
    rig.wait_state("ended")


def test_a_link_warning_shows_at_once_while_the_stream_runs_on(janome: tuple[Rig, JanomeSimulator]) -> None:
    """A warning on its own (no change of the safety state) reaches GET /api/state and /ws/telemetry
    while the stream runs on. It showed only at the next state change (a stop) before: the servo
    process sent its safety view only when the state changed."""
    rig, sim = janome
    hdr = rig.lease()
    rig.wait_state("ready")
    rig.start_streaming(hdr)
    assert rig.state()["warnings"] == []
    with websockets.sync.client.connect(f"{rig.ws_url}/ws/telemetry?hz=50") as ws:
        sim.corrupt_next_target()  # the robot answers a frame error: the target is sent again, a warning
        s = rig.wait(lambda s: bool(s["warnings"]), 5.0, "the warning in GET /api/state")
        assert s["state"] == "streaming" and s["fault"] is None, s
        w = s["warnings"][-1]
        assert w["code"] == "link" and w["message"].startswith("robot rejected target"), w
        deadline = time.monotonic() + 5.0
        while not (seen := json.loads(ws.recv(timeout=5)))["warnings"]:
            assert time.monotonic() < deadline, "no warning on /ws/telemetry"
        assert seen["warnings"][-1]["message"] == w["message"] and seen["state"] == "streaming", seen
    assert rig.state()["state"] == "streaming"  # nothing but the warning changed


def test_limits_are_the_speeds_commanded_and_a_faster_jog_is_refused(janome: tuple[Rig, JanomeSimulator]) -> None:
    """GET /api/limits gives the speeds the stream really commands: the JR3000's profile allows 800 mm/s,
    the link one step of 10 mm per 0.1 s (100 mm/s; R 20 deg: 200 deg/s). It gave the profile's 800,
    and a jog at 300 mm/s was answered 200 and ran at 100. Now a jog or twist over them is refused
    (422 naming the field, the value, the limit, where it comes from and what to send), changing
    nothing; one at the limit runs at it."""
    rig, _sim = janome
    lim = rig.http.get("/api/limits").json()
    assert lim["speed"] == [100.0, 100.0, 100.0, 200.0] and lim["cp_speed_mm_s"] == 100.0, lim
    assert lim["speed_source"][0] == lim["cp_speed_source"] == \
        "the link's step: link.max_step_mm 10 mm per 0.1 s step", lim
    assert lim["speed_source"][3] == "the link's step: link.max_step_deg 20 deg per 0.1 s step", lim
    assert lim["profile_speed"] == [800.0, 800.0, 320.0, 1000.0] and lim["profile_cp_speed_mm_s"] == 800.0, lim
    # The console's jog slider is a share of the axes' speeds in GET /api/robot: the same ones.
    assert [a["speed"] for a in rig.http.get("/api/robot").json()["axes"]] == lim["speed"]

    hdr = rig.lease()
    rig.wait_state("ready")
    rig.start_streaming(hdr)
    # At the limit: accepted, commanded at 100 mm/s (the state's vel is the commands' own rate).
    top = 0.0
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        rig.post("/api/jog", hdr, {"joints": [lim["speed"][0], 0.0, 0.0, 0.0], "hold_ms": 300})
        top = max(top, rig.state()["vel"][0])
        time.sleep(0.05)
    assert top == pytest.approx(100.0, abs=0.5), top
    s0 = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 10.0, "the hold-to-run stop")
    assert s0["q_cmd"][0] > 150.0 + 30.0, s0["q_cmd"]  # from home X=150

    for body, words in (
            ({"joints": [300.0, 0, 0, 0]},
             "joints[0]=300 mm/s is faster than X's speed limit 100 mm/s (the link's step: link.max_step_mm 10 mm "
             "per 0.1 s step); send at most 100 mm/s, as GET /api/limits says (speed)"),
            ({"joints": [0, 0, 0, -200.5]},
             "joints[3]=-200.5 deg/s is faster than R's speed limit 200 deg/s (the link's step: link.max_step_deg "
             "20 deg per 0.1 s step); send at most 200 deg/s, as GET /api/limits says (speed)"),
            ({"linear": [0, 300.0, 0]},
             "linear[1]=300 mm/s is faster than Y's speed limit 100 mm/s (the link's step: link.max_step_mm 10 mm "
             "per 0.1 s step); send at most 100 mm/s, as GET /api/limits says (speed)"),
            ({"linear": [80.0, 0, -80.0], "angular": [0, 0, 10.0]},
             "linear[0], linear[1], linear[2] = [80.0, 0.0, -80.0] mm/s: 113.1 mm/s along X Y Z is above the line "
             "speed limit 100 mm/s (the link's step: link.max_step_mm 10 mm per 0.1 s step); send at most 100 mm/s "
             "along X Y Z, as GET /api/limits says (cp_speed_mm_s)")):
        r = rig.http.post("/api/jog", json={**body, "hold_ms": 300}, headers=hdr)
        assert r.status_code == 422 and r.json()["detail"] == words, (body, r.text)
        s = rig.state()  # a refused jog resumes nothing and moves nothing
        assert s["state"] == "stopped" and s["at_rest"] and s["q_cmd"] == s0["q_cmd"], s
