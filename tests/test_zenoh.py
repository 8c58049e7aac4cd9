"""The Zenoh interface with real Zenoh sessions on loopback (peer mode, no router, no multicast):
ROS 2 messages in CDR keyed as rmw_zenoh names them, commands through the REST rules, the lease by
queryable, and two services in two processes seen by the fleet monitor."""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import zenoh  # a test dependency (pyproject's test extra): missing, the tests must fail, not skip
from hypothesis import given
from hypothesis import strategies as st
from test_api_harness import AUTH, STOP_WAYS, TOKEN, Rig, running_rig, servo_app_argv

from servo_app.monitor import FleetMonitor
from servo_app.ros import messages as ros
from servo_app.zenoh_api import (
    ROS_UNITS,
    Said,
    ZenohInterface,
    ZenohSettings,
    parse_rmw_attachment,
    refusal_as_sent,
    rmw_attachment,
    ros_key,
)

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def client_session(*connect: str) -> Any:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def wait_for(pred: Callable[[], Any], timeout: float = 10.0, what: str = "") -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what or pred}")
        time.sleep(0.01)


class Client:
    """A Zenoh peer of the cell: the lease query, command publishers, the replies it collects."""

    def __init__(self, session: Any, cell: str) -> None:
        self.session, self.cell = session, cell
        self.replies: list[dict[str, Any]] = []
        self._subs = [session.declare_subscriber(f"servo_app/{cell}/reply", self._on_reply)]
        self._pubs: dict[str, Any] = {}

    def _on_reply(self, sample: Any) -> None:
        self.replies.append(json.loads(sample.payload.to_bytes()))

    def lease(self, **body: Any) -> dict[str, Any]:
        payload = {"token": TOKEN, "client": "ros-node", "force": True, **body}

        def ask() -> list[Any]:  # none until the queryable's declaration has reached this session
            return [r for r in self.session.get(f"servo_app/{self.cell}/lease", payload=json.dumps(payload).encode(),
                                                timeout=5.0) if r.ok is not None]

        replies = wait_for(ask, 20.0, "the lease queryable's answer")
        return json.loads(replies[0].ok.payload.to_bytes())  # type: ignore[no-any-return]

    def pub_put(self, topic: str, typename: str, message: Any) -> None:
        """Publish a ROS command."""
        key = ros_key(0, f"/{self.cell}/{topic}", typename)
        if key not in self._pubs:
            self._pubs[key] = self.session.declare_publisher(key)
        self._pubs[key].put(ros.serialize(message, typename))

    def send(self, topic: str, typename: str, message: Any) -> dict[str, Any]:
        """Publish a ROS command and wait for its answer on the reply key."""
        n = len(self.replies)
        self.pub_put(topic, typename, message)
        return wait_for(lambda: self.replies[n] if len(self.replies) > n else None, 10.0, f"a reply to {topic}")

    def send_json(self, kind: str, body: dict[str, Any]) -> dict[str, Any]:
        n = len(self.replies)
        self.session.put(f"servo_app/{self.cell}/json/cmd/{kind}", json.dumps(body).encode())
        return wait_for(lambda: self.replies[n] if len(self.replies) > n else None, 10.0, f"a reply to {kind}")


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Rig, ZenohInterface, Client]]:
    port = free_port()
    with running_rig(tmp_path_factory.mktemp("zenoh")) as rig:
        api = rig.server.server.config.app.state.api
        iface = ZenohInterface(api, ZenohSettings(cell="cell_a", listen=[f"tcp/127.0.0.1:{port}"],
                                                  json=True)).start()
        session = client_session(f"tcp/127.0.0.1:{port}")
        try:
            yield rig, iface, Client(session, "cell_a")
        finally:
            session.close()
            iface.close()
            assert rig.sim_alarms() == [], "the controller alarmed"


def send_fresh(client: Client, topic: str, typename: str, message_at: Callable[[int], Any], tries: int = 5
               ) -> dict[str, Any]:
    """A hold-to-run command stamped now (``message_at(time.time_ns())``), sent again freshly stamped while
    it is refused as stale, as a teleoperation node sends a new one every cycle anyway. Stale means it
    was handled over its 0.2 s hold after its stamp: the service shares this process, and a full garbage
    collection of the whole suite's heap took up to 0.6 s here. Any other refusal is returned at once."""
    for _ in range(tries):
        r = client.send(topic, typename, message_at(time.time_ns()))
        if r["ok"] or r["status"] != 409 or not str(r["detail"]).startswith("stale hold-to-run"):
            break
    return r


def streaming_for_zenoh(rig: Rig, client: Client) -> str:
    """A running stream, the lease taken through the queryable (it stops the arm: resume over Zenoh)."""
    rig.streaming()
    granted = client.lease()
    assert granted["ok"], json.dumps(granted)  # (a dict message is cut short: the whole reply)
    assert client.send("resume", ros.EMPTY, ros.Empty())["ok"]
    rig.wait_state("streaming")
    return str(granted["lease_id"])


# ------------------------------------------------------------------------------------- the key space

def test_keys_follow_rmw_zenoh_jazzy() -> None:
    key = ros_key(0, "/cell_a/joint_states", ros.JOINT_STATE)
    assert key == ("0/cell_a/joint_states/sensor_msgs::msg::dds_::JointState_/"
                   "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e")
    # control_msgs/JointJog is registered from its .msg text: its hash is computed like any other
    assert ros_key(3, "/c/delta_joint_cmds", ros.JOINT_JOG).startswith("3/c/delta_joint_cmds/"
                                                                        "control_msgs::msg::dds_::JointJog_/RIHS01_")


@given(st.integers(1, 2**63 - 1), st.integers(0, 2**63 - 1), st.binary(min_size=16, max_size=16))
def test_attachment_is_zenoh_ext_serialisation(seq: int, t_ns: int, gid: bytes) -> None:
    """rmw_zenoh reads the attachment with zenoh-ext's deserializer: int64, int64, a 16-byte sequence."""
    from zenoh import ext

    oracle = ext.z_serialize((ext.Int64(seq), ext.Int64(t_ns), [ext.UInt8(b) for b in gid])).to_bytes()
    assert rmw_attachment(seq, t_ns, gid) == oracle
    assert parse_rmw_attachment(oracle) == (seq, t_ns, gid)


@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(-3, 3), st.floats(-3, 3), st.floats(-3, 3))
def test_twist_and_jog_round_trip_in_cdr(x: float, y: float, z: float, a: float, b: float, c: float) -> None:
    m = ros.deserialize(ros.serialize(ros.twist_stamped(123, (x, y, z), (a, b, c), "tool0"), ros.TWIST_STAMPED),
                        ros.TWIST_STAMPED)
    assert (m.twist.linear.x, m.twist.linear.y, m.twist.linear.z) == (x, y, z)
    assert (m.twist.angular.x, m.twist.angular.y, m.twist.angular.z) == (a, b, c)
    assert m.header.frame_id == "tool0" and ros.stamp_ns(m.header) == 123
    j = ros.deserialize(ros.serialize(ros.joint_jog(5, ["joint_2"], [x], 0.5), ros.JOINT_JOG), ros.JOINT_JOG)
    assert list(j.joint_names) == ["joint_2"] and j.velocities.tolist() == [x] and j.duration == 0.5


@given(st.floats(-1e5, 1e5), st.floats(-1e5, 1e5), st.sampled_from(sorted(ROS_UNITS)))
def test_a_refusals_limits_are_also_in_the_senders_units(x: float, lo: float, unit: str) -> None:
    """A REST refusal of a ROS command: after the field as sent, REST's words with each limit also in
    the sender's unit (a value with its unit, a range in the field's unit); the echo of the converted
    value (``joints[0]=...``) is left as REST wrote it (the field as sent comes first)."""
    ros_unit, factor = ROS_UNITS[unit]
    said = {"joints": Said("position = [...] rad", ("position[0] (joint_1) = 1 rad (joints[0] = 57.3 deg)",),
                            (unit,))}
    at_most = f"{abs(x):g}"
    out = refusal_as_sent("joint_target", said, f"joints[0]={x!r} {unit} is outside [{lo!r}, {abs(lo)!r}]; "
                                                f"send at most {at_most} {unit}")
    assert out.startswith(f"joint_target: position[0] (joint_1) = 1 rad (joints[0] = 57.3 deg): joints[0]={x!r} "
                          f"{unit} is outside"), out
    assert f"[{lo!r}, {abs(lo)!r}] ({lo * factor:.4g} to {abs(lo) * factor:.4g} {ros_unit})" in out, out
    assert out.endswith(f"send at most {at_most} {unit} ({float(at_most) * factor:.4g} {ros_unit})"), out


# ------------------------------------------------------------------------------- telemetry and commands

@pytest.mark.e2e
def test_joint_states_arrive_at_the_rate_and_decode_as_ros2(cell: tuple[Rig, ZenohInterface, Client]) -> None:
    rig, iface, client = cell
    rig.streaming()
    got: list[tuple[float, bytes, bytes]] = []
    sub = client.session.declare_subscriber(ros_key(0, "/cell_a/joint_states", ros.JOINT_STATE),
                                            lambda s: got.append((time.monotonic(), s.payload.to_bytes(),
                                                                  s.attachment.to_bytes())))
    try:
        wait_for(lambda: len(got) >= 60, 10.0, "60 joint states")
    finally:
        sub.undeclare()
    times = np.array([t for t, _, _ in got[10:]])
    rate = (len(times) - 1) / (times[-1] - times[0])
    assert 0.7 * iface.settings.hz < rate < 1.3 * iface.settings.hz, rate
    seqs = [parse_rmw_attachment(a) for _, _, a in got]
    assert all(s is not None for s in seqs)
    assert np.all(np.diff([s[0] for s in seqs if s]) == 1), "the publisher's sequence numbers have gaps"
    m = ros.deserialize(got[-1][1], ros.JOINT_STATE)
    assert list(m.name) == ros.joint_names(6)
    q = rig.state()["q_servo"]
    np.testing.assert_allclose(m.position, iface.joints_to_ros(q[:6]), atol=1e-3)


@pytest.mark.e2e
def test_ros_commands_move_the_arm(cell: tuple[Rig, ZenohInterface, Client]) -> None:
    rig, iface, client = cell
    streaming_for_zenoh(rig, client)
    q0 = rig.state()["q_cmd"]
    # delta_joint_cmds, held by repeating it (hold-to-run, as MoveIt Servo publishes)
    for _ in range(10):
        r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG, lambda t: ros.joint_jog(t, ["joint_1"], [0.3]))
        assert r["ok"], json.dumps(r)
    s = rig.wait(lambda s: s["q_cmd"][0] > q0[0] + 0.5, 5.0, "J1 moved")
    assert abs(s["q_cmd"][3] - q0[3]) < 1e-6, "an axis not commanded moved"
    # delta_twist_cmds: +z in the base frame
    z0 = rig.state()["cart_servo"][2]
    for _ in range(10):
        r = send_fresh(client, "delta_twist_cmds", ros.TWIST_STAMPED,
                       lambda t: ros.twist_stamped(t, (0, 0, 0.05), (0, 0, 0)))
        assert r["ok"], json.dumps(r)
    rig.wait(lambda s: s["cart_servo"][2] > z0 + 2.0, 5.0, "the TCP rose")
    # joint_target (rad, the model's chain): J1 to 5 deg
    goal = iface.joints_to_ros([5.0, *rig.state()["q_cmd"][1:6]])
    r = client.send("joint_target", ros.JOINT_STATE, ros.joint_state(0, goal))
    assert r["ok"], json.dumps(r)
    rig.wait(lambda s: abs(s["q_cmd"][0] - 5.0) < 0.01 and s["at_rest"], 10.0, "at the joint target")
    # pose_target (m): 20 mm lower than here
    c = rig.state()["cart_servo"]
    from servo_app.robots.conventions import xyzwpr_to_matrix

    goal_pose = xyzwpr_to_matrix([c[0], c[1], c[2] - 20.0, *c[3:6]])  # in metres
    r = client.send("pose_target", ros.POSE_STAMPED, ros.pose_stamped(0, goal_pose))
    assert r["ok"], r["detail"]
    rig.wait(lambda s: abs(s["cart_servo"][2] - (c[2] - 20.0)) < 0.5 and s["at_rest"], 10.0, "at the pose target")
    # stop, then resume
    assert client.send("stop", ros.EMPTY, ros.Empty())["ok"]
    rig.wait_state("stopped")
    assert client.send("resume", ros.EMPTY, ros.Empty())["ok"]
    rig.wait_state("streaming")
    assert rig.sim_alarms() == []


@pytest.mark.e2e
def test_json_commands_carry_the_token_and_lease(cell: tuple[Rig, ZenohInterface, Client]) -> None:
    rig, _, client = cell
    lease_id = streaming_for_zenoh(rig, client)
    q0 = rig.state()["q_cmd"]
    for _ in range(6):
        r = client.send_json("jog", {"token": TOKEN, "lease_id": lease_id, "joints": [0, 0, 0, 0, 0, 20],
                                     "hold_ms": 300})
        assert r["ok"], json.dumps(r)
    rig.wait(lambda s: s["q_cmd"][5] > q0[5] + 0.5, 5.0, "J6 moved")
    r = client.send_json("jog", {"lease_id": lease_id, "joints": [0, 0, 0, 0, 0, 20]})
    assert (r["status"], r["detail"]) == (401, "missing or wrong bearer token")


@pytest.mark.e2e
def test_every_refusal_is_answered_with_the_rest_message(cell: tuple[Rig, ZenohInterface, Client]) -> None:
    rig, _, client = cell
    lease_id = streaming_for_zenoh(rig, client)
    jog = ros.joint_jog(0, ["joint_1"], [0.1])
    # bad values: the REST model's error, word for word (a hold of 5 s is over its 2 s bound)
    rest = rig.http.post("/api/jog", json={"joints": [5.7, 0, 0, 0, 0, 0], "hold_ms": 5000},
                         headers={**AUTH, "X-Lease-Id": lease_id})
    assert rest.status_code == 422
    # (named as the ROS sender gave it: duration in s; test_a_joint_jog_refusal_names_the_velocities_...)
    r = client.send("delta_joint_cmds", ros.JOINT_JOG, ros.joint_jog(0, ["joint_1"], [0.1], duration_s=5.0))
    assert r["status"] == 422 and rest.json()["detail"][0]["msg"] in r["detail"], r
    r = client.send("delta_twist_cmds", ros.TWIST_STAMPED, ros.twist_stamped(0, (0, 0, 0), (0, 0, 0), "camera"))
    assert r["status"] == 422 and "base" in r["detail"], r
    r = client.send("delta_joint_cmds", ros.JOINT_JOG, ros.joint_jog(0, ["joint_9"], [0.1]))
    assert r["status"] == 422 and "unknown joint 'joint_9'" in r["detail"], r
    # stale hold-to-run: stamped a second ago, past its 0.2 s hold
    r = client.send("delta_joint_cmds", ros.JOINT_JOG, ros.joint_jog(time.time_ns() - 1_000_000_000, ["joint_1"],
                                                                     [0.1]))
    assert r["status"] == 409 and r["detail"].startswith("stale hold-to-run command"), r
    # wrong state: stopped (soft); a target is refused in REST's words
    rig.post("/api/session/stop", AUTH)
    rig.wait_state("stopped")
    rest = rig.http.post("/api/target", json={"joints": [1, 0, 0, 0, -90, 0]},
                         headers={**AUTH, "X-Lease-Id": lease_id})
    r = client.send("joint_target", ros.JOINT_STATE, ros.joint_state(0, np.radians([1, 0, 0, 0, -90, 0])))
    assert rest.status_code == r["status"] == 409 and r["detail"] == rest.json()["detail"], (r, rest.text)
    # a lease taken over through REST: ROS commands no longer act for the Zenoh holder
    rig.lease("operator")
    rest = rig.http.post("/api/jog", json={"joints": [1, 0, 0, 0, 0, 0]}, headers={**AUTH, "X-Lease-Id": lease_id})
    r = client.send("delta_joint_cmds", ros.JOINT_JOG, jog)
    assert rest.status_code == r["status"] == 409 and r["detail"] == rest.json()["detail"], (r, rest.text)
    # no lease at all
    held = rig.lease("operator")
    rig.http.delete("/api/lease", headers=held)
    rest = rig.http.post("/api/jog", json={"joints": [1, 0, 0, 0, 0, 0]}, headers={**AUTH, "X-Lease-Id": lease_id})
    r = client.send("delta_joint_cmds", ros.JOINT_JOG, jog)
    assert rest.status_code == r["status"] == 409 and r["detail"] == rest.json()["detail"], (r, rest.text)
    # the lease queryable: a wrong token, a live lease without force (REST's 409 text)
    assert client.lease(token="wrong") == {"ok": False, "status": 401, "detail": "missing or wrong bearer token"}
    assert client.lease()["ok"]
    rest = rig.http.post("/api/lease", json={"client": "other"}, headers=AUTH)
    refused = client.lease(client="other", force=False)
    assert rest.status_code == refused["status"] == 409
    assert refused["detail"].split(" for ")[0] == rest.json()["detail"].split(" for ")[0]
    assert rig.sim_alarms() == []


# ------------------------------------------------------------------------ two cells in two processes

@contextlib.contextmanager
def service_process(tmp: Path, cell: str, zenoh_port: int) -> Iterator[tuple[subprocess.Popen[str], int]]:
    http_port = free_port()
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "servo_app.cli", "run", "--zenoh", "--cell", cell, "--zenoh-listen",
         f"tcp/127.0.0.1:{zenoh_port}", "--http-port", str(http_port), "--token", TOKEN, "--var-dir",
         str(tmp / cell), "--api-priority", "0"], env=env, cwd=tmp, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout or []), daemon=True)
    reader.start()
    try:
        yield proc, http_port
    finally:
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        reader.join(5)
        assert any("controller alarms []" in line for line in lines), "".join(lines)


@pytest.mark.e2e
@pytest.mark.slow
def test_two_services_in_two_processes_one_monitor(tmp_path: Path) -> None:
    ports = {"cell_a": free_port(), "cell_b": free_port()}
    endpoints = [f"tcp/127.0.0.1:{p}" for p in ports.values()]
    with service_process(tmp_path, "cell_a", ports["cell_a"]) as (_, http_a), \
            service_process(tmp_path, "cell_b", ports["cell_b"]) as (_, http_b):
        monitor = FleetMonitor(ZenohSettings(cell="monitor", connect=endpoints)).start()
        session = client_session(*endpoints)
        try:
            cells = wait_for(lambda: (c := monitor.cells()).keys() >= {"cell_a", "cell_b"} and c, 90.0,
                             "both cells on the monitor")
            assert all(not c["stale"] and c["alarms"] == [] for c in cells.values()), cells
            lines = monitor.lines()
            assert any(line.startswith("cell_a") for line in lines) and any(line.startswith("cell_b") for line in lines)
            client = Client(session, "cell_a")
            lease_id = client.lease()["lease_id"]
            # The lease from the queryable is a REST lease too: start cell a's stream with it.
            http = httpx.Client(base_url=f"http://127.0.0.1:{http_a}", timeout=10.0)
            assert http.post("/api/session/start", headers={**AUTH, "X-Lease-Id": lease_id}).status_code == 200
            wait_for(lambda: monitor.cells()["cell_a"]["state"] == "streaming", 15.0, "cell a streaming")
            assert monitor.cells()["cell_a"]["lease_held"] and not monitor.cells()["cell_b"]["lease_held"]
            a0, b0 = monitor.cells()["cell_a"]["q_cmd"], monitor.cells()["cell_b"]["q_cmd"]
            for _ in range(10):
                r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG,
                               lambda t: ros.joint_jog(t, ["joint_1"], [0.3]))
                assert r["ok"], json.dumps(r)
            wait_for(lambda: monitor.cells()["cell_a"]["q_cmd"][0] > a0[0] + 0.5, 10.0, "cell a moved")
            assert monitor.cells()["cell_b"]["q_cmd"] == b0, "cell b moved on a command to cell a"
            assert math.isfinite(monitor.cells()["cell_a"]["latency_p99_us"])
            http.close()
            assert httpx.get(f"http://127.0.0.1:{http_b}/api/health").json() == {"ok": True}
        finally:
            session.close()
            monitor.close()


@pytest.mark.e2e
@pytest.mark.parametrize(("how", "sig"), STOP_WAYS, ids=[how for how, _ in STOP_WAYS])
def test_the_monitor_command_serves_the_cells_until_stopped(cell: tuple[Rig, ZenohInterface, Client], how: str,
                                                            sig: int) -> None:
    _, iface, _ = cell
    http_port = free_port()
    proc = subprocess.Popen(servo_app_argv(how, "monitor", "--connect", iface.settings.listen[0], "--http-port",
                                           str(http_port)), cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert f"http://127.0.0.1:{http_port}/" in (proc.stdout.readline() if proc.stdout else "")

        def page() -> str:
            with contextlib.suppress(httpx.HTTPError):
                text = httpx.get(f"http://127.0.0.1:{http_port}/", timeout=5.0).text
                return text if "cell_a" in text else ""
            return ""

        wait_for(page, 60.0, "cell_a on the monitor's page")
        proc.send_signal(sig)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    _, err = proc.communicate()
    assert proc.returncode == 0, err


@pytest.mark.e2e
def test_a_stop_goes_ahead_of_a_flood_of_jogs_and_the_backlog_does_not_move_the_arm(
        cell: tuple[Rig, ZenohInterface, Client], caplog: pytest.LogCaptureFixture) -> None:
    """A node publishing unstamped jogs far faster than they are handled fills the command queue. A
    stop published then is handled next (it was dropped for the full queue, or waited behind every
    jog), and a jog that waited in the queue past its hold is refused as stale (the backlog kept the
    arm moving for a second after its sender had stopped)."""
    rig, iface, client = cell
    streaming_for_zenoh(rig, client)
    jogs = client.session.declare_publisher(ros_key(0, "/cell_a/delta_joint_cmds", ros.JOINT_JOG))
    stop = client.session.declare_publisher(ros_key(0, "/cell_a/stop", ros.EMPTY),
                                            congestion_control=zenoh.CongestionControl.BLOCK)
    n = len(client.replies)
    jog = ros.serialize(ros.joint_jog(0, ["joint_1"], [0.1], duration_s=0.05), ros.JOINT_JOG)
    for _ in range(3000):
        jogs.put(jog)
    stop.put(ros.serialize(ros.Empty(), ros.EMPTY))
    i = n + wait_for(lambda: next((k for k, r in enumerate(client.replies[n:]) if r["command"] == "stop"), None),
                     10.0, "the stop's reply")
    assert client.replies[i]["ok"], client.replies[i]
    # the end of the backlog: a command queued after it is answered after it
    unmatched = ros.JointState(header=ros.header(0, ""), name=["joint_1", "joint_2"], position=np.zeros(1),
                               velocity=np.zeros(0), effort=np.zeros(0))
    client.pub_put("joint_target", ros.JOINT_STATE, unmatched)
    end = i + wait_for(lambda: next((k for k, r in enumerate(client.replies[i:]) if r["command"] == "joint_target"),
                                    None), 20.0, "the backlog's end")
    assert client.replies[end]["status"] == 422
    assert any(r["command"] == "joint_jog" for r in client.replies[i + 1:end]), "the stop waited for every jog"
    assert any(str(r["detail"]).startswith("stale hold-to-run command: received") for r in client.replies[n:end])
    rig.wait_state("stopped")
    jogs.undeclare()
    stop.undeclare()
    # The jogs the full queue dropped are counted and logged at most once a second (a line each before).
    lines = [r for r in caplog.records if "command queue full" in r.getMessage()]
    assert len(lines) <= min(max(1, iface.dropped), 10), (len(lines), iface.dropped)


@pytest.mark.e2e
def test_a_joint_target_naming_some_joints_is_refused_and_moves_nothing(
        cell: tuple[Rig, ZenohInterface, Client]) -> None:
    """A JointState naming joint_1 and joint_5 only: the joints it leaves out were sent to 0 (J4 swung
    from 10 deg to 0); now it is refused, naming them, and the arm stays where it is."""
    rig, iface, client = cell
    lease_id = streaming_for_zenoh(rig, client)
    rig.post("/api/target", {**AUTH, "X-Lease-Id": lease_id}, json={"joints": [0, 0, 0, 10, -90, 0]})
    s0 = rig.wait(lambda s: abs(s["q_cmd"][3] - 10.0) < 0.01 and s["at_rest"], 10.0, "J4 at 10 deg")
    goal = iface.joints_to_ros(s0["q_cmd"][:6])
    partial = ros.JointState(header=ros.header(0, ""), name=["joint_1", "joint_5"],
                             position=np.array([goal[0] + 0.05, goal[4]]), velocity=np.zeros(0), effort=np.zeros(0))
    r = client.send("joint_target", ros.JOINT_STATE, partial)
    assert r["status"] == 422 and "['joint_2', 'joint_3', 'joint_4', 'joint_6']" in r["detail"], r
    s = rig.state()
    assert s["q_cmd"] == s0["q_cmd"] and s["state"] == s0["state"] == "streaming"
    # the same joints all named, in another order, are a target
    full = ros.JointState(header=ros.header(0, ""), name=[f"joint_{i}" for i in (6, 5, 4, 3, 2, 1)],
                          position=goal[::-1].copy(), velocity=np.zeros(0), effort=np.zeros(0))
    assert client.send("joint_target", ros.JOINT_STATE, full)["ok"]


@pytest.mark.e2e
def test_a_pose_target_in_another_frame_than_the_world_is_refused(cell: tuple[Rig, ZenohInterface, Client]) -> None:
    """A PoseStamped 10 mm along the tool's z (frame_id tool0) was taken as the world pose (0, 0, 10 mm)
    and the arm went there; now a frame other than the world's is refused and the arm stays."""
    rig, _, client = cell
    streaming_for_zenoh(rig, client)
    s0 = rig.wait_at_rest_settled()
    in_tool = ros.PoseStamped(header=ros.header(0, "tool0"), pose=ros.Pose(
        position=ros.Point(x=0.0, y=0.0, z=0.01), orientation=ros.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)))
    r = client.send("pose_target", ros.POSE_STAMPED, in_tool)
    assert r["status"] == 422 and "frame_id 'tool0'" in r["detail"] and "'base_link'" in r["detail"], r
    s = rig.state()
    assert s["q_cmd"] == s0["q_cmd"] and s["state"] == "streaming" and s["at_rest"]
    # the pose the cell publishes (frame "base") is a target as it is
    from servo_app.robots.conventions import xyzwpr_to_matrix

    here = ros.pose_stamped(0, xyzwpr_to_matrix(s0["cart_servo"][:6]))
    assert here.header.frame_id == "base"
    assert client.send("pose_target", ros.POSE_STAMPED, here)["ok"]



@pytest.mark.e2e
def test_a_joint_jog_with_a_nan_duration_is_refused_naming_it(cell: tuple[Rig, ZenohInterface, Client]) -> None:
    """NaN > 0 is false: a JointJog whose duration was NaN moved the arm with the default hold."""
    rig, _, client = cell
    streaming_for_zenoh(rig, client)
    s0 = rig.wait_at_rest_settled()
    r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG,
                   lambda t: ros.joint_jog(t, ["joint_1"], [0.1], duration_s=math.nan))
    assert r["status"] == 422 and "duration=nan" in r["detail"], r
    # A negative duration (taken as the default hold) and a joint named twice (the last value won).
    r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG,
                   lambda t: ros.joint_jog(t, ["joint_1"], [0.1], duration_s=-1.0))
    assert r["status"] == 422 and "duration=-1.0 is not a hold time" in r["detail"], r
    r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG,
                   lambda t: ros.joint_jog(t, ["joint_1", "joint_1"], [0.0, 0.1]))
    assert r["status"] == 422 and "['joint_1'] named more than once" in r["detail"], r
    s = rig.state()
    assert s["q_cmd"] == s0["q_cmd"] and s["at_rest"] and s["state"] == "streaming"


def ros_number(detail: str, pattern: str) -> tuple[float, float]:
    """The two numbers of ``pattern``'s groups in ``detail`` (a service-unit limit and its ROS value)."""
    import re

    m = re.search(pattern, detail)
    assert m is not None, (pattern, detail)
    return float(m.group(1)), float(m.group(2))


@pytest.mark.e2e
def test_a_twist_refusal_names_the_ros_fields_as_sent(cell: tuple[Rig, ZenohInterface, Client]) -> None:
    """A TwistStamped over the flange-speed cap (3, 3, 0) m/s was refused naming "linear=[3000.0, 3000.0,
    0.0]: 4242.6 mm/s", values the ROS sender never sent, in units it does not use; now the refusal
    names twist.linear as sent, in m/s, and the cap in m/s too. So do a component over its bound,
    a turn too fast, NaN, and a frame that is no frame (header.frame_id). Nothing moves."""
    rig, _, client = cell
    streaming_for_zenoh(rig, client)
    s0 = rig.wait_at_rest_settled()

    def refused(linear: tuple[float, ...], angular: tuple[float, ...], frame: str = "base_link") -> str:
        r = send_fresh(client, "delta_twist_cmds", ros.TWIST_STAMPED,
                       lambda t: ros.twist_stamped(t, linear, angular, frame))
        assert r["status"] == 422 and isinstance(r["detail"], str), r
        assert r["detail"].startswith("delta_twist_cmds: "), r
        return str(r["detail"])

    d = refused((3.0, 3.0, 0.0), (0.0, 0.0, 0.0))
    assert "twist.linear = (3, 3, 0) m/s (linear = [3000, 3000, 0] mm/s)" in d, d
    cap_mm_s, cap_m_s = ros_number(d, r"send at most (\d+) mm/s \(([\d.]+) m/s\)")
    assert cap_m_s == pytest.approx(cap_mm_s / 1000.0) and cap_m_s < math.hypot(3.0, 3.0), d
    d = refused((5.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert "twist.linear.x = 5 m/s (linear[0] = 5000 mm/s)" in d, d
    lo, hi = ros_number(d, r"\[-4000.0, 4000.0\] \((-?[\d.]+) to ([\d.]+) m/s\)")
    assert (lo, hi) == (-4.0, 4.0), d
    d = refused((0.0, 0.0, 0.0), (0.0, 0.0, -30.0))
    assert "twist.angular.z = -30 rad/s (angular[2] = -1718.87 deg/s)" in d, d
    assert "[-1000.0, 1000.0] (-17.45 to 17.45 rad/s)" in d, d
    d = refused((0.0, math.nan, 0.0), (0.0, 0.0, 0.0))
    assert "twist.linear.y = nan m/s" in d and "is not a finite number" in d, d
    d = refused((0.01, 0.0, 0.0), (0.0, 0.0, 0.0), frame="camera")
    assert "header.frame_id = 'camera'" in d and "'base' or 'tool'" in d, d
    s = rig.state()
    assert s["q_cmd"] == s0["q_cmd"] and s["at_rest"] and s["state"] == "streaming"


@pytest.mark.e2e
def test_a_joint_jog_refusal_names_the_velocities_as_sent_with_the_j2_j3_coupling(
        cell: tuple[Rig, ZenohInterface, Client]) -> None:
    """joint_3 at 4 rad/s (229 deg/s, within J3's limit) with joint_2 at -6 rad/s is J3 at 573 deg/s in
    FANUC's convention (J3 from the horizontal: joint_3 - joint_2), over J3's limit: the refusal named
    "joints[2]=572.958 deg/s", a value the sender never sent. Now it names velocities[1] (joint_3) and
    velocities[0] (joint_2) as sent, says how they make J3, and gives the limit in rad/s."""
    rig, iface, client = cell
    assert iface.j23 == 1.0  # the LR Mate's coupling: J3 = joint_3 - joint_2
    streaming_for_zenoh(rig, client)
    s0 = rig.wait_at_rest_settled()
    r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG,
                   lambda t: ros.joint_jog(t, ["joint_2", "joint_3"], [-6.0, 4.0]))
    d = r["detail"]
    assert r["status"] == 422 and isinstance(d, str) and d.startswith("delta_joint_cmds: "), r
    assert "velocities[1] (joint_3) = 4 rad/s with velocities[0] (joint_2) = -6 rad/s" in d, d
    assert "J3 = 572.958 deg/s in FANUC's convention: joint_3 - joint_2" in d, d
    limit_deg_s, limit_rad_s = ros_number(d, r"J3's speed limit ([\d.]+) deg/s \(([\d.]+) rad/s\)")
    assert limit_rad_s == pytest.approx(math.radians(limit_deg_s), rel=1e-3) and 4.0 < limit_rad_s < 10.0, d
    # unnamed (in order), a NaN: the position in the array and the joint it stands for
    r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG,
                   lambda t: ros.joint_jog(t, [], [0.0, 0.0, 0.0, math.nan, 0.0, 0.0]))
    assert r["status"] == 422 and "velocities[3] (joint_4) = nan rad/s" in r["detail"], r
    # a count the arm does not have: REST's count refusal after the velocities as sent
    for velocities in ([0.1] * 8, []):
        r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG, lambda t, v=velocities: ros.joint_jog(t, [], v))
        assert r["status"] == 422 and r["detail"].startswith(f"delta_joint_cmds: velocities = {velocities} rad/s"), r
    # the hold time: duration in s, not hold_ms
    r = send_fresh(client, "delta_joint_cmds", ros.JOINT_JOG,
                   lambda t: ros.joint_jog(t, ["joint_1"], [0.1], duration_s=5.0))
    assert r["status"] == 422 and "duration = 5 s (hold_ms = 5000)" in r["detail"], r
    assert "less than or equal to 2000 (2 s)" in r["detail"], r
    s = rig.state()
    assert s["q_cmd"] == s0["q_cmd"] and s["at_rest"] and s["state"] == "streaming"


@pytest.mark.e2e
def test_a_joint_target_refusal_names_the_positions_as_sent_with_the_j2_j3_coupling(
        cell: tuple[Rig, ZenohInterface, Client]) -> None:
    """joint_3 at -1.3 rad (-74.5 deg, below its range) with joint_2 at 0.5 rad: the refusal named
    "joints[2]=-103.132 deg", FANUC's coupled J3 (joint_3 - joint_2), which the sender never sent. Now it
    names the position entries as sent (by the names given, in any order), and the range in rad."""
    rig, _, client = cell
    streaming_for_zenoh(rig, client)
    s0 = rig.wait_at_rest_settled()
    q = np.array([0.0, 0.5, -1.3, 0.0, -1.5, 0.0])
    reversed_names = ros.JointState(header=ros.header(0, ""), name=[f"joint_{i}" for i in (6, 5, 4, 3, 2, 1)],
                                    position=q[::-1].copy(), velocity=np.zeros(0), effort=np.zeros(0))
    r = client.send("joint_target", ros.JOINT_STATE, reversed_names)
    d = r["detail"]
    assert r["status"] == 422 and isinstance(d, str) and d.startswith("joint_target: "), r
    assert "position[3] (joint_3) = -1.3 rad with position[4] (joint_2) = 0.5 rad" in d, d
    assert "J3 = -103.132 deg in FANUC's convention: joint_3 - joint_2" in d, d
    lo, hi = ros_number(d, r"joint range \[-?[\d.]+, [\d.]+\] \((-?[\d.]+) to ([\d.]+) rad\)")
    assert lo > -1.3 and lo == pytest.approx(math.radians(-70.0), abs=0.02) and hi > 3.0, d
    # unnamed: in order
    r = client.send("joint_target", ros.JOINT_STATE, ros.joint_state(0, q))
    assert r["status"] == 422 and "position[2] (joint_3) = -1.3 rad with position[1] (joint_2) = 0.5 rad" in \
        r["detail"], r
    r = client.send("joint_target", ros.JOINT_STATE, ros.joint_state(0, [0.0, 0.0, 0.0, math.inf, -1.5, 0.0]))
    assert r["status"] == 422 and "position[3] (joint_4) = inf rad" in r["detail"], r
    s = rig.state()
    assert s["q_cmd"] == s0["q_cmd"] and s["at_rest"] and s["state"] == "streaming"


def publish_until_exit(session: zenoh.Session, proc: subprocess.Popen[str], puts: dict[str, bytes],
                       what: str) -> tuple[str, str, float]:
    """Put each key's payload at 10 Hz (a cell's status, live) until the monitor ``proc`` has printed and
    exited (``what`` if not within 60 s); closes ``session``. Its stdout, stderr and when it was seen gone."""
    deadline = time.monotonic() + 60.0
    try:
        while proc.poll() is None:
            assert time.monotonic() < deadline, what
            for key, payload in puts.items():
                session.put(key, payload)
            time.sleep(0.1)
        exited = time.monotonic()
        out, err = proc.communicate(timeout=30)
    finally:
        session.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
    return out, err, exited

@pytest.mark.e2e
def test_the_monitor_shows_a_malformed_status_and_keeps_the_other_cells() -> None:
    """Anything can be published on servo_app/<cell>/status: a status that is not a JSON object, or
    whose fields are not what servo-app run publishes, took the monitor command down with a
    traceback (exit 1) and every cell's line with it. Now the bad cell's line says what it got and the
    good cell's line stays."""
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "servo_app.cli", "monitor", "--listen", f"tcp/127.0.0.1:{port}",
                             "--seconds", "6", "--once"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    session = client_session(f"tcp/127.0.0.1:{port}")
    statuses = {"good": {"state": "streaming", "latency_p99_us": 250.0, "alarms": [], "lease_held": False},
                "listy": [1, 2], "odd": {"state": "ready", "latency_p99_us": "fast", "lease_held": True,
                                          "lease_client": 7, "alarms": [3, "MOTN-017"]}}
    puts = {f"servo_app/{cell}/status": json.dumps(status).encode() for cell, status in statuses.items()}
    puts["servo_app/text/status"] = b"not json"
    # (the old monitor hung: its Zenoh session left open by the exception)
    out, err, _ = publish_until_exit(session, proc, puts, "the monitor did not exit after --seconds 6")
    assert proc.returncode == 0, err
    lines = {line.split()[0]: line for line in out.splitlines()[1:]}
    assert lines["good"].split()[1:4] == ["streaming", "0.25", "ms"], lines
    assert lines["listy"].split()[1] == "malformed" and "status not a JSON object: [1, 2]" in lines["listy"], lines
    assert lines["text"].split()[1] == "malformed" and "status not JSON" in lines["text"], lines
    assert lines["odd"].split()[1:5] == ["ready", "?", "7", "3"] and lines["odd"].endswith("MOTN-017"), lines


@pytest.mark.e2e
def test_the_monitor_once_without_seconds_prints_after_a_short_window_and_exits() -> None:
    """servo-app monitor --once without --seconds waited for Ctrl-C, then printed: a script running it
    hung. Now it prints each cell's line once after ONCE_WINDOW_S and exits 0; its help says so."""
    from servo_app.monitor import ONCE_WINDOW_S

    port = free_port()
    conf = zenoh.Config()  # a cell's peer, up first: the monitor connects to it as to a router
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "servo_app.cli", "monitor", "--connect", f"tcp/127.0.0.1:{port}",
                             "--once"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    status = {"state": "streaming", "latency_p99_us": 250.0, "alarms": [], "lease_held": False}
    out, err, exited = publish_until_exit(session, proc, {"servo_app/cell_a/status": json.dumps(status).encode()},
                                          "servo-app monitor --once did not exit within 60 s")
    assert proc.returncode == 0, err
    assert exited - t0 >= ONCE_WINDOW_S, exited - t0
    lines = {line.split()[0]: line for line in out.splitlines()[1:]}
    assert lines["cell_a"].split()[1:4] == ["streaming", "0.25", "ms"], out
    helptext = subprocess.run([sys.executable, "-m", "servo_app.cli", "monitor", "--help"], cwd=ROOT,
                              capture_output=True, text=True, timeout=60).stdout
    assert f"with --once, {ONCE_WINDOW_S:g} s" in " ".join(helptext.split()), helptext
    docs = " ".join((ROOT / "docs" / "zenoh.md").read_text().split())
    assert f"(after {ONCE_WINDOW_S:g} s unless `--seconds`" in docs


@pytest.mark.parametrize(("argv", "words"), [
    (["monitor", "--connect", "nonsense", "--seconds", "1"],
     "servo-app monitor: --connect nonsense: Endpoints must be of the form"),
    (["monitor", "--config", "/nonexistent/zenoh.json5", "--seconds", "1"],
     "servo-app monitor: --config /nonexistent/zenoh.json5: No such file or directory"),
    (["monitor", "--listen", "tcp/192.0.2.1:7447", "--seconds", "1"],
     "servo-app monitor: cannot open the Zenoh session: Can not create a new TCP listener bound to tcp/192.0.2.1"),
    (["run", "--zenoh", "--zenoh-connect", "nonsense", "--http-port", "0", "--token", TOKEN],
     "servo_app: --zenoh-connect nonsense: Endpoints must be of the form"),
    # Taken as any int: the Zenoh session opened, then an OverflowError traceback, and it hung.
    (["monitor", "--http-port", "70000", "--seconds", "1"],
     "servo-app monitor: error: argument --http-port: 70000 is outside 0..65535 (0: any free port)"),
    (["monitor", "--http-port", "-1", "--seconds", "1"], "argument --http-port: -1 is outside 0..65535"),
])
def test_an_unusable_zenoh_option_exits_2_naming_it(tmp_path: Path, argv: list[str], words: str) -> None:
    """A Zenoh endpoint or configuration zenoh refuses was a Python traceback from deep in zenoh (exit 1;
    servo-app run had started its servo process and simulator first); now exit 2, naming the option and
    value, in zenoh's words without its source locations."""
    if argv[0] == "run":
        argv = [*argv, "--var-dir", str(tmp_path / "var")]
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", *argv], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2, (r.stdout, r.stderr)
    text = r.stdout + r.stderr
    assert words in text and "Traceback" not in text and ".rs:" not in text, text
