"""A running service for end-to-end tests: uvicorn on loopback in a thread, the servo process and the
embedded simulator in processes of their own (so this process's GIL cannot disturb the cycle).

Imported by tests/test_api_e2e.py and tests/test_faults_e2e.py; its own test checks the harness.
"""

from __future__ import annotations

import contextlib
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import uvicorn

from servo_app.api.app import create_app
from servo_app.messages import LogClosed, LogOpened
from servo_app.service import ServiceConfig, ServoService
from servo_app.session_log import SessionLog, read_session_log
from servo_app.sim.janome_sim import JanomeSimulator

TOKEN = "test-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}

# The ways a command-line tool is stopped: Ctrl-C, Ctrl-C to one started with SIGINT ignored (a script's
# background job inherits it, and Python then raises no KeyboardInterrupt), and SIGTERM.
STOP_WAYS = [("ctrl-c", signal.SIGINT), ("ignore_sigint", signal.SIGINT), ("sigterm", signal.SIGTERM)]
_CLI_SHIM = ("import signal, sys\n"
             "if sys.argv[1] == 'ignore_sigint': signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
             "from servo_app.cli import main\n"
             "sys.exit(main(sys.argv[2:]))\n")


def servo_app_argv(how: str, *argv: str) -> list[str]:
    """The command line of ``servo-app *argv`` started as ``how`` (a first word of STOP_WAYS) says."""
    return [sys.executable, "-c", _CLI_SHIM, how, *argv]


def wait_healthy(c: httpx.Client, proc: subprocess.Popen[Any] | None = None, timeout: float = 60.0,
                 output: Callable[[], str] = str) -> None:
    """Until the service ``c`` talks to answers /api/health (it binds its port a moment after it starts);
    fails at once if ``proc`` (that service) exits first, or after ``timeout``, with ``output()``."""
    deadline = time.monotonic() + timeout
    while True:
        assert proc is None or proc.poll() is None, \
            f"the service exited ({proc.returncode}) before it answered /api/health: {output()}"
        try:
            if c.get("/api/health").status_code == 200:
                return
        except httpx.TransportError:
            pass
        assert time.monotonic() < deadline, f"no /api/health answer within {timeout} s: {output()}"
        time.sleep(0.05)

class LiveServer:
    """uvicorn.Server in a daemon thread on 127.0.0.1, any free port (signal handlers stay unset)."""

    def __init__(self, app: Any) -> None:
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning",
                                                    lifespan="on", ws="websockets-sansio"))
        self.thread = threading.Thread(target=self.server.run, name="uvicorn", daemon=True)

    def start(self, timeout: float = 10.0) -> LiveServer:
        self.thread.start()
        deadline = time.monotonic() + timeout
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.01)
        return self

    @property
    def port(self) -> int:
        return int(self.server.servers[0].sockets[0].getsockname()[1])

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(10.0)


@dataclass
class Rig:
    service: ServoService
    server: LiveServer
    var_dir: Path
    http: httpx.Client = field(init=False)

    def __post_init__(self) -> None:
        self.http = httpx.Client(base_url=self.base_url, timeout=10.0)

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.server.port}"

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.server.port}"

    # -- control
    def lease(self, client: str = "tester", force: bool = True, ttl_s: float | None = None) -> dict[str, str]:
        """Acquire the control lease; returns the headers that carry it (and the token)."""
        body: dict[str, Any] = {"client": client, "force": force}
        if ttl_s is not None:
            body["ttl_s"] = ttl_s
        r = self.http.post("/api/lease", json=body, headers=AUTH)
        assert r.status_code == 200, r.text
        return {**AUTH, "X-Lease-Id": r.json()["lease_id"]}

    def post(self, path: str, headers: dict[str, str], json: Any = None, expect: int = 200) -> httpx.Response:
        r = self.http.post(path, json=json, headers=headers)
        assert r.status_code == expect, f"POST {path}: {r.status_code} {r.text}"
        return r

    def state(self) -> dict[str, Any]:
        r = self.http.get("/api/state")
        assert r.status_code == 200, r.text
        return r.json()  # type: ignore[no-any-return]

    def wait(self, pred: Callable[[dict[str, Any]], bool], timeout: float = 10.0, what: str = "") -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        s = self.state()
        while not pred(s):
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out waiting for {what or pred}: state={s['state']} link={s['link']} "
                                     f"stop={s.get('stop_reason')} fault={s.get('fault')} alarms={s.get('alarms')}")
            time.sleep(0.01)
            s = self.state()
        return s

    def wait_state(self, *states: str, timeout: float = 10.0) -> dict[str, Any]:
        return self.wait(lambda s: s["state"] in states, timeout, f"state in {states}")

    def wait_at_rest_settled(self, timeout: float = 3.0) -> dict[str, Any]:
        """Commands at rest, then the simulated servo settled (it follows the commands with a lag)."""
        s = self.wait(lambda s: s["at_rest"] and max(map(abs, s["vel"])) < 1e-6, timeout, "at rest")
        deadline = time.monotonic() + timeout
        last = np.array(s["cart_servo"])
        while True:
            time.sleep(0.05)
            s = self.state()
            now = np.array(s["cart_servo"])
            if np.abs(now - last).max() < 1e-3:
                return s
            assert time.monotonic() < deadline, "the servo position did not settle"
            last = now

    def start_streaming(self, headers: dict[str, str]) -> dict[str, Any]:
        self.post("/api/session/start", headers)
        return self.wait_state("streaming")

    def jog_for(self, headers: dict[str, str], joints: list[float], seconds: float, period: float = 0.05,
                hold_ms: float = 300.0) -> int:
        """Hold the jog button: renew a joint jog every ``period`` for ``seconds``; returns 200s seen."""
        ok = 0
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            r = self.http.post("/api/jog", json={"joints": joints, "hold_ms": hold_ms}, headers=headers)
            assert r.status_code in (200, 409), r.text
            ok += r.status_code == 200
            time.sleep(period)
        return ok

    def streaming(self, client: str = "tester", ttl_s: float | None = None) -> dict[str, str]:
        """Hold the lease (taking it over: the old holder's motion is stopped by the time it is
        granted) and have a stream running, starting a new one if the last has ended; returns the
        headers."""
        h = self.lease(client, ttl_s=ttl_s)
        s = self.wait(lambda s: s["state"] != "stopping", 5.0, "not stopping")
        if s["state"] == "fault":  # an earlier test's fault (that test fails on its own): recover, as an operator would
            self.post("/api/reset", h)
            s = self.wait_state("disconnected", "connected", "ready", "ended")
        if s["state"] == "stopped":
            if s["stop_fast"]:
                self.post("/api/reset", h)
            self.post("/api/session/resume", h)
            self.wait_state("streaming")
        elif s["state"] != "streaming":
            self.start_streaming(h)
        return h

    def end_and_wait(self, headers: dict[str, str]) -> dict[str, Any]:
        self.post("/api/session/end", headers)
        return self.wait_state("ended", timeout=15.0)

    def sim_alarms(self) -> list[str]:
        return [e["code"] for e in self.service.sim_call("events")]

    # -- logs
    def latest_log(self, timeout: float = 5.0) -> SessionLog:
        """Download the newest session log through the API once the servo process has closed it."""
        deadline = time.monotonic() + timeout

        def path_of(kind: type[LogOpened | LogClosed]) -> str | None:
            ev = self.service.last_event(kind)
            return ev.path if isinstance(ev, (LogOpened, LogClosed)) else None

        while path_of(LogClosed) is None or path_of(LogOpened) != path_of(LogClosed):
            if time.monotonic() > deadline:
                raise AssertionError("the session log was not closed")
            time.sleep(0.02)
        logs = self.http.get("/api/sessions").json()
        assert logs, "no session logs listed"
        r = self.http.get(f"/api/sessions/{logs[0]['name']}")
        assert r.status_code == 200
        path = self.var_dir / "download.srvlog"
        path.write_bytes(r.content)
        return read_session_log(path)


def assert_log_complete(log: SessionLog, ended: bool, min_records: int = 10) -> None:
    """Every command has the next sequence number; status records are there; ended: last data last."""
    cmds, sts = log.commands, log.statuses
    assert len(cmds) >= min_records and len(sts) >= min_records, (len(cmds), len(sts))
    gaps = np.flatnonzero(np.diff(cmds["seq"].astype(np.int64)) != 1)
    assert gaps.size == 0, f"command sequence gaps at {cmds['seq'][gaps][:5]}"
    if ended:
        assert cmds["flags"][-1] & 1 == 1, "the last command is not last data"
        assert np.all(cmds["flags"][:-1] & 1 == 0), "last data sent before the end"


def assert_came_to_rest(log: SessionLog, interval_s: float, tail: int = 2) -> None:
    """The commanded motion ended at rest (the shaper's rest: below 0.1 deg/s) after moving; the
    deceleration itself is judged by the simulator's limit checker (an alarm otherwise)."""
    q = log.commands["values"][:, :6].astype(float)
    v = np.diff(q, axis=0) / interval_s
    assert np.abs(v[-tail:]).max() < 0.1, f"the last commands still move: {np.abs(v[-tail:]).max()} deg/s"
    assert np.abs(v).max() > 1.0, "the arm never moved"


@contextlib.contextmanager
def running_rig(tmp: Path, jog_rate_per_s: int = 100, cors_origins: list[str] | None = None,
                **cfg: Any) -> Iterator[Rig]:
    service = ServoService(ServiceConfig(var_dir=tmp, **cfg))
    service.open()
    server = None
    try:
        server = LiveServer(create_app(service, TOKEN, jog_rate_per_s=jog_rate_per_s,
                                       cors_origins=cors_origins)).start()
        rig = Rig(service, server, tmp)
        try:
            yield rig
        finally:
            rig.http.close()
    finally:
        if server is not None:
            server.stop()
        service.close()


@contextlib.contextmanager
def running_janome_rig(tmp: Path, model: str = "jr3000") -> Iterator[tuple[Rig, JanomeSimulator]]:
    """The service listening for a Janome robot on a free port, and the robot's point job (the
    simulator) connected to it."""
    service = ServoService(ServiceConfig(robot="janome:127.0.0.1:0", model=model, var_dir=tmp))
    service.open()
    server = None
    sim = None
    try:
        server = LiveServer(create_app(service, TOKEN)).start()
        rig = Rig(service, server, tmp)
        assert service.robot_address is not None
        sim = JanomeSimulator(service.robot_address, model).start()
        try:
            yield rig, sim
        finally:
            rig.http.close()
    finally:
        if sim is not None:
            sim.stop()
        if server is not None:
            server.stop()
        service.close()


@pytest.mark.e2e
def test_harness_serves_the_api_and_stops(tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig:
        assert rig.http.get("/api/health").json() == {"ok": True}
        assert rig.state()["state"] in ("disconnected", "connected", "ready")
        thread = rig.server.thread
    assert not thread.is_alive()
