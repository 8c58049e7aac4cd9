"""The command line, end to end: `servo-app sim fanuc` in one process, `servo-app run --robot` in another."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from test_api_harness import wait_healthy

pytestmark = pytest.mark.e2e
TOKEN = "cli-test-token"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def servo_app(*args: str, **kw: object) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "servo_app.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)  # type: ignore[call-overload]


def stop(p: subprocess.Popen[str]) -> tuple[int, str, str]:
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
    try:
        out, err = p.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        p.kill()
        out, err = p.communicate()
    return p.returncode, out, err


def wait_state(c: httpx.Client, pred: Callable[[dict[str, Any]], bool], what: str,
               timeout: float = 20.0) -> dict[str, Any]:
    """The first /api/state for which ``pred`` holds; fails naming ``what`` and the last state."""
    deadline = time.monotonic() + timeout
    while True:
        s = c.get("/api/state").json()
        if pred(s):
            return s
        assert time.monotonic() < deadline, f"not {what} within {timeout} s: {s}"
        time.sleep(0.02)


@pytest.fixture
def sim() -> Iterator[tuple[subprocess.Popen[str], int]]:
    p = servo_app("sim", "fanuc", "--port", "0", "--joints", "0,0,0,0,-90,0")
    assert p.stdout is not None
    line = p.stdout.readline()
    m = re.search(r"udp://[\d.]+:(\d+)", line)
    assert m, line
    yield p, int(m.group(1))
    stop(p)


def test_run_against_an_external_simulator_process(sim: tuple[subprocess.Popen[str], int], tmp_path: Path) -> None:
    sim_proc, udp_port = sim
    http = free_port()
    run = servo_app("run", "--robot", f"fanuc:127.0.0.1:{udp_port}", "--model", "lrmate200id", "--http-port",
                    str(http), "--var-dir", str(tmp_path), "--token", TOKEN, env={**os.environ})
    base = f"http://127.0.0.1:{http}"
    try:
        with httpx.Client(base_url=base, timeout=5) as c:
            wait_healthy(c, run, timeout=30.0)
            auth = {"Authorization": f"Bearer {TOKEN}"}
            lease = c.post("/api/lease", json={"client": "cli-test"}, headers=auth).json()["lease_id"]
            hdr = {**auth, "X-Lease-Id": lease}
            assert c.post("/api/session/start", headers=hdr).status_code == 200
            state = wait_state(c, lambda s: s["state"] == "streaming", "streaming")
            assert state["state"] == "streaming" and state["simulated"] is False
            assert state["robot"] == f"127.0.0.1:{udp_port}"
            r = c.post("/api/target", json={"joints": [15, 5, -5, 10, -80, 20], "speed_scale": 0.5}, headers=hdr)
            assert r.status_code == 200, r.text
            s = wait_state(c, lambda s: s["at_rest"] and abs(s["q_cmd"][0] - 15) < 1e-3, "at rest at J1 15")
            assert abs(s["q_servo"][0] - 15) < 0.5  # the external controller followed
            assert c.post("/api/session/end", headers=hdr).status_code == 200
            wait_state(c, lambda s: s["state"] == "ended", "ended")
    finally:
        code, run_out, run_err = stop(run)
        _, _, sim_err = stop(sim_proc)
    assert code == 0, run_err
    assert re.search(r"API event loop (SCHED_FIFO 5|unavailable)", run_out), run_out  # feed samples handled first
    alarms = [line for line in sim_err.splitlines() if re.match(r"(MOTN|PRIO)-\d+", line)]
    assert alarms == [], alarms


def test_run_janome_with_its_embedded_simulator_through_rest(tmp_path: Path) -> None:
    """Issue 8 through the API: start, jog, stop, end against the embedded Janome point-job simulator."""
    http = free_port()
    run = servo_app("run", "--robot", "janome", "--model", "jr3000", "--http-port", str(http), "--var-dir",
                    str(tmp_path), "--token", TOKEN)
    base = f"http://127.0.0.1:{http}"
    try:
        with httpx.Client(base_url=base, timeout=5) as c:
            wait_healthy(c, run, timeout=30.0)
            auth = {"Authorization": f"Bearer {TOKEN}"}
            lease = c.post("/api/lease", json={"client": "janome-test"}, headers=auth).json()["lease_id"]
            hdr = {**auth, "X-Lease-Id": lease}
            wait_state(c, lambda s: s["state"] == "ready", "ready (the point job connects on its own)")
            assert c.get("/api/limits").json()["axes"] == ["X", "Y", "Z", "R"]
            assert c.post("/api/session/start", headers=hdr).status_code == 200
            wait_state(c, lambda s: s["state"] == "streaming", "streaming")
            x0 = c.get("/api/state").json()["q_servo"][0]
            for _ in range(10):  # hold the jog button for about a second
                r = c.post("/api/jog", json={"joints": [40.0, 0.0, 0.0, 0.0], "hold_ms": 500}, headers=hdr)
                assert r.status_code == 200, r.text
                time.sleep(0.1)
            assert c.post("/api/session/stop", headers=auth).status_code == 200
            s = wait_state(c, lambda s: s["state"] == "stopped", "stopped")
            assert s["q_servo"][0] > x0 + 5.0  # the robot moved along +X
            r = c.post("/api/jog", content='{"joints": [NaN, 0, 0, 0]}',
                       headers={**hdr, "content-type": "application/json"})
            assert r.status_code == 422 and "joints[0]=nan" in r.text  # named; nothing reaches the robot
            assert c.post("/api/session/end", headers=hdr).status_code == 200
            wait_state(c, lambda s: s["state"] == "ended", "ended")
    finally:
        code, out, err = stop(run)
    assert code == 0, (out, err)
    # The exchange was logged frame by frame, readable like any session log.
    from servo_app.session_log import read_session_log

    paths = sorted((tmp_path / "sessions").glob("janome-*.srvlog"))
    logs = [read_session_log(p) for p in paths]
    assert logs
    log = max(logs, key=lambda lg: len(lg.commands))  # the point job may have reconnected afterwards
    # `servo-app check` reads the model from the header and checks the targets as the robot takes them.
    checked = subprocess.run([sys.executable, "-m", "servo_app.cli", "check", str(paths[logs.index(log)])],
                             capture_output=True, text=True, timeout=120)
    assert checked.returncode == 0 and "(jr3000)" in checked.stdout, (checked.stdout, checked.stderr)
    assert log.header["protocol"] == "janome-pointjob-v1"
    xs = log.commands["values"][:, 0]
    assert len(log.commands) > 5 and xs.max() > xs[0] + 5.0  # the +X jog is in it


_IMPORTED = """\
import sys
from servo_app.cli import main
try:
    code = main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
print(code, sorted(m for m in ("servo_app.run", "servo_app.service", "fastapi", "uvicorn") if m in sys.modules))
"""


@pytest.mark.parametrize("argv", [["check", "{tmp}/missing.csv"], ["export", "{tmp}/missing.srvlog", "--mcap",
                                  "{tmp}/x.mcap"], ["sim", "fanuc", "--help"], ["profiles"]])
def test_a_command_other_than_run_does_not_import_the_service(argv: list[str], tmp_path: Path) -> None:
    """Each command imports its own module alone: with every subcommand's parser built, `servo-app
    check` (and export, sim ...) imported the service's modules too (servo_app.run, servo_app.service,
    the differential IK with mink and scipy) and started twice as late (4.8 s against 2.3 s here, under
    load), and the suite starts these commands many times."""
    argv = [a.format(tmp=tmp_path) for a in argv]
    r = subprocess.run([sys.executable, "-c", _IMPORTED, *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    code, imported = r.stdout.strip().splitlines()[-1].split(" ", 1)
    assert imported == "[]", (argv, imported)
    assert code in ("0", "2"), r.stdout + r.stderr  # it ran: what it says of a missing file is tested elsewhere


def test_the_help_still_lists_every_command() -> None:
    r = subprocess.run([sys.executable, "-m", "servo_app.cli", "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "{sim,run,check,replay,export,monitor,profiles}" in r.stdout, r.stdout
