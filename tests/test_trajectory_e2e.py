"""POST /api/trajectory, the client's replay and ``servo-app replay`` end to end: uvicorn, the servo
process and the simulator on loopback. Every replay ends at its last waypoint with zero alarms, and its
session log passes ``servo-app check``."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_api_harness import AUTH, STOP_WAYS, TOKEN, Rig, running_janome_rig, running_rig, servo_app_argv

from servo_app.client import ServoClient
from servo_app.messages import LogOpened
from servo_app.motion.limit_tables import AxisTable, LimitTables, default_tables
from servo_app.robots.conventions import matrix_to_xyzwpr
from servo_app.robots.kinematics import ArmKinematics
from servo_app.robots.profile import load_profile
from servo_app.service.trajectory import read_log_window
from servo_app.session_log import SessionLogWriter, read_session_log

pytestmark = pytest.mark.e2e

HOME = [0.0, 10.0, -10.0, 0.0, -80.0, 0.0]  # wrist bent: away from every configuration boundary


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    with running_rig(tmp_path_factory.mktemp("trajectory")) as r:
        yield r


def at_home(rig: Rig) -> dict[str, str]:
    """A running stream with the arm at rest at HOME (a joint target, if it is elsewhere)."""
    h = rig.streaming("trajectory")
    s = rig.wait(lambda s: s["at_rest"], 15.0, "at rest")
    if not np.allclose(s["q_cmd"][:6], HOME, atol=1e-3):
        rig.post("/api/target", h, {"joints": HOME})
        rig.wait(lambda s: s["at_rest"] and np.allclose(s["q_cmd"][:6], HOME, atol=1e-3), 20.0, "at HOME")
    return h


def replay_to_end(rig: Rig, headers: dict[str, str], timeout: float = 20.0, **post: Any) -> dict[str, Any]:
    r = rig.http.post("/api/trajectory", headers=headers, **post)
    assert r.status_code == 200, r.text
    return rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], timeout,
                    "the replay done")


def log_now(rig: Rig) -> tuple[str, float]:
    """The stream's session log (being written) and the time of its newest command (s after its first)."""
    ev = rig.service.last_event(LogOpened)
    assert isinstance(ev, LogOpened)
    t = read_session_log(Path(ev.path)).commands["t"]
    return Path(ev.path).name, float(t[-1] - t[0])


def check_log_passes(rig: Rig, headers: dict[str, str]) -> np.ndarray:
    """End the stream, then run ``servo-app check`` on its session log; the commanded joints."""
    rig.end_and_wait(headers)
    log = rig.latest_log()
    path = rig.var_dir / "download.srvlog"
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "check", str(path)], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    return log.commands["values"][:, :6].astype(float)


def test_joint_waypoints_replay_to_the_end_and_the_log_passes_the_check(rig: Rig) -> None:
    h = at_home(rig)
    waypoints = [[20.0, 15.0, -5.0, 10.0, -70.0, 30.0], [-15.0, 5.0, -15.0, -10.0, -90.0, -20.0]]
    s = replay_to_end(rig, h, json={"joints": waypoints})
    assert np.allclose(s["q_cmd"][:6], waypoints[-1], atol=1e-3)
    assert s["trajectory"]["index"] == s["trajectory"]["total"] - 1
    assert rig.sim_alarms() == []
    check_log_passes(rig, h)


def test_cartesian_waypoints_keep_the_tcp_on_the_straight_segments(rig: Rig) -> None:
    h = at_home(rig)
    kin = ArmKinematics(rig.service.profile)
    x0 = matrix_to_xyzwpr(kin.fk_fanuc_deg(np.array(HOME)))
    poses = [x0, x0 + np.array([60.0, 40.0, -30.0, 0.0, 0.0, 10.0]), x0 + np.array([0.0, -50.0, 20.0, 5.0, 0.0, 0.0])]
    _, started = log_now(rig)
    s = replay_to_end(rig, h, json={"poses": [p.tolist() for p in poses]})
    assert rig.sim_alarms() == []
    rig.end_and_wait(h)
    log = rig.latest_log()
    cmds = log.commands[log.commands["t"] - log.commands["t"][0] >= started]
    xyz = np.array([kin.fk_fanuc_deg(row)[:3, 3] * 1000.0 for row in cmds["values"][:, :6].astype(float)])
    corners = np.array([p[:3] for p in poses])
    assert max(distance_to_polyline(p, corners) for p in xyz) < 1.0
    assert np.allclose(kin.fk_fanuc_deg(np.array(s["q_cmd"][:6]))[:3, 3] * 1000.0, poses[-1][:3], atol=0.05)
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "check", str(rig.var_dir / "download.srvlog")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def test_blended_joint_waypoints_are_passed_through_without_stopping(rig: Rig) -> None:
    """``blend``: one motion through the via points, at rest only at the last (rest to rest, the arm
    stopped at each): the commands as the session log recorded them pass each inner waypoint at speed."""
    h = at_home(rig)
    via = np.array([[20.0, 20.0, -5.0, 10.0, -70.0, 30.0], [35.0, 10.0, 5.0, 0.0, -85.0, 0.0],
                    [15.0, 0.0, -15.0, -10.0, -95.0, -30.0], [-10.0, 15.0, -5.0, 0.0, -80.0, 10.0]])
    _, started = log_now(rig)
    r = rig.http.post("/api/trajectory", headers=h, json={"joints": via.tolist(), "blend": True})
    assert r.status_code == 200, r.text
    assert "blended" in r.json()["detail"]["label"], r.text
    s = rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 20.0, "done")
    assert np.allclose(s["q_cmd"][:6], via[-1], atol=1e-3)
    assert rig.sim_alarms() == []
    rig.end_and_wait(h)
    log = rig.latest_log()
    cmds = log.commands[log.commands["t"] - log.commands["t"][0] >= started]
    q = cmds["values"][:, :6].astype(float)
    dt = float(np.median(np.diff(cmds["t"])))
    speed = np.abs(np.diff(q, axis=0)).max(axis=1) / dt  # the fastest joint's, deg/s
    for w in via[:-1]:
        k = int(np.argmin(np.linalg.norm(q - w, axis=1)))
        assert distance_to_polyline(w, q) < 0.05, w
        assert speed[k - 1: k + 1].min() > 50.0, (w, speed[k - 1: k + 1])
    assert np.array_equal(q[-1], via[-1].astype(np.float32))
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "check", str(rig.var_dir / "download.srvlog")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def distance_to_polyline(point: np.ndarray, line: np.ndarray) -> float:
    """Distance from a point to the polyline through ``line``'s rows (repeated rows: a point of it)."""
    a, b = line[:-1], line[1:]
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", point - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * d - point, axis=1)))


def test_a_csv_body_replays_its_rows(rig: Rig) -> None:
    h = at_home(rig)
    t = np.linspace(0.0, 1.0, 200)[:, None]
    rows = np.array(HOME) + np.hstack([20.0 * np.sin(np.pi * t), 5.0 * t, np.zeros((200, 3)), -10.0 * t])
    text = "j1,j2,j3,j4,j5,j6\n" + "\n".join(",".join(f"{v:.5f}" for v in r) for r in rows)
    r = rig.http.post("/api/trajectory", content=text.encode(), headers={**h, "Content-Type": "text/csv"})
    assert r.status_code == 200, r.text
    s = rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 20.0, "done")
    assert np.allclose(s["q_cmd"][:6], rows[-1], atol=1e-3)
    assert rig.sim_alarms() == []


def test_a_csv_of_thousands_of_rows_is_taken_and_bodies_past_the_routes_limit_are_not(rig: Rig) -> None:
    """The trajectory upload's own body limit (2 MiB; 64 KiB elsewhere took only ~1000 rows): 4000 rows at
    full precision (~400 KB) replay to the end; 2.5 MB is 413 before it is read, a JSON body of more values
    than the largest valid one is 422 before it is parsed, and neither changes anything."""
    from servo_app.api.body_limit import MAX_BODY_BYTES
    from servo_app.api.trajectory import MAX_BODY_BYTES as TRAJECTORY_BODY_BYTES

    h = at_home(rig)
    t = np.linspace(0.0, 1.0, 4000)[:, None]
    rows = np.array(HOME) + np.hstack([12.0 * np.sin(np.pi * t / 2), -4.0 * t, np.zeros((4000, 3)), 8.0 * t])
    text = "j1,j2,j3,j4,j5,j6\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows)
    assert len(text) > 4 * MAX_BODY_BYTES
    r = rig.http.post("/api/trajectory", content=text.encode(), params={"pace": "limits"},
                      headers={**h, "Content-Type": "text/csv"})
    assert r.status_code == 200, r.text
    s = rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 30.0, "done")
    assert np.allclose(s["q_cmd"][:6], rows[-1], atol=1e-3)
    before = rig.state()
    too_big = b"j1,j2,j3,j4,j5,j6\n" + b"0,0,0,0,0,0\n" * 210_000  # 2.5 MB
    assert len(too_big) > TRAJECTORY_BODY_BYTES
    r = rig.http.post("/api/trajectory", content=too_big, headers={**h, "Content-Type": "text/csv"})
    assert r.status_code == 413 and f"at most {TRAJECTORY_BODY_BYTES} bytes" in r.json()["detail"], r.text[:300]
    many = b'{"joints": [[' + b"0," * 200_000 + b'0]]}'  # 400 KB of one waypoint's values
    r = rig.http.post("/api/trajectory", content=many, headers={**h, "Content-Type": "application/json"})
    assert r.status_code == 422 and "more than 100000 values" in r.json()["detail"][0]["msg"], r.text[:300]
    s = rig.state()
    assert s["state"] == "streaming" and s["at_rest"] and s["q_cmd"] == before["q_cmd"]
    assert s["trajectory"] == before["trajectory"]
    assert rig.sim_alarms() == []


def test_a_recorded_jog_replays_from_its_session_log(rig: Rig) -> None:
    h = at_home(rig)
    name, from_s = log_now(rig)
    rig.jog_for(h, [10.0, 0.0, 5.0, 0.0, 0.0, 15.0], 1.0)  # the teleoperated stretch: recorded per cycle
    jogged = rig.wait_at_rest_settled(5.0)["q_cmd"][:6]
    _, to_s = log_now(rig)
    rig.post("/api/target", h, {"joints": HOME})
    rig.wait(lambda s: s["at_rest"] and np.allclose(s["q_cmd"][:6], HOME, atol=1e-3), 20.0, "back at HOME")
    r = rig.http.post("/api/trajectory", headers=h, json={"log": name, "from_s": from_s, "to_s": to_s})
    assert r.status_code == 200, r.text
    # At the recorded pace: the second of jogging takes about as long again (timed by the limits alone
    # it took 0.3 s), and the rests around it are not replayed.
    assert 0.95 < r.json()["detail"]["duration_s"] < 3.0, r.json()
    s = rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 20.0, "done")
    assert np.allclose(s["q_cmd"][:6], jogged, atol=1e-3)
    assert rig.sim_alarms() == []
    check_log_passes(rig, h)


def test_a_log_of_moves_resting_at_corners_replays_at_full_speed_through_each_rest(rig: Rig) -> None:
    """Joint targets one after the other, each reached at rest, the next leaving at an angle: the
    log's window replays at speed_scale 1 (it was refused, TOPP-RA finding no timing, or the corners
    were cut: the spline ran through knots thinned past the rest points), through every point where
    the recording rested, with zero alarms."""
    h = at_home(rig)
    name, from_s = log_now(rig)
    jog_end, t1, t2 = ([37.36, -2.26, 14.65, 49.91, -80.0, 74.54], [40.0, -10.0, 20.0, 30.0, -40.0, 60.0],
                       [-30.0, 20.0, -20.0, -30.0, -100.0, -60.0])
    goals = (jog_end, t1, jog_end, t1, t2, t1, t2)
    for goal in goals:
        rig.post("/api/target", h, {"joints": goal, "speed_scale": 1.0})
        rig.wait(lambda s, q=goal: s["at_rest"] and np.allclose(s["q_cmd"][:6], q, atol=1e-3), 20.0, f"at {goal}")
    _, to_s = log_now(rig)
    rig.post("/api/target", h, {"joints": HOME})
    rig.wait(lambda s: s["at_rest"] and np.allclose(s["q_cmd"][:6], HOME, atol=1e-3), 20.0, "back at HOME")
    _, replay_from = log_now(rig)
    r = rig.http.post("/api/trajectory", headers=h, json={"log": name, "from_s": from_s, "to_s": to_s,
                                                          "speed_scale": 1.0})
    assert r.status_code == 200, r.text

    def done(s: dict[str, Any]) -> bool:
        rig.http.post("/api/lease/renew", headers=h)  # (a replay longer than the lease's TTL)
        return (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"]

    s = rig.wait(done, 60.0, "the replay done")
    assert np.allclose(s["q_cmd"][:6], t2, atol=1e-3)
    replayed = read_log_window(Path(rig.service.last_event(LogOpened).path), name, replay_from, None)
    for goal in goals:  # every rest of the recording is on the replayed path, not cut short
        assert np.abs(replayed - goal).max(axis=1).min() < 1e-3, goal
    assert rig.sim_alarms() == []


def test_a_log_keeps_its_recorded_pace_on_a_stream_of_another_interval(tmp_path: Path) -> None:
    """A log recorded at 8 ms (its header says so) replayed on a 4 ms stream: at the recorded pace it
    takes as long as it was recorded (it was timed at 4 ms a row: twice as fast as recorded)."""
    with running_rig(tmp_path, interval_ms=4) as fast:
        h = fast.streaming("pace")
        q0 = np.array(fast.wait(lambda s: s["at_rest"], 15.0, "at rest")["q_cmd"][:6])
        s = np.linspace(0.0, 1.0, 126)[:, None]  # 1 s at 8 ms, then at rest
        rows = q0 + (10 * s**3 - 15 * s**4 + 6 * s**5) * np.array([10.0, 0.0, 0.0, 0.0, 0.0, 10.0])
        name = "session-recorded-at-8ms.srvlog"
        w = SessionLogWriter(fast.service.cfg.log_dir / name,
                             {"model": "lrmate200id", "interval_ms": 8.0, "protocol": "fanuc-j519-v1"})
        for i, q in enumerate(rows):
            w.command(i * 0.008, i + 1, int(i == len(rows) - 1), 1, 0, 100.0, tuple(q))
        w.close()
        r = fast.http.post("/api/trajectory", headers=h, json={"log": name})
        assert r.status_code == 200, r.text
        assert 0.95 < r.json()["detail"]["duration_s"] < 1.6, r.json()
        fast.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 20.0, "done")
        assert np.allclose(fast.state()["q_cmd"][:6], rows[-1], atol=1e-3)
        assert fast.sim_alarms() == []


def test_stop_pauses_on_the_path_and_resume_finishes_it(rig: Rig) -> None:
    h = at_home(rig)
    goal = [40.0, 20.0, 0.0, 20.0, -60.0, 60.0]
    rig.post("/api/trajectory", h, {"joints": [goal], "speed_scale": 0.5})
    rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "playing"
             and s["trajectory"]["index"] > s["trajectory"]["total"] // 4, 10.0, "a quarter played")
    rig.post("/api/session/stop", h)
    s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 10.0, "paused")
    assert s["trajectory"]["state"] == "paused" and s["trajectory"]["paused"]
    q = np.array(s["q_cmd"][:6])
    # on the straight joint-space line from HOME to the goal
    d = np.array(goal) - np.array(HOME)
    k = float((q - HOME) @ d / (d @ d))
    assert 0.0 < k < 1.0 and np.abs(np.array(HOME) + k * d - q).max() < 1e-3
    rig.post("/api/session/resume", h)
    s = rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 20.0, "done")
    assert np.allclose(s["q_cmd"][:6], goal, atol=1e-3)
    assert rig.sim_alarms() == []


def test_a_jog_ends_the_replay_and_the_state_says_why(rig: Rig) -> None:
    goal = [40.0, 20.0, 0.0, 20.0, -60.0, 60.0]
    for took_over in ("jog", "twist"):  # each replay left reports its own reason
        h = at_home(rig)
        rig.post("/api/trajectory", h, {"joints": [goal], "speed_scale": 0.5})
        rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "playing"
                 and s["trajectory"]["index"] > s["trajectory"]["total"] // 4, 10.0, "a quarter played")
        rig.post("/api/jog", h, {"joints": [0.0, 0.0, 0.0, 0.0, 0.0, 5.0]} if took_over == "jog"
                 else {"linear": [5.0, 0.0, 0.0]})
        s = rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "ended", 5.0, "the replay ended")
        assert s["trajectory"]["reason"] == f"a {took_over} took over"
        rig.wait(lambda s: s["at_rest"], 10.0, "at rest")
    assert rig.sim_alarms() == []
    # A new replay that runs to its end has no reason to give.
    s = replay_to_end(rig, h, json={"joints": [HOME]})
    assert "reason" not in s["trajectory"] or s["trajectory"]["reason"] is None


@pytest.mark.parametrize(("body", "words"), [
    ({"joints": [[0.0, 0.0, 0.0, 0.0, math.nan, 0.0]]}, "joints[0][4]=nan"),
    ({"joints": [[0.0, 0.0, 0.0]]}, "joints[0] has 3 values"),
    ({"joints": [[0.0, 0.0, 0.0, 0.0, -80.0, 500.0]]}, "joints[0]"),
    ({"poses": [[3000.0, 0.0, 300.0, 180.0, 0.0, 0.0]]}, "poses[0]: xyzwpr X=3000 Y=0 Z=300 mm is 2"),
    # In metres: said so (it was "no joint solution"), for the poses and for a CSV body's rows.
    ({"poses": [[400.0, 0.0, 300.0, 180.0, 0.0, 0.0], [0.4, 0.0, 0.3, 180.0, 0.0, 0.0]]},
     "poses[1]: xyzwpr X=0.4 Y=0 Z=0.3 all lie within +-5: units are mm (did you send metres?"),
    ({"joints": [HOME, HOME], "times": [1.0, 1.0]}, "times[1]=1.0"),
    ({"log": "no-such.srvlog"}, "log='no-such.srvlog'"),
    ({"log": "no-such.srvlog", "pace": "fast"}, "pace"),
    ({"poses": [[400.0, 0.0, 300.0, 180.0, 0.0, 0.0]], "blend": True}, "blend=true: only with joints"),
    ({"joints": [HOME, [20.0, 10.0, -10.0, 0.0, -80.0, 0.0]], "times": [1.0, 2.0], "blend": True},
     "times: not with blend=true"),
    # J5 to 1 deg from its range and on: the spline turns past it (straight segments would not).
    ({"joints": [[20.0, 10.0, -10.0, 0.0, -80.0, 0.0], [20.0, 10.0, -10.0, 0.0, -124.0, 0.0],
                 [40.0, 10.0, -10.0, 0.0, -80.0, 0.0]], "blend": True},
     "blend: the spline from joints[1] to joints[2] overshoots"),
])
def test_refusals_name_the_field_and_change_nothing(rig: Rig, body: dict[str, Any], words: str) -> None:
    h = at_home(rig)
    before = rig.state()
    # NaN as Python's json writes it (httpx's encoder refuses it: a hand-written body, as curl would send)
    r = rig.http.post("/api/trajectory", content=json.dumps(body).encode(),
                      headers={**h, "Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    assert words in r.text, r.text
    after = rig.state()
    assert after["state"] == before["state"] == "streaming"
    assert after["q_cmd"] == before["q_cmd"] and after["at_rest"]
    assert (after.get("trajectory") or {}).get("state") in (None, "done", "ended")


def test_a_csv_of_poses_in_metres_is_refused_by_row_and_changes_nothing(rig: Rig) -> None:
    h = at_home(rig)
    before = rig.state()
    text = "x,y,z,w,p,r\n400,0,300,180,0,0\n0.4,0,0.3,180,0,0\n"
    r = rig.http.post("/api/trajectory", content=text.encode(), headers={**h, "Content-Type": "text/csv"})
    assert r.status_code == 422, r.text
    assert "csv row 2: xyzwpr X=0.4 Y=0 Z=0.3 all lie within +-5: units are mm (did you send metres?" in r.text
    after = rig.state()
    assert (after["state"], after["q_cmd"], after.get("trajectory")) == (before["state"], before["q_cmd"],
                                                                          before.get("trajectory"))


def test_the_client_replays_and_servo_app_replay_runs_a_csv_file(rig: Rig, tmp_path: Path) -> None:
    at_home(rig)
    with ServoClient(rig.base_url, TOKEN, take_over=True) as arm:
        arm.ensure_streaming()  # taking the lease over stopped the rig's stream: resume it
        summary = arm.replay([[10.0, 10.0, -10.0, 0.0, -80.0, 10.0]])
        assert summary["samples"] > 10 and arm.state().trajectory is not None
        assert arm.state().trajectory.state == "done"  # type: ignore[union-attr]
        summary = arm.replay([[0.0, 20.0, -10.0, 0.0, -80.0, 0.0], HOME], blend=True)
        assert "blended" in summary["label"] and arm.state().trajectory.state == "done"  # type: ignore[union-attr]
    last = [-10.0, 15.0, -5.0, 5.0, -75.0, -15.0]
    csv = tmp_path / "path.csv"
    csv.write_text(f"# J1..J6\n{','.join(map(str, HOME))}\n{','.join(map(str, last))}\n")
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "replay", str(csv), "--url", rig.base_url,
                        "--token", TOKEN, "--take-over"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "done" in r.stdout
    s = rig.state()
    assert np.allclose(s["q_cmd"][:6], last, atol=1e-3) and rig.sim_alarms() == []


def test_servo_app_replay_of_a_log_the_service_does_not_list_keeps_its_kind(rig: Rig, tmp_path: Path) -> None:
    """A session log from elsewhere (not in the service's log directory) is sent as a CSV: a Cartesian
    log's rows are flange poses and replay as such, ending at the pose's joints (they were sent as
    joint values, refused as out of range or worse); a Janome log is refused, exit 2, saying why."""
    at_home(rig)
    kin = ArmKinematics(load_profile("lrmate200id"))
    s = np.linspace(0.0, 1.0, 120)[:, None]
    joints = np.array(HOME) + (10 * s**3 - 15 * s**4 + 6 * s**5) * np.array([12.0, 6.0, -4.0, 8.0, 10.0, -15.0])
    cart = tmp_path / "elsewhere-cartesian.srvlog"
    w = SessionLogWriter(cart, {"model": "lrmate200id", "interval_ms": 8.0, "protocol": "fanuc-j519-v1"})
    for i, q in enumerate(joints):  # data format 0: the flange pose of each commanded position
        pose = tuple(matrix_to_xyzwpr(kin.fk_fanuc_deg(q)))
        w.command(i * 0.008, i + 1, int(i == len(joints) - 1), 0, 0, 100.0, pose)
    w.close()
    argv = ["--url", rig.base_url, "--token", TOKEN, "--take-over"]
    replay = [sys.executable, "-m", "servo_app.cli", "replay"]
    r = subprocess.run([*replay, str(cart), *argv], capture_output=True, text=True, timeout=90)
    assert r.returncode == 0, r.stdout + r.stderr
    assert np.allclose(rig.state()["q_cmd"][:6], joints[-1], atol=1e-3)
    janome = tmp_path / "elsewhere-janome.srvlog"
    w = SessionLogWriter(janome, {"model": "jr3000", "protocol": "janome-pointjob-v1"})
    w.command(0.0, 1, 0, 1, 0, 0.0, (200.0, 0.0, 50.0, 0.0))
    w.close()
    r = subprocess.run([*replay, str(janome), *argv], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "a Janome session log" in r.stderr and str(janome) in r.stderr, r.stderr
    assert rig.sim_alarms() == []


def test_servo_app_replay_of_a_file_named_like_a_service_log_replays_the_file(rig: Rig, tmp_path: Path) -> None:
    """A log file given to ``servo-app replay`` that has the name of one of the service's logs but is
    another file (cut down, or from another machine): its own commands are replayed, not the
    service's log of that name."""
    at_home(rig)
    name, _ = log_now(rig)  # the service's log being written now
    s = np.linspace(0.0, 1.0, 100)[:, None]
    goal = np.array(HOME) + np.array([-12.0, 5.0, 0.0, 0.0, 6.0, 20.0])
    rows = np.array(HOME) + (10 * s**3 - 15 * s**4 + 6 * s**5) * (goal - np.array(HOME))
    mine = tmp_path / name
    w = SessionLogWriter(mine, {"model": "lrmate200id", "interval_ms": 8.0, "protocol": "fanuc-j519-v1"})
    for i, q in enumerate(rows):
        w.command(i * 0.008, i + 1, int(i == len(rows) - 1), 1, 0, 100.0, tuple(q))
    w.close()
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "replay", str(mine), "--url", rig.base_url,
                        "--token", TOKEN, "--take-over"], capture_output=True, text=True, timeout=90)
    assert r.returncode == 0, r.stdout + r.stderr
    assert np.allclose(rig.state()["q_cmd"][:6], goal, atol=1e-3)
    assert rig.sim_alarms() == []


@pytest.mark.parametrize(("name", "content", "words"), [
    ("bad.json", b"{joints: [1, 2]", "not JSON"),
    ("list.json", b"[[0, 0, 0, 0, 0, 0]]", "a JSON body needs one of joints, poses or log"),
    ("blob.csv", b"\xff\xfe\x00binary", "not a text file nor a session log"),
])
def test_servo_app_replay_of_an_unusable_file_exits_2_naming_it(rig: Rig, tmp_path: Path, name: str,
                                                                content: bytes, words: str) -> None:
    """A file replay cannot use: exit 2, the file and what to give (it was a bare JSON error without
    the file, the service's "got none" for a JSON list, a codec error), and the arm does not move."""
    at_home(rig)
    before = rig.state()["q_cmd"]
    bad = tmp_path / name
    bad.write_bytes(content)
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "replay", str(bad), "--url", rig.base_url,
                        "--token", TOKEN, "--take-over"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"servo-app replay: {bad}: " in r.stderr and words in r.stderr, r.stderr
    assert rig.state()["q_cmd"] == before


def write_joint_csv(path: Path, rows: np.ndarray) -> None:
    """Joint rows (FANUC deg) as the CSV ``servo-app replay`` reads."""
    path.write_text("j1,j2,j3,j4,j5,j6\n" + "\n".join(",".join(f"{v:.5f}" for v in r) for r in rows))


def start_replay(rig: Rig, csv: Path, how: str) -> subprocess.Popen[str]:
    """``servo-app replay CSV --take-over`` against the rig, started as ``how`` (STOP_WAYS) says."""
    return subprocess.Popen(servo_app_argv(how, "replay", str(csv), "--url", rig.base_url, "--token", TOKEN,
                                           "--take-over"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)

@pytest.mark.parametrize(("how", "sig"), STOP_WAYS, ids=[how for how, _ in STOP_WAYS])
def test_servo_app_replay_interrupted_pauses_the_arm_on_its_path(rig: Rig, tmp_path: Path, how: str,
                                                                 sig: int) -> None:
    """Ctrl-C or SIGTERM while ``servo-app replay`` follows its replay: the arm pauses along the path
    (a soft stop, resumable) and the command exits 130 saying so, however it was started."""
    at_home(rig)
    t = np.linspace(0.0, 1.0, 1000)[:, None]  # 8 s at the recorded pace
    rows = np.array(HOME) + np.hstack([15.0 * t, np.zeros((1000, 4)), -15.0 * t])
    csv = tmp_path / "long.csv"
    write_joint_csv(csv, rows)
    proc = start_replay(rig, csv, how)
    try:
        rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "playing" and not s["at_rest"], 30.0,
                 "the replay playing")
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 130, out + err
    assert "interrupted: the arm pauses along the path" in err, err
    s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 10.0, "paused")
    assert s["trajectory"]["state"] == "paused", s["trajectory"]
    assert not np.allclose(s["q_cmd"][:6], rows[-1], atol=1e-3)  # stopped on the way, not at the end
    assert rig.sim_alarms() == []


@pytest.mark.parametrize(("how", "sig"), STOP_WAYS, ids=[how for how, _ in STOP_WAYS])
def test_servo_app_replay_interrupted_before_its_replay_plays_exits_130(rig: Rig, tmp_path: Path, how: str,
                                                                        sig: int) -> None:
    """Ctrl-C or SIGTERM while ``servo-app replay`` takes over a moving arm (before it sent its replay):
    the handlers were set only once the replay played, so SIGTERM ended the command by its default
    (-15) and Ctrl-C with a traceback; an interrupt in the last moment before the replay (seen under
    load) left the arm playing with no one following. Now it exits 130 whenever it comes, and no replay
    plays on."""
    h = at_home(rig)
    rig.post("/api/target", h, {"joints": [HOME[0] + 40.0, *HOME[1:]], "speed_scale": 0.05})
    rig.wait(lambda s: not s["at_rest"], 10.0, "moving under the old holder")
    t = np.linspace(0.0, 1.0, 200)[:, None]
    rows = np.array(HOME) + np.hstack([10.0 * t, np.zeros((200, 5))])
    csv = tmp_path / "short.csv"
    write_joint_csv(csv, rows)
    proc = start_replay(rig, csv, how)
    try:
        # The take-over done: the command now stops the arm, resumes and waits for it to settle.
        deadline = time.monotonic() + 30.0
        while rig.http.get("/api/lease", headers=AUTH).json().get("client") != "servo-app replay":
            assert proc.poll() is None and time.monotonic() < deadline, "servo-app replay took no lease"
            time.sleep(0.01)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 130, (proc.returncode, out + err)
    assert "Traceback" not in err, err
    assert re.search(r"interrupted (before the replay was sent: nothing replayed|: the arm pauses along)", err), err
    s = rig.wait(lambda s: s["at_rest"], 20.0, "at rest")
    assert (s.get("trajectory") or {}).get("state") != "playing", s["trajectory"]
    assert rig.sim_alarms() == []


def test_servo_app_replay_exits_1_when_the_arm_is_stopped_from_elsewhere(rig: Rig, tmp_path: Path) -> None:
    """Another client stops the arm during ``servo-app replay``: the replay pauses on its path and the
    command exits 1 at once, saying why and how to continue (it waited for --timeout)."""
    at_home(rig)
    t = np.linspace(0.0, 1.0, 1000)[:, None]  # 8 s at the recorded pace
    rows = np.array(HOME) + np.hstack([15.0 * t, np.zeros((1000, 4)), -15.0 * t])
    csv = tmp_path / "long.csv"
    write_joint_csv(csv, rows)
    proc = subprocess.Popen([sys.executable, "-m", "servo_app.cli", "replay", str(csv), "--url", rig.base_url,
                             "--token", TOKEN, "--take-over", "--timeout", "120"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "playing" and not s["at_rest"], 30.0,
                 "the replay playing")
        assert rig.http.post("/api/session/stop", headers=AUTH).status_code == 200
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 1, out + err
    assert "the arm was stopped" in err and "paused at" in err and "POST /api/session/resume" in err, err
    assert rig.state()["trajectory"]["state"] == "paused"
    assert rig.sim_alarms() == []


def test_the_client_records_a_jog_and_replays_it(rig: Rig) -> None:
    at_home(rig)
    with ServoClient(rig.base_url, TOKEN, take_over=True) as arm:
        arm.ensure_streaming()
        with arm.record() as rec:
            arm.jog_joints([0.0, 8.0, 0.0, -10.0, 0.0, 10.0], duration=0.8)  # released: waits for rest
        jogged = arm.state().joints
        assert jogged is not None and rec.end_unix is not None
        arm.move_joints(HOME)
        summary = arm.replay(**rec.window)
        assert summary["samples"] > 10
        s = arm.state()
        assert s.joints is not None and np.allclose(s.joints[:6], jogged[:6], atol=1e-3)
    assert rig.sim_alarms() == []


def test_the_janome_backend_refuses_a_trajectory_by_name(tmp_path: Path) -> None:
    with running_janome_rig(tmp_path) as (janome, _):
        h = janome.lease()
        r = janome.http.post("/api/trajectory", json={"joints": [[0.0, 0.0, 0.0, 0.0]]}, headers=h)
        assert r.status_code == 422 and "not supported by the Janome backend" in r.text, r.text


def _scaled(tables: LimitTables, factor: float) -> LimitTables:
    """The same tables with every acceleration and jerk stage times ``factor`` (a controller that is
    stricter than the profile's defaults)."""
    def axis(t: AxisTable) -> AxisTable:
        return AxisTable(tuple(v * factor for v in t.no_payload), tuple(v * factor for v in t.max_payload))

    vel, acc, jerk = tables.tables
    return replace(tables, tables=(vel, tuple(axis(t) for t in acc), tuple(axis(t) for t in jerk)))


def test_a_replay_keeps_the_controllers_own_tables_when_they_are_tighter(rig: Rig, tmp_path: Path) -> None:
    """The plan is timed for the tables the controller sent at the stream's start, not the profile's:
    against a controller whose acceleration and jerk limits are 0.3 of the defaults the same waypoints
    take longer and still replay to the end with zero alarms (planned for the defaults, they would ask
    for more than this controller allows)."""
    waypoints = [[25.0, 15.0, -5.0, 10.0, -70.0, 30.0], [-20.0, 5.0, -15.0, -10.0, -90.0, -20.0]]
    h = at_home(rig)
    r = rig.http.post("/api/trajectory", headers=h, json={"joints": waypoints})
    assert r.status_code == 200, r.text
    default_duration = r.json()["detail"]["duration_s"]
    rig.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 20.0, "done")

    tight = _scaled(default_tables(load_profile("lrmate200id")), 0.3)
    with running_rig(tmp_path, sim_options={"tables": tight}) as strict:
        h = at_home(strict)
        assert strict.state()["tables_from_controller"]
        r = strict.http.post("/api/trajectory", headers=h, json={"joints": waypoints})
        assert r.status_code == 200, r.text
        assert r.json()["detail"]["duration_s"] > 1.2 * default_duration
        s = strict.wait(lambda s: (s.get("trajectory") or {}).get("state") == "done" and s["at_rest"], 30.0,
                        "the replay done")
        assert np.allclose(s["q_cmd"][:6], waypoints[-1], atol=1e-3)
        assert strict.sim_alarms() == []


def test_a_log_window_where_the_arm_rested_is_refused_naming_it_and_where_the_log_moves(rig: Rig) -> None:
    """A window of a log in which the arm was at rest, where it rests now: nothing to replay. The
    refusal said only "the path does not move"; it names the window and where in the log the arm
    moves, and changes nothing."""
    h = at_home(rig)
    s = np.linspace(0.0, 1.0, 126)[:, None]  # 1 s at rest at HOME, 1 s to HOME + 10 deg on J1, 1 s at rest
    move = HOME + (10 * s**3 - 15 * s**4 + 6 * s**5) * np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    rows = np.vstack([np.tile(HOME, (125, 1)), move, np.tile(move[-1], (125, 1))])
    name = "session-resting-then-moving.srvlog"
    w = SessionLogWriter(rig.service.cfg.log_dir / name,
                         {"model": "lrmate200id", "interval_ms": 8.0, "protocol": "fanuc-j519-v1"})
    for i, q in enumerate(rows):
        w.command(i * 0.008, i + 1, int(i == len(rows) - 1), 1, 0, 100.0, tuple(q))
    w.close()
    before = rig.state()
    r = rig.http.post("/api/trajectory", headers=h, json={"log": name, "from_s": 0.0, "to_s": 0.9})
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert f"log={name!r} from_s=0..to_s=0.9: nothing to replay" in detail, detail
    assert "at rest at [0.0, 10.0, -10.0, 0.0, -80.0, 0.0]" in detail, detail
    assert "the log moves between 1.000 and 2.000 s (of 0..3.000 s)" in detail and "from_s, to_s" in detail, detail
    after = rig.state()
    assert after["state"] == "streaming" and after["q_cmd"] == before["q_cmd"]
    assert after["trajectory"] == before["trajectory"]
