"""The disk fills up mid-jog, end to end: `servo-app run` (API, servo process, embedded simulator) with its
var directory on a small disk of its own (tests/small_disk.py), filled to its last byte by another
process while a Cartesian jog runs over REST. The service must end the stream itself (a soft stop, then
last data: the controller raises no alarm), log every record of it, say why, refuse a start until there
is room again, and start again once there is, all without a restart."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from small_disk import fill, free, launch, read, unavailable
from test_api_harness import assert_came_to_rest, assert_log_complete, wait_healthy

from servo_app.session_log import SessionLog, read_session_log

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120),
              pytest.mark.skipif(unavailable() is not None, reason=str(unavailable()))]

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "disk-full-test"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait(c: httpx.Client, pred: Callable[[dict[str, Any]], bool], what: str, timeout: float = 15.0
         ) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while True:
        s = c.get("/api/state").json()
        if pred(s):
            return s
        if time.monotonic() > deadline:
            raise AssertionError(f"not {what} within {timeout} s: {s['state']} ({s.get('stop_reason')})")
        time.sleep(0.02)


@pytest.fixture
def service(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], httpx.Client, Path]]:
    yield from run_service(tmp_path)


@pytest.fixture
def service_with_mcap(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], httpx.Client, Path]]:
    yield from run_service(tmp_path, "--mcap")


def run_service(tmp_path: Path, *extra: str) -> Iterator[tuple[subprocess.Popen[str], httpx.Client, Path]]:
    var = tmp_path / "var"
    var.mkdir()
    port = free_port()
    p = launch(var, 4096, [sys.executable, "-m", "servo_app.cli", "run", "--http-port", str(port), "--token", TOKEN,
                           "--var-dir", str(var), "--interval-ms", "8", *extra],
               env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    c = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10)
    try:
        wait_healthy(c, p)
        yield p, c, var
    finally:
        c.close()
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
        out, _ = p.communicate(timeout=30)
        print(out[-3000:])


def jog_until(c: httpx.Client, h: dict[str, str], done: threading.Event) -> None:
    """Cartesian jogs over REST at 20 Hz (+-X 40 mm/s, flipping every second) until ``done``; refusals
    (the stream ending under it) are what a client sees then, not errors."""
    t0 = time.monotonic()
    n = 0
    while not done.is_set():
        n += 1
        if n % 40 == 0:
            c.post("/api/lease/renew", headers=h)
        sign = 1.0 if int(time.monotonic() - t0) % 2 == 0 else -1.0
        c.post("/api/jog", headers=h, json={"linear": [40.0 * sign, 0, 0], "angular": [0, 0, 0], "frame": "base",
                                            "hold_ms": 200})
        done.wait(0.05)


def lease(c: httpx.Client) -> dict[str, str]:
    """The headers of requests under a new lease."""
    return {**AUTH, "X-Lease-Id": c.post("/api/lease", json={"client": "disk-test"}, headers=AUTH).json()["lease_id"]}


def fill_mid_jog(p: subprocess.Popen[str], c: httpx.Client, h: dict[str, str], var: Path,
                 pred: Callable[[dict[str, Any]], bool], what: str) -> dict[str, Any]:
    """Start a stream, jog it (jog_until), fill the disk once the arm moves, and return the first state
    that satisfies ``pred`` (``what``), the jog stopped."""
    assert c.post("/api/session/start", headers=h).status_code == 200
    wait(c, lambda s: s["state"] == "streaming", "streaming")
    done = threading.Event()
    jogger = threading.Thread(target=jog_until, args=(httpx.Client(base_url=str(c.base_url), timeout=10), h, done))
    jogger.start()
    try:
        wait(c, lambda s: s["state"] == "streaming" and max(map(abs, s["vel"])) > 2.0, "jogging")
        fill(p.pid, var / "filler")  # another process takes the disk's last byte
        return wait(c, pred, what)
    finally:
        done.set()
        jogger.join()


def newest_log(c: httpx.Client, var: Path) -> SessionLog:
    name = max((s["name"] for s in c.get("/api/sessions").json()), key=lambda n: n)
    r = c.get(f"/api/sessions/{name}")
    assert r.status_code == 200, r.text
    path = var.parent / name  # (outside the small disk: the test's own)
    path.write_bytes(r.content)
    return read_session_log(path)


def test_a_disk_filling_up_mid_jog_ends_the_stream_softly_logged_whole_and_recovers(
        service: tuple[subprocess.Popen[str], httpx.Client, Path]) -> None:
    p, c, var = service
    h = lease(c)
    s = fill_mid_jog(p, c, h, var, lambda s: s["state"] == "ended", "ended")
    assert s["stop_reason"].startswith("session log: the disk is full: No space left on device"), s["stop_reason"]
    assert any(w["code"] == "SESSION-LOG" for w in s["warnings"]), s["warnings"]
    assert not [a for a in s.get("alarm_history") or [] if a["code"] != "SESSION-LOG"], s["alarm_history"]

    # The stream's stop and end are in the log, every command of them: the reserve took them.
    log = newest_log(c, var)
    assert_log_complete(log, ended=True)
    assert_came_to_rest(log, 0.008)

    # No room for a new log: the start is refused, naming why and what to do, and nothing changes.
    r = c.post("/api/session/start", headers=h)
    assert r.status_code == 409, r.text
    detail = r.json()["detail"]
    assert "session log cannot be opened" in detail and "free disk space there, then start again" in detail, detail
    assert c.get("/api/state").json()["state"] == "ended"

    # Room again: the same service starts a new stream and ends it cleanly.
    free(p.pid, var / "filler")
    assert c.post("/api/session/start", headers=h).status_code == 200
    wait(c, lambda s: s["state"] == "streaming", "streaming again")
    assert c.post("/api/session/end", headers=h).status_code == 200
    s = wait(c, lambda s: s["state"] == "ended" and s["link"] == "closed", "ended again")
    assert s["stop_reason"] == "end requested"
    assert_log_complete(newest_log(c, var), ended=True, min_records=3)
    assert p.poll() is None
    # The audit log lost the lines of the full disk's requests, not their answers, and says how many.
    lines = [json.loads(line) for line in read(p.pid, var / "audit.log").splitlines()]  # (none torn)
    dropped = [a for a in lines if a["action"] == "audit.dropped"]
    assert len(dropped) == 1 and "lines not written" in dropped[0]["detail"], dropped


def test_a_full_disk_refuses_a_points_change_409_and_keeps_the_file(
        service: tuple[subprocess.Popen[str], httpx.Client, Path]) -> None:
    p, c, var = service
    h = lease(c)
    assert c.post("/api/session/start", headers=h).status_code == 200
    wait(c, lambda s: s["state"] == "streaming" and s["settled"], "streaming, settled")
    assert c.post("/api/points/kept", headers=h).status_code == 200
    before = read(p.pid, var / "points.json")
    fill(p.pid, var / "filler")
    # The points file is rewritten whole for a change: on a full disk that is refused (was a 500), naming
    # the file, the reason and what to do, and the old file stands.
    r = c.delete("/api/points/kept", headers=h)
    assert r.status_code == 409, r.text
    detail = r.json()["detail"]
    assert "points.json cannot be written (No space left on device)" in detail, detail
    assert detail.endswith("free disk space in " + str(var) + " (or make it writable), then try again"), detail
    assert [pt["name"] for pt in c.get("/api/points").json()] == ["kept"]
    assert read(p.pid, var / "points.json") == before
    listing = subprocess.run(["nsenter", "--target", str(p.pid), "--mount", "--", "ls", "-A", str(var)],
                             capture_output=True, text=True, check=True).stdout.split()
    assert not [n for n in listing if n.startswith(".points-")], listing  # no temporary file left behind
    free(p.pid, var / "filler")
    assert c.delete("/api/points/kept", headers=h).status_code == 200
    assert c.get("/api/points").json() == []
    assert p.poll() is None


def test_a_live_mcap_cut_short_by_a_full_disk_is_told_to_the_operator(
        service_with_mcap: tuple[subprocess.Popen[str], httpx.Client, Path]) -> None:
    """servo-app run --mcap: the disk fills mid-jog; the live MCAP beside the session log cannot be
    finished. Before, only a log line said so; now the state's alarms and mcap_error name the file, the
    cause and the export that converts the complete .srvlog, and /metrics counts it."""
    p, c, var = service_with_mcap
    h = lease(c)
    s = fill_mid_jog(p, c, h, var, lambda s: s["state"] == "ended" and s.get("mcap_error") is not None,
                     "ended, MCAP stopped")
    name = max(x["name"] for x in c.get("/api/sessions").json())
    err = s["mcap_error"]
    assert err["file"].endswith(name.removesuffix(".srvlog") + ".mcap"), err
    assert err["error"] == "No space left on device", err
    assert f"servo-app export {err['file'].removesuffix('.mcap')}.srvlog --mcap {err['file']}" in err["remedy"], err
    warned = [a for a in s["alarms"] if a["code"] == "MCAP-LIVE"]
    assert len(warned) == 1 and warned[0]["warning"], s["alarms"]
    assert name.removesuffix(".srvlog") + ".mcap" in warned[0]["message"], warned
    assert "No space left on device" in warned[0]["message"] and "servo-app export" in warned[0]["remedy"], warned
    assert any(a["code"] == "MCAP-LIVE" for a in s["alarm_history"]), s["alarm_history"]
    assert 'servo_alarms_total{code="MCAP-LIVE"} 1.0' in c.get("/metrics").text

    # Room again: the next session's live MCAP is written whole, and mcap_error, which named the first
    # file for as long as the service ran, is cleared (the warning stays in the alarm history).
    free(p.pid, var / "filler")
    assert c.post("/api/session/start", headers=h).status_code == 200
    wait(c, lambda s: s["state"] == "streaming", "streaming again")
    assert c.get("/api/state").json()["mcap_error"] == err  # the new one is not whole yet
    assert c.post("/api/session/end", headers=h).status_code == 200
    s = wait(c, lambda s: s["state"] == "ended" and s["mcap_error"] is None, "ended, mcap_error cleared")
    assert any(a["code"] == "MCAP-LIVE" for a in s["alarm_history"]), s["alarm_history"]
