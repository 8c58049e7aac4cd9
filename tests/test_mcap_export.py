"""`servo-app export FILE.srvlog --mcap OUT.mcap`: a session log as ROS 2-typed MCAP.

The round trip reads the file back with the ``mcap`` library and ``mcap_ros2``'s decoder (not the
rosbags typestore that wrote it: the schemas embedded in the file must be enough), and checks every
message against the session log it came from.
"""

from __future__ import annotations

import io
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Channel, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from test_api_harness import assert_log_complete, running_rig

from servo_app.mcap_export import TOPICS
from servo_app.robots.conventions import fanuc_deg_to_model_rad, wpr_to_rotation
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile
from servo_app.ros import messages as ros
from servo_app.session_log import SessionLog, SessionLogWriter, read_session_log

MODEL = "lrmate200id"


def export(src: Path, out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "servo_app.cli", "export", str(src), "--mcap", str(out), *extra],
                          capture_output=True, text=True, timeout=120)


def read_mcap(path: Path) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, str], dict[str, str]]:
    """Messages by topic as (log_time ns, decoded), the schema name of each topic, the metadata."""
    by_topic: dict[str, list[tuple[int, Any]]] = {}
    schemas: dict[str, str] = {}
    meta: dict[str, str] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            assert schema is not None and schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            schemas[channel.topic] = schema.name
            by_topic.setdefault(channel.topic, []).append((message.log_time, decoded))
        for m in reader.iter_metadata():
            meta.update(m.metadata)
    return by_topic, schemas, meta


def read_mcap_unfinished(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """Messages by topic of an MCAP still being written (no summary or footer yet): its records up to
    the last complete one."""
    by_topic: dict[str, list[tuple[int, Any]]] = {}
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders = DecoderFactory()
    try:
        for record in StreamReader(io.BytesIO(path.read_bytes())).records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, McapMessage):
                ch = channels[record.channel_id]
                decode = decoders.decoder_for(ch.message_encoding, schemas[ch.schema_id])
                assert decode is not None
                by_topic.setdefault(ch.topic, []).append((record.log_time, decode(record.data)))
    except EndOfFile:  # the writer is mid-chunk: what came before is what there is
        pass
    return by_topic


def stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def record_ns(log: SessionLog, rec: np.void) -> int:
    return round(float(log.header["opened_unix"]) * 1e9) + round(float(rec["t"]) * 1e9)


@pytest.mark.e2e
@pytest.mark.slow
def test_a_streamed_session_round_trips_through_mcap(tmp_path: Path) -> None:
    """A real stream (joint jog then a Cartesian twist, ended by the service), exported by the CLI:
    every status and every command is in the file, in ROS 2 types, with the log's numbers."""
    with running_rig(tmp_path) as rig:
        h = rig.streaming()
        rig.jog_for(h, [8, 0, 0, 0, 0, 0], 0.4)
        rig.wait(lambda s: s["at_rest"], 5.0, "at rest after the joint jog")
        rig.post("/api/jog", h, {"linear": [0, 30, 0], "hold_ms": 300})
        rig.wait(lambda s: s["at_rest"], 5.0, "at rest after the Cartesian jog's hold ran out")
        rig.end_and_wait(h)
        log = rig.latest_log()
        assert rig.sim_alarms() == []
    assert_log_complete(log, ended=True)
    src = rig.var_dir / "download.srvlog"
    out = tmp_path / "session.mcap"
    done = export(src, out)
    assert done.returncode == 0, done.stderr
    assert f"{out}:" in done.stdout

    by_topic, schemas, meta = read_mcap(out)
    assert schemas == {t: name for t, name in TOPICS.items() if t in by_topic}
    assert meta["model"] == MODEL
    cmds, sts = log.commands, log.statuses
    assert len(by_topic["/joint_commands"]) == len(cmds) == len(by_topic["/limit_usage"])
    assert len(by_topic["/joint_states"]) == len(sts) == len(by_topic["/status_bits"]) == len(by_topic["/tcp_pose"])
    assert "/diagnostics" not in by_topic, "a clean stream raises no alarm"

    profile = load_profile(MODEL)
    kin = ArmKinematics(profile)
    for rec, (t, msg) in zip(cmds, by_topic["/joint_commands"], strict=True):
        assert t == stamp_ns(msg) == record_ns(log, rec)
        assert msg.name == [f"joint_{i}" for i in range(1, 7)]
        want = fanuc_deg_to_model_rad(rec["values"][:6].astype(float), profile.j23_factor)
        np.testing.assert_array_equal(msg.position, want)
    for rec, (t, msg) in zip(sts, by_topic["/joint_states"], strict=True):
        assert t == record_ns(log, rec)
        np.testing.assert_array_equal(msg.position,
                                      fanuc_deg_to_model_rad(rec["values"][:6].astype(float), profile.j23_factor))
    for rec, (_, msg) in zip(sts, by_topic["/status_bits"], strict=True):
        assert (msg.seq, msg.bits, msg.io) == (int(rec["seq"]), int(rec["flags"]), int(rec["io"]))
        assert ("sysrdy" in msg.set) == bool(rec["flags"] & 0x04)
    for rec, (_, msg) in zip(cmds, by_topic["/tcp_pose/commanded"], strict=True):
        pose = kin.fk_fanuc_deg(rec["values"][:6].astype(float))
        p = msg.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], pose[:3, 3], atol=1e-12)
        o = msg.pose.orientation
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, pose[:3, :3].flatten())
        assert abs(abs(float(np.dot([o.w, o.x, o.y, o.z], quat))) - 1.0) < 1e-9

    # Limit usage: the finite differences of the commands over the fixed interval, in % of the table.
    dt = float(log.header["interval_ms"]) / 1000.0
    q = cmds["values"][:, :6].astype(float)
    v = np.diff(q, axis=0, prepend=q[:1]) / dt
    usage = np.array([m.velocity_pct for _, m in by_topic["/limit_usage"]])
    ratio = usage[1:] / np.maximum(np.abs(v[1:]), 1e-9)
    moving = np.abs(v[1:]) > 1.0
    assert moving.any(), "the stream never moved"
    per_axis = [np.unique(np.round(ratio[moving[:, k], k], 6)) for k in range(6)]
    assert all(len(u) <= 1 for u in per_axis), "velocity % is not |v| / one constant per axis"
    assert usage.max() < 100.0 and usage[np.abs(v) > 1.0].max() > 1.0


def write_log(path: Path, rows: np.ndarray, *, interval_ms: float = 8.0, protocol: str = "fanuc-j519",
              model: str = MODEL, last: bool = True, statuses: bool = True) -> None:
    """A session log as the servo process writes it (the same writer), one status then one command per row."""
    w = SessionLogWriter(path, {"model": model, "interval_ms": interval_ms, "protocol": protocol})
    t = 0.0
    for i, row in enumerate(rows):
        if statuses:
            w.status(t, 100 + i, 0x05, 0, tuple(float(x) for x in row))
        w.command(t + 0.0002, 100 + i, int(last and i == len(rows) - 1), 1, 0, 200.0, tuple(float(x) for x in row))
        t += interval_ms / 1000.0
    w.close()


def test_a_limit_violation_is_on_diagnostics_as_servo_app_check_reports_it(tmp_path: Path) -> None:
    rows = np.zeros((40, 6))
    rows[20:, 0] = 1.5  # a 1.5 deg step of J1 in one 8 ms cycle: far above its velocity limit
    src, out = tmp_path / "jump.srvlog", tmp_path / "jump.mcap"
    write_log(src, rows)
    done = export(src, out)
    assert done.returncode == 0, done.stderr
    check = subprocess.run([sys.executable, "-m", "servo_app.cli", "check", str(src)], capture_output=True,
                           text=True, timeout=120)
    assert check.returncode == 1
    by_topic, _, _ = read_mcap(out)
    errors = [s for _, m in by_topic["/diagnostics"] for s in m.status if s.level == ros.ERROR]
    assert errors, by_topic["/diagnostics"]
    first = {kv.key: kv.value for kv in errors[0].values}
    assert first["seq"] == "120" and first["axis"] == "J1"
    assert first["code"] in check.stdout and errors[0].message.splitlines()[0] in check.stdout
    assert "alarms:" in done.stdout


def test_a_janome_log_exports_its_poses(tmp_path: Path) -> None:
    rows = np.array([[300.0 + i, 10.0, 50.0, 30.0 + i, 0, 0] for i in range(10)])
    src, out = tmp_path / "janome.srvlog", tmp_path / "janome.mcap"
    write_log(src, rows, interval_ms=8.0, protocol="janome-pointjob-v1", model="jr3000")
    done = export(src, out)
    assert done.returncode == 0, done.stderr
    by_topic, _, _ = read_mcap(out)
    assert set(by_topic) == {"/tcp_pose", "/tcp_pose/commanded", "/status_bits"}
    for row, (_, msg) in zip(rows, by_topic["/tcp_pose/commanded"], strict=True):
        p, o = msg.pose.position, msg.pose.orientation
        assert (p.x, p.y, p.z) == pytest.approx((row[0] / 1000, row[1] / 1000, row[2] / 1000), abs=1e-9)
        assert 2 * math.degrees(math.atan2(o.z, o.w)) == pytest.approx(row[3], abs=1e-4)


def test_unusable_input_exits_2_naming_the_file_and_what_to_do(tmp_path: Path) -> None:
    not_a_log = tmp_path / "notes.txt"
    not_a_log.write_text("hello")
    done = export(not_a_log, tmp_path / "x.mcap")
    assert done.returncode == 2 and "not a servo_app session log" in done.stderr and str(not_a_log) in done.stderr
    nameless = tmp_path / "nameless.srvlog"
    write_log(nameless, np.zeros((3, 6)), model="")
    done = export(nameless, tmp_path / "y.mcap")
    assert done.returncode == 2 and "--model" in done.stderr
    assert not (tmp_path / "x.mcap").exists() and not (tmp_path / "y.mcap").exists()
    done = export(nameless, tmp_path / "y.mcap", "--model", MODEL)
    assert done.returncode == 0, done.stderr
    # A header that is no JSON object, or no UTF-8: refused as the file's fault (a traceback before),
    # by export and check alike.
    import struct

    from servo_app.session_log import MAGIC

    for name, header in (("list.srvlog", b"[1, 2]"), ("latin.srvlog", b'{"model": "\xe9"}')):
        bad = tmp_path / name
        bad.write_bytes(MAGIC + struct.pack("<I", len(header)) + header)
        for cmd in (["export", str(bad), "--mcap", str(tmp_path / "z.mcap")], ["check", str(bad)]):
            done = subprocess.run([sys.executable, "-m", "servo_app.cli", *cmd], capture_output=True, text=True,
                                  timeout=120)
            assert done.returncode == 2 and "Traceback" not in done.stderr, (cmd, done.stderr)
            assert str(bad) in done.stderr and "header is not" in done.stderr, done.stderr


def test_an_empty_log_is_named_as_such_by_export_and_check(tmp_path: Path) -> None:
    """A 0-byte .srvlog (a process killed as it opened its log): both commands exit 2 saying it is empty
    and why, naming the file once (check said "a CSV names no robot model", export "not a servo_app
    session log (magic=b'')" after the path twice)."""
    empty = tmp_path / "session-killed.srvlog"
    empty.write_bytes(b"")
    for cmd in (["export", str(empty), "--mcap", str(tmp_path / "e.mcap")], ["check", str(empty)]):
        done = subprocess.run([sys.executable, "-m", "servo_app.cli", *cmd], capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 2, done.stderr
        assert f"{empty}: empty (0 bytes): no header was written" in done.stderr, done.stderr
        assert done.stderr.count(str(empty)) == 1, done.stderr


def test_an_output_that_cannot_be_written_exits_2_naming_it(tmp_path: Path) -> None:
    """--mcap in a directory that is not there (or not writable): exit 2 naming the output and what to
    do, no traceback, nothing left behind (it was a traceback, exit 1)."""
    src = tmp_path / "ok.srvlog"
    write_log(src, np.zeros((5, 6)))
    out = tmp_path / "no-such-dir" / "x.mcap"
    done = export(src, out)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert f"cannot write {out}" in done.stderr and "writable directory" in done.stderr, done.stderr
    assert not out.parent.exists()


@settings(max_examples=200, deadline=None)
@given(st.floats(-180, 180), st.floats(-89.9, 89.9), st.floats(-180, 180))
def test_quaternion_of_a_rotation_matches_mujoco(w: float, p: float, r: float) -> None:
    rot = wpr_to_rotation(w, p, r)
    x, y, z, qw = ros.rotation_to_quaternion(rot)
    want = np.zeros(4)
    mujoco.mju_mat2Quat(want, rot.flatten())
    assert abs(abs(float(np.dot([qw, x, y, z], want))) - 1.0) < 1e-12
    assert math.isclose(x * x + y * y + z * z + qw * qw, 1.0, rel_tol=1e-12)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-10, 10, allow_nan=False), min_size=6, max_size=6),
       st.integers(0, (2**31 - 1) * 10**9))  # builtin_interfaces/Time.sec is an int32
def test_joint_states_round_trip_through_cdr(q: list[float], t_ns: int) -> None:
    msg = ros.joint_state(t_ns, q, q)
    back = ros.deserialize(ros.serialize(msg, ros.JOINT_STATE), ros.JOINT_STATE)
    assert stamp_ns(back) == t_ns
    np.testing.assert_array_equal(back.position, q)
    assert list(back.name) == [f"joint_{i}" for i in range(1, 7)]


def test_session_log_fixture_reads_back(tmp_path: Path) -> None:
    src = tmp_path / "x.srvlog"
    write_log(src, np.ones((4, 6)))
    log = read_session_log(src)
    assert len(log.commands) == len(log.statuses) == 4 and log.commands["flags"][-1] & 1


@pytest.mark.e2e
def test_the_service_writes_mcap_live_beside_the_session_log(tmp_path: Path) -> None:
    """`servo-app run --mcap`: while the stream runs the MCAP grows (read back mid-stream), and once
    the log closes it holds every record's messages, as an export of the same log does."""
    with running_rig(tmp_path, mcap_live=True) as rig:
        h = rig.streaming()
        rig.jog_for(h, [0, 0, 0, 0, 0, 10], 0.3)
        live = sorted((tmp_path / "sessions").glob("*.mcap"))
        assert len(live) == 1
        rig.wait(lambda s: live[0].stat().st_size > 64 * 1024, 10.0, "the live MCAP grows")
        mid_stream = read_mcap_unfinished(live[0])
        assert mid_stream["/joint_commands"], "commands are in the live MCAP while streaming"
        rig.end_and_wait(h)
        log = rig.latest_log()
        assert rig.sim_alarms() == []
    srvlog = live[0].with_suffix(".srvlog")
    assert read_session_log(srvlog).records.size == log.records.size
    by_topic, _, _ = read_mcap(live[0])
    assert len(by_topic["/joint_commands"]) == len(log.commands) and len(by_topic["/joint_states"]) == len(log.statuses)
    exported = tmp_path / "exported.mcap"
    assert export(srvlog, exported).returncode == 0
    again, _, _ = read_mcap(exported)
    assert {t: [ts for ts, _ in v] for t, v in again.items()} == {t: [ts for ts, _ in v] for t, v in by_topic.items()}


def test_a_stream_the_controller_stops_is_on_diagnostics(tmp_path: Path) -> None:
    """Status bit 0 clearing while commands flow (the controller ended the stream, not our last data)."""
    src, out = tmp_path / "stopped.srvlog", tmp_path / "stopped.mcap"
    w = SessionLogWriter(src, {"model": MODEL, "interval_ms": 8.0, "protocol": "fanuc-j519"})
    for i in range(6):
        w.status(i * 0.008, 10 + i, 0x05 if i < 4 else 0x04, 0, (0.0,) * 6)
        if i < 4:
            w.command(i * 0.008 + 1e-4, 10 + i, 0, 1, 0, 100.0, (0.0,) * 6)
    w.close()
    assert export(src, out).returncode == 0
    by_topic, _, _ = read_mcap(out)
    [(_, diag)] = by_topic["/diagnostics"]
    assert diag.status[0].level == ros.ERROR and "status bit 0 cleared" in diag.status[0].message
    assert {kv.key: kv.value for kv in diag.status[0].values} == {"seq": "14"}


def test_a_cartesian_stream_exports_its_poses_and_the_joints_the_controller_makes(tmp_path: Path) -> None:
    """X Y Z W P R commands (data format 0): the commanded pose is the command itself, in metres; the
    joints are the controller's conversion of it (as `servo-app check` converts them)."""
    from servo_app.robots.conventions import matrix_to_xyzwpr

    profile = load_profile(MODEL)
    kin = ArmKinematics(profile)
    s = np.linspace(0.0, 1.0, 30)
    ramp = 0.5 * (10 * s**3 - 15 * s**4 + 6 * s**5)  # 0.5 deg, quintic: within every limit
    joints = np.array([[10.0 + r, 20.0, -10.0 - r, 5.0, -60.0, 15.0 + r] for r in ramp])
    poses = np.array([matrix_to_xyzwpr(kin.fk_fanuc_deg(q)) for q in joints])
    src, out = tmp_path / "cart.srvlog", tmp_path / "cart.mcap"
    w = SessionLogWriter(src, {"model": MODEL, "interval_ms": 8.0, "protocol": "fanuc-j519"})
    for i, (q, xyzwpr) in enumerate(zip(joints, poses, strict=True)):
        w.status(i * 0.008, 50 + i, 0x05, 0, tuple(q))
        w.command(i * 0.008 + 1e-4, 50 + i, int(i == len(joints) - 1), 0, 0, 100.0, tuple(xyzwpr))
    w.close()
    done = export(src, out)
    assert done.returncode == 0, done.stderr
    by_topic, _, _ = read_mcap(out)
    assert "/diagnostics" not in by_topic, [s.message for _, m in by_topic["/diagnostics"] for s in m.status]
    logged = read_session_log(src).commands["values"][:, :6].astype(float)
    for xyzwpr, (_, msg) in zip(logged, by_topic["/tcp_pose/commanded"], strict=True):
        p = msg.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], xyzwpr[:3] / 1000.0, rtol=0, atol=1e-12)
    for q, (_, msg) in zip(joints, by_topic["/joint_commands"], strict=True):
        np.testing.assert_allclose(msg.position, fanuc_deg_to_model_rad(q, profile.j23_factor), atol=1e-5)


def test_a_cartesian_command_without_joints_is_exported_with_its_alarm_and_the_rest_too(tmp_path: Path) -> None:
    """One X Y Z W P R command out of reach (5 m) in the middle of a Cartesian stream: the export no
    longer refuses the whole log; every command's pose is in the file, every other its joints, and
    /diagnostics and the output name the one without (its Sq. and the controller's code, as
    `servo-app check` reports it)."""
    from servo_app.robots.conventions import matrix_to_xyzwpr

    profile = load_profile(MODEL)
    kin = ArmKinematics(profile)
    s = np.linspace(0.0, 1.0, 30)
    ramp = 0.5 * (10 * s**3 - 15 * s**4 + 6 * s**5)
    joints = np.array([[10.0 + r, 20.0, -10.0 - r, 5.0, -60.0, 15.0 + r] for r in ramp])
    poses = np.array([matrix_to_xyzwpr(kin.fk_fanuc_deg(q)) for q in joints])
    poses[12, :3] = (5000.0, 0.0, 0.0)  # Sq.62: no joint solution
    src, out = tmp_path / "cart.srvlog", tmp_path / "cart.mcap"
    w = SessionLogWriter(src, {"model": MODEL, "interval_ms": 8.0, "protocol": "fanuc-j519"})
    for i, xyzwpr in enumerate(poses):
        w.status(i * 0.008, 50 + i, 0x05, 0, tuple(joints[max(0, i - 1)]))
        w.command(i * 0.008 + 1e-4, 50 + i, int(i == len(poses) - 1), 0, 0, 100.0, tuple(xyzwpr))
    w.close()
    done = export(src, out)
    assert done.returncode == 0, done.stderr
    assert "1 Cartesian command(s) have no joint solution: Sq.62" in done.stdout, done.stdout
    by_topic, _, _ = read_mcap(out)
    assert len(by_topic["/tcp_pose/commanded"]) == 30 and len(by_topic["/joint_commands"]) == 29
    errors = [s for _, m in by_topic["/diagnostics"] for s in m.status if s.level == ros.ERROR]
    first = {kv.key: kv.value for kv in errors[0].values}
    assert first["seq"] == "62" and first["kind"] == "cartesian", first
    assert "5000.0, 0.0, 0.0" in errors[0].message
    check = subprocess.run([sys.executable, "-m", "servo_app.cli", "check", str(src)], capture_output=True,
                           text=True, timeout=120)
    assert check.returncode == 1 and f"{first['code']} " in check.stdout and "Sq.62" in check.stdout, check.stdout
    # The commands after it convert again, from the last one that did (the held configuration).
    for q, (_, msg) in zip(np.delete(joints, 12, axis=0), by_topic["/joint_commands"], strict=True):
        np.testing.assert_allclose(msg.position, fanuc_deg_to_model_rad(q, profile.j23_factor), atol=1e-5)
