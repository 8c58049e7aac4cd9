"""Tools (TCP frames) end to end: a running service (uvicorn, the servo process, the embedded FANUC
simulator on loopback) with a tools file; jogs, pose targets, the displayed pose, the tool change's
refusals, the payload's limits, the client; zero controller alarms throughout. The Janome backend's
refusal and the command line's check of a bad file too."""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_api_harness import AUTH, TOKEN, Rig, running_rig

from servo_app.client import RefusedError, ServoClient
from servo_app.robots.conventions import xyzwpr_to_matrix
from servo_app.robots.tool import ToolError
from servo_app.service import ServiceConfig, ServoService
from servo_app.service.tools import MAX_RUNTIME_TOOLS

pytestmark = pytest.mark.e2e

TOOLS = """
active = "gripper"

[tools.gripper]
xyzwpr = [0, 0, 150, 0, 0, 0]
payload_kg = 2.5

[tools.tilted]
xyzwpr = [0, 0, 150, 0, 30, 0]
payload_kg = 1.0

[tools.heavy]
xyzwpr = [0, 0, 120, 0, 0, 0]
payload_kg = 7.0
"""
GRIPPER = [0.0, 0.0, 150.0, 0.0, 0.0, 0.0]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    d = tmp_path_factory.mktemp("tools")
    (d / "tools.toml").write_text(TOOLS)
    with running_rig(d, tools_file=d / "tools.toml") as r:
        yield r


def at_rest_with(rig: Rig, tool: str) -> dict[str, str]:
    """The lease, a stream and the arm settled with ``tool`` active (an earlier test may have left it
    moving or with another tool)."""
    h = rig.streaming("tools")
    rig.wait(lambda s: s["at_rest"] and s["settled"], 15.0, "settled")
    r = rig.http.put("/api/tool", json={"name": tool}, headers=h)
    assert r.status_code == 200, r.text
    return h


def settled(rig: Rig) -> dict:
    return rig.wait_at_rest_settled(10.0)


def hold_twist(rig: Rig, h: dict[str, str], seconds: float, **twist: object) -> list[dict]:
    """Renew a twist jog for ``seconds`` and collect the state on the way (the TCP and the flange)."""
    states = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        r = rig.http.post("/api/jog", json={"hold_ms": 300, **twist}, headers=h)
        assert r.status_code == 200, r.text
        states.append(rig.state())
        time.sleep(0.04)
    states.append(settled(rig))
    return states


def rotation_between(a: list[float], b: list[float]) -> float:
    ra, rb = xyzwpr_to_matrix(a)[:3, :3], xyzwpr_to_matrix(b)[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(ra.T @ rb) - 1) / 2, -1, 1))))


def test_tools_listed_with_the_active_one_in_the_state(rig: Rig) -> None:
    tools = rig.http.get("/api/tools").json()
    assert [t["name"] for t in tools["tools"]] == ["flange", "gripper", "tilted", "heavy"]
    assert tools["tools"][0] == {"name": "flange", "xyzwpr": [0.0] * 6, "payload_kg": None}
    at_rest_with(rig, "gripper")
    s = rig.state()
    assert s["tool"] == {"name": "gripper", "xyzwpr": GRIPPER, "payload_kg": 2.5}
    assert rig.http.get("/api/tools").json()["active"] == "gripper"
    # The displayed pose is the TCP: the flange the controller reports times the tool.
    tcp = xyzwpr_to_matrix(s["flange_pose"]) @ xyzwpr_to_matrix(GRIPPER)
    np.testing.assert_allclose(xyzwpr_to_matrix(s["cart_servo"]), tcp, atol=1e-6)
    assert np.linalg.norm(np.subtract(s["cart_servo"][:3], s["flange_pose"][:3])) == pytest.approx(150.0, abs=1e-3)


@pytest.mark.parametrize("axis", [0, 2])
def test_turning_about_the_tool_keeps_the_tcp_still(rig: Rig, axis: int) -> None:
    h = at_rest_with(rig, "gripper")
    start = settled(rig)
    angular = [0.0, 0.0, 0.0]
    angular[axis] = 15.0
    states = hold_twist(rig, h, 1.2, linear=[0.0, 0.0, 0.0], angular=angular, frame="tool")
    p0 = np.array(start["cart_servo"][:3])
    drift = max(float(np.linalg.norm(np.array(s["cart_servo"][:3]) - p0)) for s in states)
    assert drift < 1.0, f"the TCP moved {drift:.2f} mm"
    end = states[-1]
    assert rotation_between(start["flange_pose"], end["flange_pose"]) > 8.0, "the flange turned"
    if axis == 0:  # about x the flange swings round the TCP; about z (the flange's own axis) it turns in place
        assert np.linalg.norm(np.subtract(end["flange_pose"][:3], start["flange_pose"][:3])) > 10.0
    assert rig.sim_alarms() == []


def test_a_linear_tool_jog_moves_the_tcp_along_the_tools_axis(rig: Rig) -> None:
    h = at_rest_with(rig, "tilted")
    start = settled(rig)
    states = hold_twist(rig, h, 1.0, linear=[0.0, 0.0, 40.0], angular=[0.0, 0.0, 0.0], frame="tool")
    axis = xyzwpr_to_matrix(start["cart_servo"])[:3, 2]
    flange_axis = xyzwpr_to_matrix(start["flange_pose"])[:3, 2]
    assert float(axis @ flange_axis) < 0.9, "the tilted tool's z is not the flange's"
    moved = np.subtract(states[-1]["cart_servo"][:3], start["cart_servo"][:3])
    along = float(moved @ axis)
    assert along > 20.0
    assert np.linalg.norm(moved - along * axis) < 1.0, moved
    assert rotation_between(start["cart_servo"], states[-1]["cart_servo"]) < 0.1
    assert rig.sim_alarms() == []


def test_a_pose_target_reaches_the_tcp_pose(rig: Rig) -> None:
    h = at_rest_with(rig, "gripper")
    start = settled(rig)
    goal = list(np.add(start["cart_servo"], [40.0, -30.0, 20.0, 0.0, 0.0, 10.0]))
    rig.post("/api/target", h, {"xyzwpr": goal, "linear_speed": 150.0, "angular_speed": 45.0})
    rig.wait(lambda s: s["at_rest"], 15.0, "at the target")
    s = settled(rig)
    np.testing.assert_allclose(s["cart_servo"][:3], goal[:3], atol=0.2)
    assert rotation_between(s["cart_servo"], goal) < 0.05
    tcp_of_flange = xyzwpr_to_matrix(s["flange_pose"]) @ xyzwpr_to_matrix(GRIPPER)
    np.testing.assert_allclose(tcp_of_flange[:3, 3] * 1000, goal[:3], atol=0.2)
    assert np.linalg.norm(np.subtract(s["flange_pose"][:3], goal[:3])) == pytest.approx(150.0, abs=0.3)
    assert rig.sim_alarms() == []


def test_a_tool_change_while_jogging_is_refused_and_changes_nothing(rig: Rig) -> None:
    h = at_rest_with(rig, "gripper")
    limits = rig.http.get("/api/limits").json()
    rig.post("/api/jog", h, {"joints": [15.0, 0, 0, 0, 0, 0], "hold_ms": 1500})
    rig.wait(lambda s: not s["at_rest"], 5.0, "moving")
    r = rig.http.put("/api/tool", json={"name": "tilted"}, headers=h)
    assert r.status_code == 409, r.text
    assert "moving" in r.json()["detail"]
    s = rig.state()
    assert s["tool"]["name"] == "gripper" and rig.http.get("/api/tools").json()["active"] == "gripper"
    assert rig.http.get("/api/limits").json() == limits
    rig.post("/api/session/stop", h)
    rig.wait(lambda s: s["at_rest"] and s["settled"], 10.0, "settled")
    # Unknown: 404 naming the defined tools; without the lease: refused; neither changes anything.
    r = rig.http.put("/api/tool", json={"name": "hammer"}, headers=h)
    assert r.status_code == 404 and "gripper" in r.json()["detail"]
    assert rig.http.put("/api/tool", json={"name": "tilted"}, headers=AUTH).status_code == 409
    assert rig.state()["tool"]["name"] == "gripper"
    # At rest: taken, and the next jog turns about the new TCP.
    r = rig.http.put("/api/tool", json={"name": "tilted"}, headers=h)
    assert r.status_code == 200 and r.json()["name"] == "tilted"
    rig.post("/api/session/resume", h)  # the stop before it (a soft stop: taken at rest too)
    rig.wait_state("streaming")
    s0 = settled(rig)
    assert s0["tool"]["name"] == "tilted"
    states = hold_twist(rig, h, 0.8, linear=[0.0, 0.0, 0.0], angular=[0.0, 12.0, 0.0], frame="tool")
    drift = max(float(np.linalg.norm(np.subtract(s["cart_servo"][:3], s0["cart_servo"][:3]))) for s in states)
    assert drift < 1.0
    assert rig.sim_alarms() == []


def test_a_turn_too_fast_for_the_flange_is_422_and_changes_nothing(rig: Rig) -> None:
    """A turn about the gripper's TCP (150 mm out) swings the flange at |w| 150 mm/s: above the flange's
    speed cap it is the request's own values (422, naming the turn, the tool and the cap, and what to
    send), as a TCP speed above it is; the arm stays where it was and the stream streaming. (A pose
    target within its REST bounds cannot reach the cap with this tool: the supervisor's tests cover it.)"""
    h = at_rest_with(rig, "gripper")
    s0 = settled(rig)
    vmax = rig.http.get("/api/limits").json()["max_flange_speed_mm_s"]
    # The TCP at 0.6 of the cap (taken alone) and a swing of 0.6 of it: the flange at up to 1.2 times.
    linear, turn = 0.6 * vmax, round(math.degrees(0.6 * vmax / 150.0), 1)
    assert turn <= 1000.0, "within the request's own bound, so the cap is what refuses it"
    r = rig.http.post("/api/jog", json={"linear": [linear, 0.0, 0.0], "angular": [0.0, 0.0, turn], "frame": "tool"},
                      headers=h)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    for words in (f"linear speed {linear:.1f} mm/s + {turn:g} deg/s about a TCP 150 mm from the flange",
                  "is above the flange-speed cap", "send a slower turn or linear speed"):
        assert words in detail, (words, detail)
    s = rig.state()
    assert s["state"] == "streaming" and s["at_rest"] and s["q_cmd"] == s0["q_cmd"], s["state"]
    # A slow turn about the same TCP is taken.
    rig.post("/api/jog", h, {"linear": [0.0, 0.0, 0.0], "angular": [0.0, 0.0, turn / 10], "frame": "tool",
                             "hold_ms": 100})
    rig.wait(lambda s: not s["at_rest"], 5.0, "turning")
    settled(rig)
    assert rig.sim_alarms() == []


def test_the_payload_picks_the_limit_tables_and_the_heavy_tool_streams_clean(rig: Rig) -> None:
    h = at_rest_with(rig, "tilted")  # 1 kg
    light = rig.http.get("/api/limits").json()
    assert light["tool"] == "tilted" and light["payload_kg"] == 1.0
    rig.http.put("/api/tool", json={"name": "heavy"}, headers=h).raise_for_status()  # 7 kg: the maximum
    heavy = rig.http.get("/api/limits").json()
    assert heavy["payload_kg"] == 7.0
    assert np.all(np.array(heavy["acc_deg_s2"]) <= np.array(light["acc_deg_s2"]))
    assert np.any(np.array(heavy["acc_deg_s2"]) < np.array(light["acc_deg_s2"]))
    s = rig.state()
    np.testing.assert_allclose(s["acc_limit"], heavy["acc_deg_s2"])  # the stream's own limits follow
    # A brisk joint jog out and back with the heavy tool: the controller's checker (at 7 kg) stays quiet.
    rig.jog_for(h, [60.0, -30.0, 40.0, 0.0, 0.0, 90.0], 0.6)
    rig.jog_for(h, [-60.0, 30.0, -40.0, 0.0, 0.0, -90.0], 0.6)
    settled(rig)
    assert rig.sim_alarms() == []
    assert rig.state()["state"] in ("streaming", "stopped")  # a hold-to-run stop at the end, no fault


def test_replayed_poses_are_the_active_tools_tcp(rig: Rig) -> None:
    """POST /api/trajectory's poses are TCP poses of the active tool: the replay ends with the TCP (not
    the flange) on the last pose, zero alarms."""
    h = at_rest_with(rig, "gripper")
    start = settled(rig)
    goal = list(np.add(start["cart_servo"], [30.0, 25.0, -20.0, 0.0, 0.0, 8.0]))
    r = rig.http.post("/api/trajectory", headers=h, json={"poses": [goal]})
    assert r.status_code == 200, r.text
    rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 20.0, "replayed")
    s = settled(rig)
    np.testing.assert_allclose(s["cart_servo"][:3], goal[:3], atol=0.2)
    assert rotation_between(s["cart_servo"], goal) < 0.05
    assert np.linalg.norm(np.subtract(s["flange_pose"][:3], goal[:3])) == pytest.approx(150.0, abs=0.3)
    assert rig.sim_alarms() == []


def test_client_set_tool_and_move_pose(rig: Rig) -> None:
    at_rest_with(rig, "flange")
    with ServoClient(rig.base_url, TOKEN, name="tool-client", take_over=True) as arm:
        arm.ensure_streaming()
        assert [t.name for t in arm.tools()] == ["flange", "gripper", "tilted", "heavy"]
        tool = arm.set_tool("gripper")
        assert tool.name == "gripper" and tool.xyzwpr == tuple(GRIPPER) and tool.payload_kg == 2.5
        s = arm.wait_settled()
        assert s.tool is not None and s.tool.name == "gripper" and s.pose is not None and s.flange_pose is not None
        goal = [s.pose[0] + 25.0, s.pose[1], s.pose[2] - 20.0, *s.pose[3:]]
        arm.move_pose(goal, linear_speed=150.0)
        s = arm.wait_settled()
        np.testing.assert_allclose(s.pose[:3], goal[:3], atol=0.2)  # type: ignore[index]
        with pytest.raises(RefusedError) as exc:
            arm.set_tool("hammer")
        assert exc.value.status == 404
        defined = arm.define_tool("probe", [0, 10, 90, 0, 0, 0], 0.5)
        assert defined.name == "probe" and "probe" in [t.name for t in arm.tools()]
        with pytest.raises(RefusedError, match="maximum payload"):
            arm.define_tool("anvil", [0, 0, 50, 0, 0, 0], 9.0)
        for twin, of in (("PROBE", "probe"), ("Flange", "flange")):  # a name apart only in case: refused
            with pytest.raises(RefusedError, match=f"differs from tool '{of}' only in case") as exc:
                arm.define_tool(twin, [0, 0, 50, 0, 0, 0], 1.0)
            assert exc.value.status == 422
            # The way out works: redefine the twin (probe), or name it otherwise (flange is built in).
            assert ("use 'probe' to redefine it" if of == "probe" else "name the tool otherwise") in str(exc.value)
        assert [t.name for t in arm.tools()].count("probe") == 1 and "PROBE" not in [t.name for t in arm.tools()]
    assert rig.sim_alarms() == []


def test_a_taught_point_keeps_the_tcp_pose_and_the_tool(rig: Rig) -> None:
    h = at_rest_with(rig, "gripper")
    s = settled(rig)
    point = rig.post("/api/points/tool_corner", h).json()
    assert point["tool"] == "gripper"
    np.testing.assert_allclose(point["xyzwpr"], s["cart_servo"], atol=1e-3)


# ------------------------------------------------------------------------ the configuration's checks
def test_a_payload_above_the_maximum_is_refused_at_start(tmp_path: Path) -> None:
    bad = tmp_path / "tools.toml"
    bad.write_text('[tools.anvil]\nxyzwpr = [0, 0, 80, 0, 0, 0]\npayload_kg = 12\n')
    with pytest.raises(ToolError, match=r"tools.anvil.payload_kg=12 kg is above the robot's maximum payload of 7 kg"):
        ServoService(ServiceConfig(var_dir=tmp_path, tools_file=bad))
    p = subprocess.run([sys.executable, "-m", "servo_app.cli", "run", "--tools", str(bad), "--var-dir",
                        str(tmp_path), "--http-port", "0", "--token", TOKEN], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "tools.anvil.payload_kg=12" in p.stdout


def test_janome_refuses_a_tool_offset(tmp_path: Path) -> None:
    tools = tmp_path / "tools.toml"
    tools.write_text(TOOLS)
    cfg = ServiceConfig(robot="janome:127.0.0.1:0", model="jr3000", var_dir=tmp_path, tools_file=tools)
    with pytest.raises(ToolError, match="not supported by the Janome backend"):
        ServoService(cfg).open()  # the file's active gripper
    cfg.tool = "flange"
    service = ServoService(cfg)
    service.open()
    try:
        with pytest.raises(Exception, match="not supported by the Janome backend: tool 'gripper'"):
            service.set_tool("gripper")
        assert service.tools.active.name == "flange"
    finally:
        service.close()


def test_a_tool_change_the_embedded_controller_cannot_take_is_refused_and_changes_nothing(tmp_path: Path) -> None:
    (tmp_path / "tools.toml").write_text(TOOLS)
    with running_rig(tmp_path, tools_file=tmp_path / "tools.toml") as rig:
        h = at_rest_with(rig, "gripper")
        rig.service.sim.process.kill()  # the controller's process dies: its payload cannot follow the tool
        rig.wait_state("fault")
        r = rig.http.put("/api/tool", json={"name": "heavy"}, headers=h)
        assert r.status_code == 503, r.text
        assert "the tool is not changed ('gripper' is active)" in r.json()["detail"], r.text
        # Refused, so nothing changed: the service's tool (was 'heavy' after the 503) and the servo process's.
        assert rig.http.get("/api/tools").json()["active"] == "gripper"
        assert rig.state()["tool"]["name"] == "gripper"
        rig.post("/api/reset", h)
        rig.wait_state("disconnected", "connected", "ready", "ended")
        rig.start_streaming(h)
        s = rig.wait_at_rest_settled()
        assert rig.http.get("/api/limits").json()["payload_kg"] == 2.5
        assert_moves_the_tcp_shown(rig, h, s, timeout=3.0)
        assert rig.sim_alarms() == []


def assert_moves_the_tcp_shown(rig: Rig, h: dict[str, str], s: dict[str, Any], timeout: float = 10.0) -> None:
    """The servo process moves the TCP the service shows (state ``s``, at rest): a pose target at the
    pose shown is where the arm already is."""
    rig.post("/api/target", h, {"xyzwpr": s["cart_servo"], "linear_speed": 50.0})
    after = rig.wait_at_rest_settled(timeout)
    np.testing.assert_allclose(after["q_cmd"][:6], s["q_cmd"][:6], atol=1e-3)

def test_a_tool_change_that_times_out_is_not_taken_later_by_a_stalled_servo_process(tmp_path: Path) -> None:
    """The servo process stalled (SIGSTOP) when a tool change comes: 503, the tool not changed. Once it
    runs again (SIGCONT) it must not take the change it stopped on: the arm would move a TCP other than
    the one the service shows (old code: it took 'tilted' with 'gripper' still shown)."""
    (tmp_path / "tools.toml").write_text(TOOLS)
    with running_rig(tmp_path, tools_file=tmp_path / "tools.toml", request_timeout_s=0.5) as rig:
        h = rig.lease()
        assert rig.state()["tool"]["name"] == "gripper"
        assert rig.service.stream is not None and rig.service.stream.pid is not None
        pid = rig.service.stream.pid
        os.kill(pid, signal.SIGSTOP)
        try:
            r = rig.http.put("/api/tool", json={"name": "tilted"}, headers=h)
            assert r.status_code == 503, r.text
            detail = r.json()["detail"]
            assert "the tool is not changed ('gripper' is active)" in detail and "will not take" in detail, detail
            assert rig.http.get("/api/tools").json()["active"] == "gripper"
        finally:
            os.kill(pid, signal.SIGCONT)
        # The stalled process reads the change now; the next request is answered after it (one pipe).
        rig.start_streaming(h)
        s = rig.wait_at_rest_settled(10.0)
        assert s["tool"]["name"] == "gripper" and rig.http.get("/api/tools").json()["active"] == "gripper"
        assert_moves_the_tcp_shown(rig, h, s)
        assert rig.sim_alarms() == []


def test_an_undone_tool_change_that_times_out_stops_the_stalled_servo_process(tmp_path: Path) -> None:
    """The controller cannot take the new tool's payload (its process killed), so the change is undone;
    the servo process, which took 'heavy', stalls (SIGSTOP) before the undoing. It holds a tool the
    service does not show: it is stopped (a named fault), the 503 says the tool is not changed, and a
    reset starts another with 'gripper' (old code: the raw timeout, the stalled process kept, and the
    reset could not replace it: every request to it timed out)."""
    (tmp_path / "tools.toml").write_text(TOOLS)
    with running_rig(tmp_path, tools_file=tmp_path / "tools.toml", request_timeout_s=0.5) as rig:
        h = at_rest_with(rig, "gripper")
        assert rig.service.stream is not None and rig.service.stream.pid is not None
        pid = rig.service.stream.pid
        rig.service.sim.process.kill()  # the controller's process dies: its payload cannot follow the tool
        rig.wait_state("fault")
        tools = rig.service.tools
        set_payload = tools._set_simulator_payload
        assert set_payload is not None

        def stall_then_set(payload_kg: float | None) -> None:  # the servo process stops before the undoing
            os.kill(pid, signal.SIGSTOP)
            set_payload(payload_kg)

        tools._set_simulator_payload = stall_then_set
        try:
            r = rig.http.put("/api/tool", json={"name": "heavy"}, headers=h)
            tools._set_simulator_payload = set_payload
            assert r.status_code == 503, r.text
            detail = r.json()["detail"]
            assert "the tool is not changed ('gripper' is active)" in detail and "was stopped (fault)" in detail, detail
            assert "took tool 'heavy' and did not answer its undoing in time" in detail, detail
            s = rig.state()
            assert s["state"] == "fault" and "did not answer its undoing" in s["fault"]["message"], s["fault"]
            assert rig.http.get("/api/tools").json()["active"] == "gripper" and s["tool"]["name"] == "gripper"
            h = rig.lease()  # (the last one may have run out meanwhile: its 10 s)
            rig.post("/api/reset", h)  # the stalled process never runs again: another, given the active tool
            rig.wait_state("disconnected", "connected", "ready", "ended")
            assert rig.service.stream is not None and rig.service.stream.pid != pid
        finally:
            tools._set_simulator_payload = set_payload
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        rig.start_streaming(h)
        s = rig.wait_at_rest_settled(10.0)
        assert s["tool"]["name"] == "gripper" and rig.http.get("/api/limits").json()["payload_kg"] == 2.5
        assert_moves_the_tcp_shown(rig, h, s)


def test_a_new_servo_process_that_does_not_take_the_tool_in_time_is_stopped(tmp_path: Path) -> None:
    """A reset's new servo process stalls (SIGSTOP) before it takes the active tool: it would stream
    the flange's TCP while the service shows 'gripper'. It is stopped (a named fault), the reset's 503
    says so, the service stays up and the next reset starts another that takes the tool (old code: the
    raw timeout, the stalled process kept, and the next reset could not replace it)."""
    (tmp_path / "tools.toml").write_text(TOOLS)
    with running_rig(tmp_path, tools_file=tmp_path / "tools.toml", request_timeout_s=0.5) as rig:
        h = rig.lease()
        service = rig.service
        assert service.stream is not None and service.stream.pid is not None
        os.kill(service.stream.pid, signal.SIGKILL)  # the servo process dies: a reset replaces it
        rig.wait_state("fault")
        spawn = service._spawn
        stalled: list[int] = []

        def spawn_and_stall() -> None:  # the new process is up, then stops before the tool reaches it
            spawn()
            assert service.stream is not None and service.stream.pid is not None
            stalled.append(service.stream.pid)
            os.kill(service.stream.pid, signal.SIGSTOP)

        service._spawn = spawn_and_stall  # type: ignore[method-assign]
        try:
            r = rig.http.post("/api/reset", headers=h)
            assert r.status_code == 503, r.text
            detail = r.json()["detail"]
            assert "the new servo process did not take the active tool 'gripper' in time and was stopped (fault)" \
                in detail and "reset again" in detail, detail
            s = rig.state()
            assert s["state"] == "fault" and "did not take the active tool" in s["fault"]["message"], s["fault"]
            assert s["tool"]["name"] == "gripper"
            service._spawn = spawn  # type: ignore[method-assign]
            rig.post("/api/reset", h)  # the stalled process never runs again: another
            rig.wait_state("disconnected", "connected", "ready", "ended")
            assert service.stream is not None and service.stream.pid not in stalled
        finally:
            service._spawn = spawn  # type: ignore[method-assign]
            for pid in stalled:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGCONT)
        h = rig.lease()  # two resets and a stall can outlast the lease's 10 s under load (seen in CI-like runs)
        rig.start_streaming(h)
        s = rig.wait_at_rest_settled(10.0)
        assert s["tool"]["name"] == "gripper" and rig.http.get("/api/limits").json()["payload_kg"] == 2.5
        assert_moves_the_tcp_shown(rig, h, s)


def test_tools_added_at_run_time_are_bounded(tmp_path: Path) -> None:
    """POST /api/tools keeps each tool until the service stops: at most MAX_RUNTIME_TOOLS new names, the
    next one a 409 naming the limit that changes nothing; redefining one is still allowed (old code:
    no limit)."""
    (tmp_path / "tools.toml").write_text(TOOLS)
    with running_rig(tmp_path, tools_file=tmp_path / "tools.toml") as rig:
        h = rig.lease()
        for i in range(MAX_RUNTIME_TOOLS):
            r = rig.http.post("/api/tools", json={"name": f"t{i}", "xyzwpr": [0, 0, 10 + i, 0, 0, 0],
                                                  "payload_kg": 1.0}, headers=h)
            assert r.status_code == 200, r.text
        before = rig.http.get("/api/tools").json()
        assert len(before["tools"]) == 4 + MAX_RUNTIME_TOOLS  # the flange, the file's three, the added
        r = rig.http.post("/api/tools", json={"name": "one_more", "xyzwpr": [0, 0, 5, 0, 0, 0], "payload_kg": 1.0},
                          headers=h)
        assert r.status_code == 409, r.text
        assert f"at most {MAX_RUNTIME_TOOLS} tools can be added at run time" in r.json()["detail"], r.text
        assert rig.http.get("/api/tools").json() == before
        r = rig.http.post("/api/tools", json={"name": "t0", "xyzwpr": [0, 0, 99, 0, 0, 0], "payload_kg": 1.0},
                          headers=h)
        assert r.status_code == 200, r.text
        assert rig.http.put("/api/tool", json={"name": "t0"}, headers=h).status_code == 200
        assert rig.state()["tool"] == {"name": "t0", "xyzwpr": [0.0, 0.0, 99.0, 0.0, 0.0, 0.0], "payload_kg": 1.0}
