"""Fault injection end to end (issue 5.5): the simulator misbehaves on the wire, clients misbehave at
the API, the process is signalled mid-motion. Each case ends with the arm at rest after a controlled
deceleration, or in fault with the controller's code; the service itself causes no alarm; the
session log is complete (no gap in the command sequence, status records present)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from test_api_harness import (
    AUTH,
    TOKEN,
    Rig,
    assert_came_to_rest,
    assert_log_complete,
    running_rig,
    wait_healthy,
)

from servo_app.session_log import SessionLog, read_session_log
from servo_app.sim.fanuc_server import FaultConfig

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

ROOT = Path(__file__).resolve().parents[1]
INTERVAL_S = 0.008


def drive(rig: Rig, h: dict[str, str], seconds: float) -> None:
    """Jog two joints out and back, renewing the hold-to-run every 50 ms."""
    rig.jog_for(h, [25.0, 0, 0, 40.0, 0, 0], seconds / 2)
    rig.jog_for(h, [-25.0, 0, 0, -40.0, 0, 0], seconds / 2)


def finish(rig: Rig, h: dict[str, str]) -> tuple[dict[str, Any], SessionLog]:
    """End the stream; the log must be complete, the arm at rest, the controller without alarms."""
    s = rig.end_and_wait(h)
    assert s["link"] == "closed"
    log = rig.latest_log()
    assert_log_complete(log, ended=True)
    assert_came_to_rest(log, INTERVAL_S)
    assert rig.sim_alarms() == [], rig.sim_alarms()
    return s, log


def status_gaps(log: SessionLog) -> int:
    seq = log.statuses["seq"].astype(np.int64)
    d = np.diff(seq)
    return int(np.sum(d[d > 1] - 1))


# --------------------------------------------------------------------------------- the wire


@pytest.mark.parametrize("drop", [0.01, 0.05])
def test_status_loss_is_ridden_out_with_the_default_lead(tmp_path: Path, drop: float) -> None:
    with running_rig(tmp_path, sim_options={"faults": FaultConfig(drop_prob=drop, seed=11)}) as rig:
        assert rig.service.cfg.lead == 2
        h = rig.lease()
        rig.start_streaming(h)
        drive(rig, h, 3.0)
        s = rig.state()
        assert s["state"] in ("streaming", "stopping", "stopped"), s["fault"]
        _, log = finish(rig, h)
        print(f"drop {drop:.0%}: {s['status_lost']} lost of {s['status_received']} received, "
              f"late commands {s['late_commands']}, p99 {s['latency_p99_us']:.0f} us")
        assert status_gaps(log) >= s["status_lost"] - 2  # the log shows the gaps the session counted
        if drop >= 0.05:
            assert s["status_lost"] > 0


def test_status_loss_with_no_lead_faults_with_the_controllers_code(tmp_path: Path) -> None:
    """lead 0: a lost status packet leaves the controller without a command (MOTN-603). The service
    must end in fault carrying that code with the manual's cause and remedy, not hang or hide it."""
    with running_rig(tmp_path, lead=0, sim_options={"faults": FaultConfig(drop_prob=0.05, seed=3)}) as rig:
        h = rig.lease()
        rig.post("/api/session/start", h)
        # A packet lost in the first cycles faults the stream before it is seen streaming: either will do.
        rig.wait(lambda s: s["state"] in ("streaming", "fault"), 10.0, "streaming (or already the fault)")
        deadline = time.monotonic() + 10
        while rig.state()["state"] != "fault" and time.monotonic() < deadline:
            rig.jog_for(h, [20.0, 0, 0, 0, 0, 0], 0.2)
        s = rig.wait(lambda s: s["state"] == "fault" and (s["fault"] or {}).get("code") == "MOTN-603", 3.0,
                     "fault with MOTN-603")
        assert s["fault"]["cause"] and s["fault"]["remedy"]
        assert rig.sim_alarms() == ["MOTN-603"]
        assert any(a["code"] == "MOTN-603" and a["remedy"] for a in s["alarms"])
        log = rig.latest_log()
        assert_log_complete(log, ended=False, min_records=1)


def test_interval_jitter_6_to_10_ms(tmp_path: Path) -> None:
    with running_rig(tmp_path, sim_options={"faults": FaultConfig(jitter_s=0.001, seed=5)}) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        drive(rig, h, 2.0)
        s = rig.state()
        _, log = finish(rig, h)
        st = log.statuses
        consecutive = np.diff(st["seq"].astype(np.int64)) == 1
        dt_ms = np.diff(st["t"])[consecutive] * 1000
        print(f"jitter: status intervals {dt_ms.min():.2f}..{dt_ms.max():.2f} ms (p1 {np.percentile(dt_ms, 1):.2f}, "
              f"p99 {np.percentile(dt_ms, 99):.2f}), late commands {s['late_commands']}")
        assert np.percentile(dt_ms, 1) < 7.0 and np.percentile(dt_ms, 99) > 9.0  # the jitter was there


def test_duplicated_status_packets_are_ignored(tmp_path: Path) -> None:
    with running_rig(tmp_path, sim_options={"faults": FaultConfig(dup_prob=0.1, seed=9)}) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        drive(rig, h, 2.0)
        s = rig.state()
        finish(rig, h)
        print(f"duplicates: {s['status_duplicated']} ignored")
        assert s["status_duplicated"] > 0


def test_delayed_status_packets(tmp_path: Path) -> None:
    faults = FaultConfig(delay_prob=0.05, delay_range_s=(0.002, 0.020), seed=13)
    with running_rig(tmp_path, sim_options={"faults": faults}) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        drive(rig, h, 3.0)
        s = rig.state()
        finish(rig, h)
        print(f"delays: {s['status_lost']} counted lost (overtaken), {s['status_duplicated']} late arrivals dropped")
        assert s["status_lost"] + s["status_duplicated"] > 0


def test_controller_alarm_mid_stream_is_a_fault_with_cause_and_remedy_then_reset(tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, [0, 0, 0, 30.0, 0, 0], 0.3, hold_ms=1000)
        rig.service.sim_call("set_override", 50)  # at the pendant, mid-stream: MOTN-606
        s = rig.wait(lambda s: s["state"] == "fault" and (s["fault"] or {}).get("code") == "MOTN-606", 3.0,
                     "fault with MOTN-606")
        assert "100% OVERRIDE" in s["fault"]["cause"].upper() and s["fault"]["remedy"]
        assert rig.sim_alarms() == ["MOTN-606"]
        log = rig.latest_log()
        assert_log_complete(log, ended=False)
        # Motion and start are refused in fault; reset needs the operator to fix the cause first.
        assert rig.http.post("/api/jog", json={"joints": [1.0, 0, 0, 0, 0, 0]}, headers=h).status_code == 409
        r = rig.http.post("/api/session/start", headers=h)
        assert r.status_code == 409 and "reset" in r.json()["detail"]
        rig.service.sim_call("set_override", 100)
        rig.post("/api/reset", h)
        s = rig.wait(lambda s: s["state"] == "ready", 5.0, "ready after reset")
        assert s["fault"] is None
        rig.start_streaming(h)
        rig.jog_for(h, [0, 0, 0, -30.0, 0, 0], 0.3)
        s = rig.end_and_wait(h)
        assert rig.sim_alarms() == ["MOTN-606"]  # nothing new
        assert_log_complete(rig.latest_log(), ended=True)


# ------------------------------------------------------------------------------- the clients


def test_a_sensor_sending_nan_is_refused_and_the_arm_stays_safe(tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, [15.0, 0, 0, 0, 0, 0], 0.3)
        jh = {**h, "Content-Type": "application/json"}
        # json.dumps writes NaN/Infinity as a sensor's JSON encoder would; the API must refuse them.
        for body, field in ((f'{{"joints": [0, {v}, 0, 0, 0, 0]}}', "joints[1]") for v in ("NaN", "Infinity")):
            r = rig.http.post("/api/jog", content=body, headers=jh)
            assert r.status_code == 422, r.text
            assert field in r.text and "not a finite number" in r.text, r.text
        r = rig.http.post("/api/jog", content='{"linear": [0, NaN, 0]}', headers=jh)
        assert r.status_code == 422 and "linear[1]" in r.text, r.text
        r = rig.http.post("/api/target", content='{"joints": [NaN, 0, 0, 0, 0, 0]}', headers=jh)
        assert r.status_code == 422 and "joints[0]" in r.text, r.text
        # The last good jog runs out: the arm decelerates to rest by itself.
        s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 3.0, "hold-to-run stop")
        assert s["stop_reason"] == "hold-to-run expired"
        assert all(np.isfinite(s["q_cmd"]))
        finish(rig, h)


# Runs in a process of its own (in this one it would share the GIL with the server it floods), on
# plain sockets: an HTTP client library costs more per request than the server does to refuse one.
FLOOD = """
import itertools, json, socket, sys, threading, time
port, lease, token, rate, seconds = int(sys.argv[1]), sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5])
body = json.dumps({"joints": [20.0, 0, 0, 0, 0, 0]}).encode()
req = (f"POST /api/jog HTTP/1.1\\r\\nHost: x\\r\\nAuthorization: Bearer {token}\\r\\nX-Lease-Id: {lease}\\r\\n"
       f"Content-Type: application/json\\r\\nContent-Length: {len(body)}\\r\\n\\r\\n").encode() + body
n, slots, out, t0 = int(rate * seconds), itertools.count(), [], time.monotonic()
def worker():
    s = socket.create_connection(("127.0.0.1", port))
    f = s.makefile("rb")
    for i in slots:
        if i >= n:
            return
        time.sleep(max(0.0, t0 + i / rate - time.monotonic()))
        s.sendall(req)
        code, length = int(f.readline().split()[1]), 0
        while (line := f.readline()) not in (b"\\r\\n", b""):
            if line.lower().startswith(b"content-length:"):
                length = int(line.split(b":")[1])
        f.read(length)
        out.append((time.monotonic() - t0, code))
threads = [threading.Thread(target=worker) for _ in range(16)]
for t in threads:
    t.start()
for t in threads:
    t.join()
print(json.dumps({"elapsed": time.monotonic() - t0, "results": out}))
"""


def test_500_jog_requests_per_second(tmp_path: Path) -> None:
    """Rate limiting holds and the cycle keeps its timing while the API is flooded."""
    with running_rig(tmp_path) as rig:
        h = rig.lease("flood")
        rig.start_streaming(h)
        before = rig.state()
        run = subprocess.run([sys.executable, "-c", FLOOD, str(rig.server.port), h["X-Lease-Id"], TOKEN, "500", "2.0"],
                             capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        flood = json.loads(run.stdout)
        after = rig.state()
        elapsed, results = flood["elapsed"], flood["results"]
        codes = [c for _, c in results]
        # The limiter's clock, from the audit log: each accepted jog's line carries the time it was
        # admitted (written a reply time later).
        audit = [json.loads(x) for x in (rig.var_dir / "audit.log").read_text().splitlines()]
        ok_times = np.sort([x["t"] for x in audit if x["action"] == "jog" and x["ok"]
                            and x["client"].startswith("flood@")])  # lines are in completion order
        most = max(int(np.searchsorted(ok_times, t + 1.0) - i) for i, t in enumerate(ok_times))
        late = after["late_commands"] - before["late_commands"]
        print(f"flood: {len(codes)} jogs in {elapsed:.2f} s ({len(codes) / elapsed:.0f}/s offered): "
              f"{codes.count(200)} ok, {codes.count(429)} refused, at most {most} ok in 1 s; cycle latency "
              f"p50 {after['latency_p50_us']:.0f} us, p99 {after['latency_p99_us']:.0f} us, "
              f"max {after['latency_max_us']:.0f} us, late commands {late}")
        assert set(codes) <= {200, 429} and codes.count(429) > 0
        # A token bucket (100/s, a burst of 25 saved up): at most 100 + 25 in any one second.
        assert codes.count(200) <= 100 * (elapsed + 1.0) and most <= 125
        assert after["status_lost"] == 0 and rig.sim_alarms() == []
        assert after["q_cmd"][0] > before["q_cmd"][0] + 5.0  # the accepted jogs moved the arm
        finish(rig, h)


def test_two_clients_fighting_for_control(tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig, httpx.Client(base_url=rig.base_url, timeout=10.0) as other:
        a = rig.lease("alice", force=False)
        rig.start_streaming(a)
        # Bob has the token but not the lease: he can neither take it nor move the arm.
        r = other.post("/api/lease", json={"client": "bob"}, headers=AUTH)
        assert r.status_code == 409 and "alice" in r.json()["detail"]
        q0 = rig.state()["q_cmd"]
        for hdr in (AUTH, {**AUTH, "X-Lease-Id": "guess"}):
            r = other.post("/api/jog", json={"joints": [0, 30.0, 0, 0, 0, 0]}, headers=hdr)
            assert r.status_code == 409, r.text
        assert other.post("/api/target", json={"joints": [10.0, 0, 0, 0, -90, 0]}, headers=AUTH).status_code == 409
        assert rig.state()["q_cmd"] == q0
        # Alice moves J1; bob forces the lease mid-motion: the arm stops, alice is locked out.
        stop = threading.Event()

        def alice_holds_the_button() -> None:
            while not stop.is_set():
                rig.http.post("/api/jog", json={"joints": [20.0, 0, 0, 0, 0, 0]}, headers=a)
                time.sleep(0.04)

        t = threading.Thread(target=alice_holds_the_button, daemon=True)
        t.start()
        time.sleep(0.4)
        r = other.post("/api/lease", json={"client": "bob", "force": True}, headers=AUTH)
        assert r.status_code == 200
        b = {**AUTH, "X-Lease-Id": r.json()["lease_id"]}
        s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 3.0, "stopped after the takeover")
        stop.set()
        t.join(2)
        assert s["stop_reason"].startswith("control lease lost (alice)"), s["stop_reason"]
        q_alice = s["q_cmd"]
        assert q_alice[0] > q0[0] + 2.0
        r = rig.http.post("/api/jog", json={"joints": [20.0, 0, 0, 0, 0, 0]}, headers=a)
        assert r.status_code == 409
        time.sleep(0.1)
        assert rig.state()["q_cmd"] == q_alice
        # Bob resumes and moves J2: only his jog moves the arm.
        assert other.post("/api/session/resume", headers=b).status_code == 200
        for _ in range(8):
            assert other.post("/api/jog", json={"joints": [0, 20.0, 0, 0, 0, 0]}, headers=b).status_code == 200
            time.sleep(0.05)
        s = rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 3.0)
        assert abs(s["q_cmd"][0] - q_alice[0]) < 1e-6 and s["q_cmd"][1] > q_alice[1] + 2.0
        assert s["lease"]["client"] == "bob"
        audit = [json.loads(x) for x in (rig.var_dir / "audit.log").read_text().splitlines()]
        assert any(x["action"] == "jog" and x["client"].startswith("bob@") and x["ok"] for x in audit)
        assert any(x["action"] == "POST /api/jog" and not x["ok"] and "bob" in x["detail"] for x in audit)
        finish(rig, b)


# ------------------------------------------------------------------------------------ signals


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT-group"])
def test_signal_mid_motion_to_servo_app_run(tmp_path: Path, how: str) -> None:
    """`servo-app run` gets SIGTERM (or Ctrl-C, which reaches the whole process group) mid-motion:
    controlled stop, last data, status output off, exit code 0, no alarm line from the simulator."""
    port = _free_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "servo_app.cli", "run", "--http-port", str(port), "--var-dir", str(tmp_path),
         "--token", TOKEN], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)
    out: list[str] = []
    err: list[str] = []
    readers = [threading.Thread(target=lambda f=f, sink=sink: sink.extend(iter(f.readline, "")), daemon=True)
               for f, sink in ((proc.stdout, out), (proc.stderr, err))]
    for t in readers:
        t.start()
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        with httpx.Client(base_url=base, timeout=5.0) as c:
            wait_healthy(c, proc, 60.0, lambda: "".join(err))
            r = c.post("/api/lease", json={"client": "ops"}, headers=AUTH)
            h = {**AUTH, "X-Lease-Id": r.json()["lease_id"]}
            assert c.post("/api/session/start", headers=h).status_code == 200
            while c.get("/api/state").json()["state"] != "streaming":
                assert time.monotonic() < deadline
                time.sleep(0.02)
            assert c.post("/api/jog", json={"joints": [30.0, 0, 0, 0, 0, 0], "hold_ms": 2000},
                          headers=h).status_code == 200
            time.sleep(0.4)
            s = c.get("/api/state").json()
            assert s["vel"][0] > 10.0, s["vel"]  # moving
        if how == "SIGTERM":
            proc.send_signal(signal.SIGTERM)
        else:
            os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C in its terminal
        code = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
        for t in readers:
            t.join(5)
    stdout, stderr = "".join(out), "".join(err)
    assert code == 0, (stdout, stderr)
    alarm_lines = [line for line in stderr.splitlines() if line.startswith(("MOTN-", "PRIO-"))]
    assert alarm_lines == [], stderr
    assert "stream ended, link closed, servo process exit code 0, controller alarms []" in stdout, stdout
    (path,) = (tmp_path / "sessions").glob("*.srvlog")
    log = read_session_log(path)
    assert_log_complete(log, ended=True)
    assert_came_to_rest(log, INTERVAL_S)
    # After last data the controller cleared status bit 0; only then did the status output stop.
    assert log.statuses["flags"][-1] & 1 == 0
    assert log.statuses["t"][-1] > log.commands["t"][-1]
