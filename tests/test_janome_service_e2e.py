"""`servo-app run --robot janome` as a process, with its embedded robot (the point-job simulator in a
process of its own): signals to the group and to the simulator, with real sockets on loopback."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import time
from pathlib import Path

import httpx
import pytest
from test_api_harness import AUTH, Rig, running_rig
from test_fault_matrix_e2e import _serve, alive, children_of, eventually, no_children_left

from servo_app.service.config import MIN_SERVO_STALL_S, ServiceConfig

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
        h = rig.lease()  # the robot's restart can outlast the lease's 10 s under load
        s0 = rig.start_streaming(h)
        rig.jog_for(h, [40.0, 0.0, 0.0, 0.0], 0.6, hold_ms=500)
        s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 10.0, "hold-to-run stop")
        assert s["q_cmd"][0] > s0["q_cmd"][0] + 2.0, (s0["q_cmd"], s["q_cmd"])
    no_children_left()


def test_janome_servo_process_stalled_is_ended_and_replaced(tmp_path: os.PathLike[str]) -> None:
    """SIGSTOP to the Janome servo process mid-jog (alive, listening, but running no cycle): after the
    stall time the state names the fault, the service ends that process by itself, and a reset starts
    a new one where the embedded robot connects again; SIGCONT to the old one finds nothing; a new
    stream moves the arm. (The FANUC case: tests/test_fault_matrix_e2e.py.)"""
    with running_rig(tmp_path, robot="janome") as rig:  # type: ignore[arg-type]
        stall_s = rig.service.cfg.servo_stall_s
        h = rig.lease()
        rig.wait_state("ready", timeout=30)
        rig.start_streaming(h)
        rig.jog_for(h, [40.0, 0.0, 0.0, 0.0], 0.4, hold_ms=500)
        pid = rig.service.stream.pid  # type: ignore[union-attr]
        assert pid is not None
        t_stop = time.monotonic()
        os.kill(pid, signal.SIGSTOP)
        try:
            s = rig.wait_state("fault", timeout=stall_s + 10.0)
            assert time.monotonic() - t_stop >= stall_s
            assert s["fault"]["message"].startswith("servo process stalled: it ran no cycle for"), s["fault"]
            assert s["servo_process"].startswith("stalled"), s["servo_process"]
            r = rig.post("/api/jog", h, json={"joints": [40.0, 0.0, 0.0, 0.0]}, expect=409)
            assert "stalled" in r.json()["detail"] and "POST /api/reset" in r.json()["detail"], r.text
            assert eventually(lambda: not alive(pid), timeout=5.0), "the stalled process was not ended"
            rig.post("/api/reset", h)
            s = rig.wait_state("ready", timeout=30)  # the robot's point job connected to the new process
            assert s["fault"] is None and s["servo_process"] == "running" and s["servo_starts"] == 2, s
            assert rig.service.stream.pid != pid  # type: ignore[union-attr]
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        h = rig.lease()  # the stall, the reset and the new process's start can outlast the lease's 10 s under load
        s0 = rig.start_streaming(h)
        rig.jog_for(h, [40.0, 0.0, 0.0, 0.0], 0.6, hold_ms=500)
        s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 10.0, "hold-to-run stop")
        assert s["q_cmd"][0] > s0["q_cmd"][0] + 2.0, (s0["q_cmd"], s["q_cmd"])
        assert s["fault"] is None and s["servo_starts"] == 2, s
    no_children_left()


def _no_stall_for(rig: Rig, seconds: float, pid: int) -> None:
    """For ``seconds``: never a fault, the same servo process, running."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        s = rig.state()
        assert s["fault"] is None and s["servo_process"] == "running", s
        assert rig.service.stream.pid == pid and s["servo_starts"] == 1, s  # type: ignore[union-attr]
        time.sleep(0.05)


@pytest.mark.parametrize("robot", ["connected", "absent"])
def test_an_idle_janome_servo_process_is_not_taken_as_stalled(tmp_path: os.PathLike[str], robot: str) -> None:
    """Idle for 3x the stall time, with the robot's point job connected (ready, then streaming with no
    motion, then stopped) or with no robot at all (disconnected, waiting for its connection): the
    Janome servo process keeps publishing (every ~50 ms), so it is never faulted or ended, also at the
    shortest stall time allowed."""
    robot_arg = "janome" if robot == "connected" else "janome:127.0.0.1:0"  # (a port nobody connects to)
    ctx = running_rig(tmp_path, robot=robot_arg, servo_stall_s=MIN_SERVO_STALL_S)  # type: ignore[arg-type]
    with ctx as rig:
        stall_s = rig.service.cfg.servo_stall_s
        pid = rig.service.stream.pid  # type: ignore[union-attr]
        assert pid is not None
        if robot == "absent":
            assert rig.state()["state"] == "disconnected"
            _no_stall_for(rig, 3 * stall_s, pid)
            assert rig.state()["state"] == "disconnected"
            return
        h = rig.lease()
        rig.wait_state("ready", timeout=30)
        _no_stall_for(rig, 3 * stall_s, pid)
        rig.start_streaming(h)
        _no_stall_for(rig, 3 * stall_s, pid)
        rig.post("/api/session/stop", h)
        rig.wait_state("stopped")
        _no_stall_for(rig, 3 * stall_s, pid)
        rig.end_and_wait(h)
    no_children_left()


def listener_pid(pids: list[int], port: int) -> int:
    """Which of ``pids`` listens on TCP ``port`` (from /proc: the socket's inode among its files)."""
    inodes = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        f = line.split()
        if f[3] == "0A" and int(f[1].rsplit(":", 1)[1], 16) == port:  # 0A: LISTEN
            inodes.add(f"socket:[{f[9]}]")
    for pid in pids:
        with contextlib.suppress(OSError):
            if any(os.readlink(fd) in inodes for fd in Path(f"/proc/{pid}/fd").iterdir()):
                return pid
    raise AssertionError(f"none of {pids} listens on port {port}")


def test_run_with_a_servo_stall_time_uses_it(tmp_path: os.PathLike[str]) -> None:
    """`servo-app run --servo-stall-s 2.5`: a SIGSTOPped servo process is taken as stalled after 2.5 s,
    not the default 1 s, and the fault names that stall time; the idle process before it never was."""
    proc, base, err = _serve(["--robot", "janome", "--servo-stall-s", "2.5"], tmp_path)  # type: ignore[arg-type]
    pid = None
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # "servo_app: ... via embedded simulator at HOST:PORT; console ..."
        found = re.search(r" at [\d.]+:(\d+);", line)
        assert found, line
        with httpx.Client(base_url=base, timeout=5) as c:
            assert eventually(lambda: c.get("/api/state").json()["state"] == "ready", timeout=30)
            h = {**AUTH, "X-Lease-Id": c.post("/api/lease", json={"client": "ops"}, headers=AUTH).json()["lease_id"]}
            assert c.post("/api/session/start", headers=h).status_code == 200
            assert c.post("/api/jog", json=JOG, headers=h).status_code == 200
            pid = listener_pid(children_of(proc.pid), int(found.group(1)))
            t_stop = time.monotonic()
            os.kill(pid, signal.SIGSTOP)
            assert eventually(lambda: c.get("/api/state").json()["state"] == "fault", timeout=20)
            assert time.monotonic() - t_stop >= 2.5  # the default (1 s) faulted at ~1.1 s
            message = c.get("/api/state").json()["fault"]["message"]
            quiet = re.fullmatch(r"servo process stalled: it ran no cycle for ([\d.]+) s "
                                 r"\(stall time 2\.5 s, servo-app run --servo-stall-s\)", message)
            assert quiet and float(quiet.group(1)) >= 2.5, message
            assert eventually(lambda: not alive(pid), timeout=5.0), "the stalled process was not ended"  # type: ignore[arg-type]
            assert c.post("/api/reset", headers=h).status_code == 200
            assert eventually(lambda: c.get("/api/state").json()["state"] == "ready", timeout=30)
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=30)
    finally:
        if pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)
    assert code == 0, proc.stdout.read() + "".join(err)
    assert "Traceback" not in "".join(err), "".join(err)


@pytest.mark.parametrize("value", [0.1, 0.0, -1.0, float("inf"), float("nan")])
def test_a_stall_time_too_short_or_not_finite_is_refused(value: float) -> None:
    """Below 0.5 s an idle Janome process (publishing every ~50 ms, 125 ms seen) or a busy machine
    would be taken as stalled and ended; the refusal names the setting, its value and what to give."""
    with pytest.raises(ValueError, match=r"servo_stall_s=.*: give a number of seconds of at least 0\.5"):
        ServiceConfig(servo_stall_s=value)
