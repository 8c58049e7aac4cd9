"""servo_app.client end to end: a ServoClient against a running service (real uvicorn, the servo
process and the embedded FANUC simulator on loopback), every call, each typed error, the lease
renewed past its TTL and released on exit, jogs held by a block, zero controller alarms."""

from __future__ import annotations

import builtins
import math
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_api_harness import TOKEN, Rig, running_rig

from servo_app.client import (
    AuthError,
    FaultError,
    LeaseError,
    RefusedError,
    ServoClient,
    ServoError,
    State,
    StoppedError,
    TimeoutError,
    offset_in_tool,
)
from servo_app.robots.conventions import wpr_to_rotation

HOME = [0.0, 0.0, 0.0, 0.0, -90.0, 0.0]


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("client")) as r:
        yield r


@pytest.fixture
def arm(rig: Rig) -> Iterator[ServoClient]:
    """A client holding the lease (taken over from whatever an earlier test left) with a stream running."""
    with ServoClient(rig.base_url, TOKEN, name="client-test", take_over=True) as client:
        client.ensure_streaming()
        yield client
    assert rig.sim_alarms() == [], "the client caused a controller alarm"


# ------------------------------------------------------------------------------------ no server code
def test_the_client_imports_no_server_module() -> None:
    code = ("import sys, servo_app.client; "
            "print(sorted(m for m in sys.modules if m.startswith(('servo_app', 'fastapi', 'pydantic', 'numpy', "
            "'uvicorn', 'numba', 'mujoco'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    loaded = eval(out.stdout)  # a printed list of module names
    assert loaded and all(m == "servo_app" or m.startswith("servo_app.client") for m in loaded), loaded


# ------------------------------------------------------------------------------------------- frames
angles = st.floats(-180, 180, allow_nan=False)
offsets = st.floats(-500, 500, allow_nan=False)


@given(w=angles, p=angles, r=angles, dx=offsets, dy=offsets, dz=offsets)
def test_an_offset_in_the_tool_frame_is_the_rotation_of_the_offset(w: float, p: float, r: float, dx: float,
                                                                   dy: float, dz: float) -> None:
    pose = (100.0, -50.0, 300.0, w, p, r)
    moved = offset_in_tool(pose, dx, dy, dz)
    expected = np.array(pose[:3]) + wpr_to_rotation(w, p, r) @ np.array([dx, dy, dz])
    np.testing.assert_allclose(moved[:3], expected, atol=1e-9)
    assert moved[3:] == pose[3:]
    assert math.isclose(math.dist(moved[:3], pose[:3]), math.hypot(dx, dy, dz), abs_tol=1e-9)


# -------------------------------------------------------------------------------------------- lease
def test_the_lease_is_renewed_past_its_ttl_and_released_on_exit(rig: Rig) -> None:
    with ServoClient(rig.base_url, TOKEN, name="renewer", take_over=True, lease_ttl_s=0.6) as client:
        deadline = time.monotonic() + 10.0
        while client.lease_renewals < 5:  # five renewals at a third of the TTL: over two TTLs held
            assert time.monotonic() < deadline, "the lease was not renewed"
            time.sleep(0.05)
        lease = rig.http.get("/api/lease").json()
        assert lease["held"] and lease["client"] == "renewer"
        assert client.state().lease_holder == "renewer"
        client.ensure_streaming()
        client.move_joints(HOME)  # the lease still works for motion after several TTLs
    assert rig.http.get("/api/lease").json()["held"] is False


def test_a_second_client_is_refused_and_a_take_over_makes_the_first_lose_the_lease(rig: Rig) -> None:
    with ServoClient(rig.base_url, TOKEN, name="first", take_over=True, lease_ttl_s=0.6) as first:
        with pytest.raises(LeaseError, match="control is held by 'first'") as refused:
            ServoClient(rig.base_url, TOKEN, name="second").acquire()
        assert refused.value.status == 409
        with ServoClient(rig.base_url, TOKEN, name="second", take_over=True), \
                pytest.raises(LeaseError, match="lease"):
            first.move_joints(HOME)
        deadline = time.monotonic() + 5.0
        while first._lease_lost is None:  # the renewal thread finds the lease gone
            assert time.monotonic() < deadline, "the renewal did not notice the take-over"
            time.sleep(0.05)
        with pytest.raises(LeaseError, match="does not hold the control lease"):
            first.io_write("DO", 1, False)


def test_a_wrong_token_is_an_auth_error(rig: Rig) -> None:
    with pytest.raises(AuthError, match="bearer token") as err:
        ServoClient(rig.base_url, "not-the-token").acquire()
    assert err.value.status == 401


def test_motion_without_the_lease_says_how_to_get_it(rig: Rig) -> None:
    client = ServoClient(rig.base_url, TOKEN)
    try:
        with pytest.raises(LeaseError, match="context manager"):
            client.move_joints(HOME)
    finally:
        client.close()


# ------------------------------------------------------------------------------------------ session
def test_start_stop_resume_reset_end(arm: ServoClient) -> None:
    s = arm.stop()
    assert s is not None and s.state == "stopped" and s.stop_reason == "stop requested" and s.resumable
    assert arm.resume().state == "streaming"
    s = arm.stop(fast=True)
    assert s is not None and s.stop_fast
    with pytest.raises(RefusedError, match="reset") as refused:
        arm.resume()
    assert refused.value.status == 409 and refused.value.next_step and "POST /api/reset" in refused.value.next_step
    assert not arm.reset().stop_fast
    assert arm.resume().state == "streaming"
    assert arm.end().state == "ended"
    assert arm.start().state == "streaming"


# ------------------------------------------------------------------------------------------- motion
def test_move_joints_returns_once_the_arm_is_there(arm: ServoClient) -> None:
    arm.move_joints(HOME)
    goal = [20.0, 10.0, -5.0, 0.0, -80.0, 15.0]
    s = arm.move_joints(goal, speed_scale=0.8)
    assert s is not None and s.at_rest and s.state == "streaming"
    np.testing.assert_allclose(s.joints, goal, atol=1e-3)
    assert arm.move_joints(HOME, wait=False) is None
    s = arm.wait_settled()
    np.testing.assert_allclose(s.joints, HOME, atol=1e-3)
    np.testing.assert_allclose(s.joints_feedback, HOME, atol=0.05)


def test_move_pose_reaches_the_pose(arm: ServoClient) -> None:
    arm.move_joints(HOME)
    start = arm.wait_settled().pose
    assert start is not None
    goal = (start[0] + 40.0, start[1] - 30.0, start[2] + 20.0, *start[3:])
    arm.move_pose(goal, linear_speed=200.0)
    reached = arm.wait_settled().pose
    assert reached is not None and math.dist(reached[:3], goal[:3]) < 0.5, (reached, goal)


def test_a_stop_during_a_move_raises_stopped(arm: ServoClient, rig: Rig) -> None:
    arm.move_joints(HOME)

    def stop_once_moving() -> None:  # another client (or the pendant's operator) stops the arm mid-move
        rig.wait(lambda s: not s["at_rest"], 10.0, "moving")
        rig.http.post("/api/session/stop", headers={"Authorization": f"Bearer {TOKEN}"})

    stopper = threading.Thread(target=stop_once_moving)
    stopper.start()
    try:
        with pytest.raises(StoppedError, match="ended short") as stopped:
            arm.move_joints([60.0, 0.0, 0.0, 0.0, -90.0, 0.0], speed_scale=0.3)
    finally:
        stopper.join()
    assert stopped.value.reason == "stop requested"
    arm.resume()  # the interrupted target continues
    s = arm.wait_at_rest()
    np.testing.assert_allclose(s.joints, [60.0, 0.0, 0.0, 0.0, -90.0, 0.0], atol=1e-3)
    arm.move_joints(HOME)


def test_a_wait_that_runs_out_is_a_timeout_error(arm: ServoClient) -> None:
    arm.move_joints(HOME)
    arm.move_joints([40.0, 0.0, 0.0, 0.0, -90.0, 0.0], speed_scale=0.2, wait=False)
    with pytest.raises(TimeoutError, match="at rest") as err:
        arm.wait_at_rest(timeout=0.1)
    assert isinstance(err.value, ServoError) and isinstance(err.value, builtins.TimeoutError)
    arm.wait_at_rest()
    arm.move_joints(HOME)


def test_refusals_carry_the_field_and_the_next_step(arm: ServoClient) -> None:
    with pytest.raises(RefusedError, match="expected 6") as count:
        arm.move_joints([0.0] * 5)
    assert count.value.status == 422 and count.value.field == "joints"
    with pytest.raises(RefusedError, match="outside the joint range") as range_:
        arm.move_joints([500.0, 0, 0, 0, -90, 0])
    assert range_.value.field == "joints[0]"
    with pytest.raises(RefusedError) as schema:
        arm.move_joints(HOME, speed_scale=2.0)
    assert schema.value.status == 422 and schema.value.field == "body.speed_scale" and schema.value.errors
    with pytest.raises(RefusedError) as jog_schema:  # the union's member is not in the field either
        arm.jog(linear=(1.0, 2.0), duration=0.1)
    assert jog_schema.value.status == 422 and jog_schema.value.field == "body.linear", jog_schema.value.errors
    with pytest.raises(RefusedError, match="out of the LR Mate 200iD's reach"):
        arm.move_pose((10_000.0, 0, 0, 0, 0, 0))
    arm.end()
    with pytest.raises(RefusedError, match="target refused in ended") as ended:
        arm.move_joints(HOME)
    assert ended.value.status == 409 and ended.value.next_step == "start a new session: POST /api/session/start"


# -------------------------------------------------------------------------------------------- jogs
def test_a_jog_block_moves_the_arm_and_stops_it_at_its_end(arm: ServoClient) -> None:
    arm.move_joints(HOME)
    before = arm.wait_settled().pose
    assert before is not None
    with arm.jog(linear=(30.0, 0.0, 0.0)) as held:
        moving = arm._wait(lambda s: not s.at_rest, 5.0, "moving")
        deadline = time.monotonic() + 0.8
        while time.monotonic() < deadline:  # held far past the jog's 300 ms hold time
            s = arm.state()
            assert s.state == "streaming", (s.state, s.stop_reason)
            time.sleep(0.05)
        assert held.sent >= 3
        held.update(linear=(0.0, 20.0, 0.0))
        deadline = time.monotonic() + 5.0
        while (arm.state().pose or (0.0, 0.0))[1] < before[1] + 2.0:
            assert time.monotonic() < deadline, "the new velocity did not take"
            time.sleep(0.02)
    assert not moving.at_rest
    s = arm.state()
    assert s.at_rest, "the arm still moves after the block"
    later = arm.wait_settled()
    assert later.joints == arm.state().joints  # nothing moves on
    assert later.pose is not None and later.pose[0] > before[0] + 10.0  # it went along +X
    # A target after a jog needs no resume of the user's.
    arm.move_joints(HOME)


def test_a_jog_with_a_duration_returns_at_rest(arm: ServoClient) -> None:
    arm.move_joints(HOME)
    held = arm.jog_joints([0.0, 0.0, 0.0, 0.0, 0.0, 20.0], duration=1.0)
    s = arm.state()
    assert s.at_rest and held.sent >= 2
    # Renewed past the 300 ms hold time: about 20 deg/s for 1 s (one unrenewed jog would stop near 7 deg).
    assert s.joints is not None and 15.0 < s.joints[5] < 30.0, s.joints
    arm.jog(angular=(0.0, 0.0, -20.0), frame="tool", duration=0.3)
    arm.move_joints(HOME)


def test_a_jog_refused_at_once_raises_at_once(arm: ServoClient) -> None:
    arm.end()
    with pytest.raises(RefusedError, match="twist refused in ended") as err:
        arm.jog(linear=(10.0, 0.0, 0.0))
    assert err.value.next_step == "start a new session: POST /api/session/start"


def test_a_jog_refused_midway_ends_its_duration_early(arm: ServoClient, rig: Rig) -> None:
    arm.move_joints(HOME)

    def end_once_moving() -> None:
        rig.wait(lambda s: not s["at_rest"], 10.0, "moving")
        rig.post("/api/session/end", {"Authorization": f"Bearer {TOKEN}", "X-Lease-Id": str(arm.lease_id)})

    ender = threading.Thread(target=end_once_moving)
    ender.start()
    began = time.monotonic()
    try:
        with pytest.raises(RefusedError, match=r"jog refused in (stopping|ending|ended) \(stopped: end requested\)"):
            arm.jog_joints([0.0, 0.0, 0.0, 0.0, 0.0, 10.0], duration=30.0)
    finally:
        ender.join()
    assert time.monotonic() - began < 10.0
    arm.wait_state("ended")


# ------------------------------------------------------------------------------------ I/O, telemetry
def test_io_write_and_read(arm: ServoClient) -> None:
    arm.io_write("DO", 5, True)
    assert arm.io_read("DO", 5) is True
    assert arm.io_read16("DO", 5) & 1 == 1
    arm.io_write("DO", 5, False)
    assert arm.io_read("DO", 5) is False
    with pytest.raises(RefusedError, match="not an I/O type allowed") as err:
        arm.io_read("XX", 1)
    assert err.value.field == "type"


def test_the_last_points_of_a_type_are_read_and_written_one_by_one(arm: ServoClient) -> None:
    """DO 498..512: an access covers 16 points, so these are reached from index 497 (before: 422,
    "index=510: ... must be in 1..497", for points GET /api/limits lists as allowed)."""
    arm.io_write("DO", 510, True)
    assert arm.io_read("DO", 510) is True
    assert arm.io_read("DO", 509) is False and arm.io_read("DO", 512) is False
    assert arm.io_read16("DO", 497) == 1 << (510 - 497)
    arm.io_write("DO", 510, False)
    assert arm.io_read("DO", 510) is False
    with pytest.raises(RefusedError, match="index=513") as err:  # past the last point: refused as before
        arm.io_read("DO", 513)
    assert err.value.field == "index"


def test_telemetry_iterates_states(arm: ServoClient) -> None:
    seen: list[State] = []
    for s in arm.telemetry(hz=50):
        seen.append(s)
        if len(seen) == 10:
            break
    times = [s.published_unix for s in seen]
    assert all(s.state == "streaming" and s.lease_holder == "client-test" for s in seen)
    assert all(t is not None for t in times) and times == sorted(times) and times[0] < times[-1]
    with pytest.raises(RefusedError, match=r"outside 1\.\.100"):
        next(iter(arm.telemetry(hz=0.5)))


# -------------------------------------------------------------------------------------------- fault
def test_a_controller_alarm_is_a_fault_error_with_its_code_cause_and_remedy(tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig, ServoClient(rig.base_url, TOKEN, take_over=True) as arm:
        arm.start()
        arm.move_joints([50.0, 0.0, 0.0, 0.0, -90.0, 0.0], speed_scale=0.3, wait=False)
        rig.service.sim_call("set_override", 50)  # at the pendant, mid-stream: MOTN-606
        with pytest.raises(FaultError) as during:
            arm.wait_at_rest()
        assert during.value.code == "MOTN-606" and during.value.cause and during.value.remedy
        with pytest.raises(FaultError) as refused:  # a request refused in the fault: the same fault
            arm.move_joints(HOME)
        assert refused.value.code == "MOTN-606" and refused.value.status == 409
        rig.service.sim_call("set_override", 100)
        assert arm.reset().state != "fault"
        arm.start()
        arm.move_joints(HOME)
        assert arm.state().alarms == ()


def test_teach_without_a_stream_is_refused_at_once_saying_to_start_one(tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig, ServoClient(rig.base_url, TOKEN, name="teacher") as arm:
        assert arm.state().state == "disconnected"
        t0 = time.monotonic()
        # It waited for a settled arm that no stream reports, then raised TimeoutError ('settled: not within').
        with pytest.raises(RefusedError, match="start one: POST /api/session/start") as refused:
            arm.teach("nowhere", settle_timeout=10.0)
        assert time.monotonic() - t0 < 5.0 and refused.value.status == 409
        assert arm.points() == []
        # wait_settled likewise: it waited out its whole timeout for what no stream reports.
        t0 = time.monotonic()
        with pytest.raises(RefusedError, match=r"settled: no stream runs \(state disconnected\).*start one"):
            arm.wait_settled(timeout=10.0)
        assert time.monotonic() - t0 < 5.0
        # A second acquire while the lease is held keeps the one renewal thread (two outlived release()).
        renewer = arm._lease_thread
        arm.acquire()
        assert arm._lease_thread is renewer and renewer is not None and renewer.is_alive()
        arm.release()
        assert not renewer.is_alive() and arm.lease_id is None


def test_the_blocks_own_error_is_raised_when_the_release_fails_too(tmp_path: Path) -> None:
    """A script's block raises after the service went away: its error comes out, not the release's
    "cannot reach the service" (which used to replace it)."""
    service = running_rig(tmp_path)
    rig = service.__enter__()
    try:
        with pytest.raises(ValueError, match="the script's own error"), \
                ServoClient(rig.base_url, TOKEN, name="script") as arm:
            assert arm.lease_id is not None
            service.__exit__(None, None, None)  # the service (its uvicorn too) goes away mid-script
            raise ValueError("the script's own error")
    finally:
        service.__exit__(None, None, None)  # (a second exit: nothing left to stop)
