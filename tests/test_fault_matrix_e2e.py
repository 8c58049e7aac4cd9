"""The fault matrix (issue 13), end to end with real processes, sockets and signals on loopback.

Each case breaks something while the arm moves and ends with: the service still up and the fault
named in ``/api/state``; recovery over REST (reset, start, a jog that moves the arm) without a
restart; no process left behind; session logs that ``servo-app check`` passes, with no gap and no
phantom record. (SIGTERM while the arm moves: tests/test_faults_e2e.py::test_signal_mid_motion_to_servo_app_run.)
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families
from test_api_harness import AUTH, TOKEN, Rig, assert_log_complete, running_rig

from servo_app import cli
from servo_app.fanuc.packets import StatusStart, StatusStop
from servo_app.service.config import ServiceConfig
from servo_app.session_log import read_session_log
from servo_app.sim.fanuc_server import FaultConfig

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

ROOT = Path(__file__).resolve().parents[1]
MODEL = "lrmate200id"
JOG = [20.0, 0.0, 0.0, 30.0, 0.0, 0.0]


# ------------------------------------------------------------------------------------------ helpers


def eventually(pred: Any, timeout: float) -> bool:
    """Whether ``pred()`` holds within ``timeout`` (polled every 10 ms)."""
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def children_of(pid: int) -> list[int]:
    """Every live descendant of ``pid`` (from /proc)."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except (OSError, IndexError):
                continue
            if fields[0] != "Z":
                parents[int(entry.name)] = int(fields[1])
    out, frontier = [], [pid]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parents.items() if pp == p]
        out += kids
        frontier += kids
    return out


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def check_log(path: Path) -> str:
    """``servo-app check`` passes the log, as the controller would judge what was sent; its report.
    Its own main() in this process: the same parser, checker and report as the command, without a new
    interpreter's 2+ s of imports for each of a test's logs; the command as a process is
    tests/test_checker_cli.py's."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(["check", str(path), "--model", MODEL])
    assert code == 0, out.getvalue() + err.getvalue()
    return out.getvalue()


def all_logs(var_dir: Path) -> list[Path]:
    return sorted((var_dir / "sessions").glob("*.srvlog"), key=lambda p: p.stat().st_mtime)


def assert_logs_sound(var_dir: Path) -> None:
    """Every session log: consecutive command sequence numbers, statuses present, check passes."""
    logs = all_logs(var_dir)
    assert logs
    for path in logs:
        log = read_session_log(path)
        if len(log.commands) == 0:  # a start that never streamed: it passes, and says why
            assert "no commands were sent in this session" in check_log(path)
            continue
        assert_log_complete(log, ended=False, min_records=1)
        check_log(path)


def moves(rig: Rig, h: dict[str, str]) -> None:
    """A jog moves the arm (commanded J1 changes) and the stream is ended cleanly."""
    q0 = rig.state()["q_cmd"][0]
    rig.jog_for(h, JOG, 0.6)
    s = rig.state()
    assert abs(s["q_cmd"][0] - q0) > 1.0, (q0, s["q_cmd"], s["state"], s.get("fault"))
    rig.end_and_wait(h)


def recover(rig: Rig, h: dict[str, str]) -> None:
    """Reset, start, jog: back in business over REST alone."""
    rig.post("/api/reset", h)
    s = rig.wait_state("disconnected", "connected", "ready", timeout=15)
    assert s["fault"] is None, s["fault"]
    rig.post("/api/session/start", h)
    assert rig.state()["state"] == "streaming"  # start answers once streaming, never before
    moves(rig, h)


def service_children() -> list[bytes]:
    """The service's processes still running: this test process's children, but multiprocessing's
    resource tracker (one per interpreter) and a test's external controller."""
    out = []
    for pid in children_of(os.getpid()):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"resource_tracker" not in cmd and b"servo_app.cli\x00sim" not in cmd:  # the tests' own controller
            out.append(cmd)
    return out


def no_children_left() -> None:
    assert eventually(lambda: not service_children(), timeout=5.0), service_children()


class SimProcess:
    """``servo-app sim fanuc`` as a process of its own, on a fixed port (so it can be restarted there)."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.proc: subprocess.Popen[str] | None = None
        self.stderr: list[str] = []

    def start(self) -> SimProcess:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "servo_app.cli", "sim", "fanuc", "--port", str(self.port), "--joints",
             "0,0,0,0,-90,0"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert self.proc.stdout is not None and self.proc.stderr is not None
        line = self.proc.stdout.readline()
        assert re.search(r"udp://[\d.]+:(\d+)", line), line
        threading.Thread(target=lambda f=self.proc.stderr: self.stderr.extend(iter(f.readline, "")),
                         daemon=True).start()
        return self

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)

    def alarms(self) -> list[str]:
        return [line for line in self.stderr if line.startswith(("MOTN-", "PRIO-"))]


@pytest.fixture
def external_sim() -> Iterator[SimProcess]:
    sim = SimProcess(free_port(socket.SOCK_DGRAM)).start()
    yield sim
    sim.stop()


# ---------------------------------------------------------------------------------- the controller


def test_controller_killed_and_restarted(tmp_path: Path, external_sim: SimProcess) -> None:
    with running_rig(tmp_path, robot=f"fanuc:127.0.0.1:{external_sim.port}", model=MODEL) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        external_sim.kill()
        s = rig.wait_state("fault", timeout=5)
        assert "no status packet" in s["fault"]["message"], s["fault"]
        assert s["fault"]["remedy"], s["fault"]
        # Nothing answers yet: a start says why instead of answering 200 and staying disconnected.
        rig.post("/api/reset", h)
        r = rig.post("/api/session/start", h, expect=409)
        assert "start failed" in r.json()["detail"] and "no status" in r.json()["detail"], r.text
        assert rig.state()["state"] in ("disconnected", "fault")
        external_sim.start()  # the controller is back, on the same port
        if rig.state()["state"] == "fault":
            rig.post("/api/reset", h)
        rig.post("/api/session/start", h)
        assert rig.state()["state"] == "streaming"
        moves(rig, h)
    assert external_sim.alarms() == [], external_sim.stderr
    assert_logs_sound(tmp_path)
    no_children_left()


def test_controller_frozen_then_back(tmp_path: Path, external_sim: SimProcess) -> None:
    """The external controller stopped (SIGSTOP) mid-jog, reset and start tried while it is frozen,
    then continued (SIGCONT): it takes that start's status output start late and streams status again,
    holding MOTN-603 for the commands it missed (SYSRDY off). The link follows the status back, so the
    state, reset and start agree and name the true reason; its alarm reset at its pendant (SIGUSR1 to
    `servo-app sim fanuc`), a start streams and a jog moves the arm, without restarting the service.
    (Before the fix: `disconnected` with link `fault` for good, reset refused "in connected", and every
    start refused at once with the frozen start's "no status packet for 1.0 s".)"""
    pid = external_sim.proc.pid  # type: ignore[union-attr]
    with running_rig(tmp_path, robot=f"fanuc:127.0.0.1:{external_sim.port}", model=MODEL) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        os.kill(pid, signal.SIGSTOP)
        thaw_at = time.monotonic() + 1.5  # a deliberate freeze
        try:
            s = rig.wait_state("fault", timeout=5)
            assert "status packets lost while streaming" in s["fault"]["message"], s["fault"]
            rig.post("/api/reset", h)
            why = rig.post("/api/session/start", h, expect=409).json()["detail"]
            assert "no status packet" in why and "after status output start" in why, why
            assert rig.state()["state"] == "disconnected"
            time.sleep(max(0.0, thaw_at - time.monotonic()))
        finally:
            os.kill(pid, signal.SIGCONT)
        s = rig.wait(lambda s: s["state"] == "connected" and s["link"] == "connected" and s["status_live"],
                     timeout=5, what="connected again")
        assert s["fault"] is None and s["link_error"] == "", s
        assert eventually(lambda: any(a.startswith("MOTN-603") for a in external_sim.alarms()), timeout=5)
        # The state itself says why a start would wait (it used to show "connected" and nothing more).
        s = rig.wait(lambda s: "SYSRDY is off" in (s["not_ready"] or ""), timeout=5, what="not_ready")
        # Reset and start say what the state shows, and the true reason; a refusal changes nothing.
        r = rig.post("/api/reset", h, expect=409)
        assert "refused in connected: no fault to reset" in r.json()["detail"], r.text
        r = rig.post("/api/session/start", h, expect=409)
        assert "SYSRDY is off" in r.json()["detail"] and "no status packet" not in r.json()["detail"], r.text
        s = rig.state()
        assert (s["state"], s["link"], s["fault"]) == ("connected", "connected", None), s
        # The controller's alarm reset at its pendant: it waits at IBGN start again, and the status
        # still flowing is used.
        os.kill(pid, signal.SIGUSR1)
        s = rig.wait(lambda s: s["state"] == "ready", timeout=5, what="ready")
        assert s["not_ready"] is None, s
        rig.post("/api/session/start", h)
        assert rig.state()["state"] == "streaming"
        moves(rig, h)
    assert [a.split()[0] for a in external_sim.alarms()] == ["MOTN-603"], external_sim.stderr
    assert_logs_sound(tmp_path)
    no_children_left()


@pytest.mark.parametrize("stray", ["status-start", "status-stop", "version-2"])
def test_a_stray_datagram_to_the_controller_is_a_named_fault_then_recovered(tmp_path: Path, stray: str) -> None:
    """Another socket talks to the controller mid-stream: it takes the status output over, stops it,
    or speaks protocol version 2 (MOTN-607). The stream is lost; reset and start bring it back."""
    datagram, alarm = {"status-start": (StatusStart().encode(), "MOTN-603"),  # commands stop arriving
                       "status-stop": (StatusStop().encode(), "MOTN-608"),
                       "version-2": (StatusStart(version=2).encode(), "MOTN-607")}[stray]
    with running_rig(tmp_path) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
            other.sendto(datagram, rig.service.robot_address)
            rig.wait_state("fault", timeout=5)
        # Named by the controller's own alarm, with its cause and remedy, once it is reported.
        s = rig.wait(lambda s: (s["fault"] or {}).get("code") == alarm, timeout=5, what=alarm)
        assert s["fault"]["cause"] and s["fault"]["remedy"], s["fault"]
        recover(rig, h)
    assert_logs_sound(tmp_path)
    no_children_left()


def test_malformed_datagrams_from_the_controller_are_counted_never_logged(tmp_path: Path) -> None:
    """Datagrams from the controller's own address that do not decode (a status cut short after one
    status in five): counted, the stream goes on, and the log holds only what was sent (before the
    fix, each one logged the previous command again)."""
    faults = FaultConfig(malformed_prob=0.2, seed=3)
    with running_rig(tmp_path, sim_options={"faults": faults}) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 1.0)
        s = rig.state()
        assert s["malformed"] >= 20 and s["state"] == "streaming", s
        rig.end_and_wait(h)
        sent = rig.state()["commands_sent"]
        assert rig.sim_alarms() == []
    (path,) = all_logs(tmp_path)
    log = read_session_log(path)
    assert len(log.commands) == sent  # one record per command really sent
    assert_log_complete(log, ended=True)
    check_log(path)
    no_children_left()


# -------------------------------------------------------------------------------- the servo process


def test_servo_process_killed(tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        pid = rig.service.stream.pid  # type: ignore[union-attr]
        t_kill = time.monotonic()
        os.kill(pid, signal.SIGKILL)
        s = rig.wait_state("fault", timeout=2)
        assert time.monotonic() - t_kill < 0.5
        assert "signal 9" in s["fault"]["message"] and s["servo_process"].startswith("ended by signal 9"), s
        # Every request answers with a status code that says what to do, never 500.
        r = rig.post("/api/jog", h, json={"joints": JOG}, expect=409)
        assert "reset" in r.json()["detail"]
        rig.post("/api/session/stop", h)  # a stop is never refused
        recover(rig, h)
        assert rig.state()["servo_starts"] == 2
    assert_logs_sound(tmp_path)
    no_children_left()


def servo_killed_mid_jog(rig: Rig) -> dict[str, str]:
    """Stream, jog, SIGKILL the servo process, and wait for the fault; the lease's headers."""
    h = rig.lease()
    rig.start_streaming(h)
    rig.jog_for(h, JOG, 0.3)
    os.kill(rig.service.stream.pid, signal.SIGKILL)  # type: ignore[union-attr]
    rig.wait_state("fault", timeout=2)
    return h


def test_servo_process_killed_then_a_start_alone(tmp_path: Path) -> None:
    """SIGKILL mid-jog, then a start without a reset: it brings up a new servo process, but the embedded
    controller holds the alarm of the stream it was starved of, so the start is refused naming it. A
    reset then clears that alarm as at the pendant and answers 200 saying so (it answered 409 "no fault
    to reset" while it had cleared it: a refusal that changed something); a second reset has nothing
    left to do and is refused."""
    with running_rig(tmp_path) as rig:
        h = servo_killed_mid_jog(rig)
        r = rig.post("/api/session/start", h, expect=409)
        assert "SYSRDY is off" in r.json()["detail"], r.text
        s = rig.state()
        assert s["state"] == "connected" and "SYSRDY is off" in (s["not_ready"] or ""), s
        rig.post("/api/lease/renew", h)
        r = rig.post("/api/reset", h)
        assert "the embedded controller was reset, as at its pendant" in r.json()["detail"], r.text
        rig.wait(lambda s: s["state"] == "ready" and s["not_ready"] is None, timeout=5, what="ready")
        # Renewed as a client does (every third of the 10 s TTL): under load, the kill, the refused start and
        # the reset took 13-27 s, and the lease ran out before the end (409 "nobody holds the control lease").
        rig.post("/api/lease/renew", h)
        r = rig.post("/api/reset", h, expect=409)
        assert "no fault to reset" in r.json()["detail"], r.text
        rig.post("/api/session/start", h)
        rig.post("/api/lease/renew", h)
        moves(rig, h)
    assert_logs_sound(tmp_path)
    no_children_left()


def _spawned_servo_processes(before: set[int]) -> list[int]:
    """This process's children started since ``before`` by multiprocessing's spawn (servo processes)."""
    out = []
    for pid in set(children_of(os.getpid())) - before:
        with contextlib.suppress(OSError):
            if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes():
                out.append(pid)
    return out


def test_servo_process_killed_again_while_reset_starts_its_replacement(tmp_path: Path) -> None:
    """SIGKILL mid-jog, reset, then SIGKILL to the new servo process while it warms up: that reset
    answers 503 naming how the new process ended and what to do; the state names the fault (not
    "starting"); the next reset recovers, over REST alone."""
    with running_rig(tmp_path) as rig:
        h = servo_killed_mid_jog(rig)
        before = set(children_of(os.getpid()))
        answer: list[httpx.Response] = []
        reset = threading.Thread(target=lambda: answer.append(
            httpx.post(f"{rig.base_url}/api/reset", headers=h, timeout=60)))
        reset.start()
        assert eventually(lambda: bool(_spawned_servo_processes(before)), timeout=10), "no new servo process"
        for pid in _spawned_servo_processes(before):
            os.kill(pid, signal.SIGKILL)
        reset.join(60)
        assert answer and answer[0].status_code == 503, answer and answer[0].text
        detail = answer[0].json()["detail"]
        assert "signal 9" in detail and "before it was ready" in detail and "POST /api/reset" in detail, detail
        s = rig.state()
        assert s["state"] == "fault" and "before it was ready" in s["fault"]["message"], s
        assert s["servo_process"].startswith("ended by signal 9"), s["servo_process"]
        rig.post("/api/jog", h, json={"joints": JOG}, expect=409)  # refused, naming the way out
        recover(rig, h)
        assert rig.state()["servo_starts"] == 2  # the first and the replacement that came up
    assert_logs_sound(tmp_path)
    no_children_left()


@pytest.mark.parametrize("reset_at", ["after-the-fault", "at-once"])
def test_servo_process_stalled_is_ended_and_replaced(tmp_path: Path, reset_at: str) -> None:
    """SIGSTOP to the servo process mid-jog (alive, but running no cycle): after the stall time the
    state names the fault (`servo process stalled`), the service ends that process (SIGTERM,
    SIGKILL) by itself, and a reset starts a new one, also a reset sent at once, before the stall is
    seen; SIGCONT to the old one then finds nothing that could send the controller a stale command:
    the controller holds only the MOTN-603 of the stream it was starved of, start and jog move the
    arm. (Before the fix: `streaming` shown for good, and every reset 503 "did not answer Reset";
    continued, the old process sent its stale commands and the controller posted MOTN-600.)"""
    with running_rig(tmp_path) as rig:
        stall_s = rig.service.cfg.servo_stall_s
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        pid = rig.service.stream.pid  # type: ignore[union-attr]
        assert pid is not None
        t_stop = time.monotonic()
        os.kill(pid, signal.SIGSTOP)
        try:
            if reset_at == "at-once":  # before the stall is seen: it waits for it, then replaces the process
                rig.post("/api/reset", h)
                assert not alive(pid)
            else:
                s = rig.wait_state("fault", timeout=stall_s + 10.0)
                assert time.monotonic() - t_stop >= stall_s  # not before the stall time (how soon after: a figure)
                assert s["fault"]["message"].startswith("servo process stalled: it ran no cycle for"), s["fault"]
                assert s["servo_process"].startswith("stalled"), s["servo_process"]
                assert "POST /api/reset" in s["fault"]["remedy"], s["fault"]
                r = rig.post("/api/jog", h, json={"joints": JOG}, expect=409)  # refused at once, naming the way out
                assert "stalled" in r.json()["detail"] and "POST /api/reset" in r.json()["detail"], r.text
                assert eventually(lambda: not alive(pid), timeout=5.0), "the stalled process was not ended"
                rig.post("/api/reset", h)
            s = rig.wait_state("disconnected", "connected", "ready", timeout=15)
            assert s["fault"] is None and s["servo_process"] == "running" and s["servo_starts"] == 2, s
            assert rig.service.stream.pid != pid  # type: ignore[union-attr]
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        h = rig.lease()  # the stall, the reset and the new process's start can outlast the lease's 10 s under load
        rig.post("/api/session/start", h)
        assert rig.state()["state"] == "streaming"
        moves(rig, h)
        assert rig.sim_alarms() == ["MOTN-603"]  # no MOTN-600: nothing stale reached the controller
    log = read_session_log(all_logs(tmp_path)[0])
    assert len(log.commands) > 0  # the stalled process's log: complete up to the stall (assert_logs_sound)
    assert_logs_sound(tmp_path)
    no_children_left()


def test_a_request_to_a_stalled_servo_process_is_answered_when_the_stall_is_named(tmp_path: Path) -> None:
    """SIGSTOP to the servo process at rest; jogs come at once and halfway to the stall time. Each is
    answered 503 as the watchdog names the stall (the request's own timeout, 5 s here, is not what
    answers), naming the stall and the way out (reset); the arm did not move: after the reset and a
    new stream it is where it stopped. Old code: each waited until the process the watchdog ended
    died of its SIGKILL, the stall time and a second's grace later (2.03 s after the stop), for 'the
    servo process ended by signal 9 (SIGKILL) before answering Jog': neither why nor what to do."""
    with running_rig(tmp_path, request_timeout_s=5.0) as rig:
        stall_s = rig.service.cfg.servo_stall_s
        h = rig.lease()
        rig.start_streaming(h)
        before = rig.wait_at_rest_settled(10.0)["q_servo"]
        pid = rig.service.stream.pid  # type: ignore[union-attr]
        assert pid is not None
        answers: list[tuple[float, httpx.Response]] = []

        def jog(after_s: float) -> None:
            time.sleep(after_s)
            with httpx.Client(base_url=rig.base_url, timeout=10.0) as c:
                r = c.post("/api/jog", json={"joints": JOG, "hold_ms": 300}, headers=h)
            answers.append((time.monotonic() - t_stop, r))

        t_stop = time.monotonic()
        os.kill(pid, signal.SIGSTOP)
        try:
            jogs = [threading.Thread(target=jog, args=(t,), daemon=True) for t in (0.0, stall_s / 2)]
            for t in jogs:
                t.start()
            for t in jogs:
                t.join(15.0)
            assert len(answers) == 2
            for took, r in answers:
                assert r.status_code == 503, (took, r.text)
                detail = r.json()["detail"]
                assert detail.startswith("the servo process stalled: it ran no cycle for"), (took, detail)
                assert "did not answer Jog" in detail and detail.endswith("POST /api/reset"), detail
                assert stall_s <= took < stall_s + 0.8, (took, detail)  # (old code: 2.03 s)
            assert eventually(lambda: not alive(pid), timeout=5.0), "the stalled process was not ended"
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        rig.post("/api/reset", h)
        rig.wait_state("disconnected", "connected", "ready", timeout=15)
        rig.start_streaming(h)
        after = rig.wait_at_rest_settled(10.0)["q_servo"]
        assert np.allclose(after, before, atol=1e-3), (before, after)
        assert rig.sim_alarms() == ["MOTN-603"]  # the starved stream's, no other
    no_children_left()


# ------------------------------------------------------------------------------------ the main process


def _serve(args: list[str], var_dir: Path) -> tuple[subprocess.Popen[str], str, list[str]]:
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "servo_app.cli", "run", "--http-port", str(port), "--var-dir",
                             str(var_dir), "--token", TOKEN, *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    err: list[str] = []
    assert proc.stderr is not None
    threading.Thread(target=lambda: err.extend(iter(proc.stderr.readline, "")), daemon=True).start()  # type: ignore[union-attr]
    base = f"http://127.0.0.1:{port}"

    def up() -> bool:
        assert proc.poll() is None, "".join(err)
        try:
            return httpx.get(f"{base}/api/health", timeout=1).status_code == 200
        except httpx.TransportError:
            return False

    assert eventually(up, timeout=60), "servo-app run did not come up"
    return proc, base, err


def _jog_then_kill_main(proc: subprocess.Popen[str], base: str) -> tuple[list[int], float]:
    with httpx.Client(base_url=base, timeout=5) as c:
        lease = c.post("/api/lease", json={"client": "ops"}, headers=AUTH).json()["lease_id"]
        h = {**AUTH, "X-Lease-Id": lease}
        assert c.post("/api/session/start", headers=h).status_code == 200
        assert c.post("/api/jog", json={"joints": [30.0, 0, 0, 0, 0, 0], "hold_ms": 2000}, headers=h).status_code == 200
        assert eventually(lambda: c.get("/api/state").json()["vel"][0] > 10.0, timeout=5)
    kids = children_of(proc.pid)
    assert kids
    proc.kill()
    t = time.monotonic()
    proc.wait(5)
    return kids, t


@pytest.mark.parametrize("controller", ["embedded", "external"])
def test_main_process_killed(tmp_path: Path, controller: str) -> None:
    """SIGKILL to `servo-app run` mid-motion: its servo process stops the arm softly, sends last data,
    stops the status output and exits, whether the controller is its embedded simulator or external;
    nothing outlives the main process by more than 2 s."""
    sim = SimProcess(free_port(socket.SOCK_DGRAM)).start() if controller == "external" else None
    try:
        args = ["--robot", f"fanuc:127.0.0.1:{sim.port}"] if sim else []
        proc, base, err = _serve(args, tmp_path)
        try:
            kids, t_kill = _jog_then_kill_main(proc, base)
            gone = eventually(lambda: not any(alive(p) for p in kids), timeout=2.0)
            left = [p for p in kids if alive(p)]
        finally:
            for p in kids if "kids" in locals() else []:
                if alive(p):
                    os.kill(p, signal.SIGKILL)
        assert gone, f"still running {time.monotonic() - t_kill:.2f} s after the main process died: {left}"
        alarms = [line for line in err if line.startswith(("MOTN-", "PRIO-"))]
        alarms += sim.alarms() if sim else []
        assert alarms == [], "".join(err)
    finally:
        if sim is not None:
            sim.stop()
    (path,) = all_logs(tmp_path)
    log = read_session_log(path)
    assert_log_complete(log, ended=True)  # the stream ended with last data: a soft stop, not a cut
    v = np.diff(log.commands["values"][:, 0].astype(float)) / 0.008
    assert np.abs(v).max() > 10.0 and abs(v[-1]) < 0.1  # it moved, then came to rest
    check_log(path)


def test_sigterm_to_the_servo_process_ends_it_cleanly(tmp_path: Path) -> None:
    """SIGTERM to the servo process alone: soft stop, last data, exit; the service names it and recovers."""
    with running_rig(tmp_path) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        handle = rig.service.stream
        assert handle is not None
        os.kill(handle.pid, signal.SIGTERM)  # type: ignore[arg-type]
        s = rig.wait_state("fault", timeout=5)
        assert handle.process.exitcode == 0 and "exited with code 0" in s["fault"]["message"], s["fault"]
        assert rig.sim_alarms() == []
        recover(rig, h)
    log = read_session_log(all_logs(tmp_path)[0])
    assert_log_complete(log, ended=True)
    assert_logs_sound(tmp_path)
    no_children_left()


# --------------------------------------------------------------------- the embedded controller frozen


@contextlib.contextmanager
def frozen(pid: int, seconds: float) -> Iterator[None]:
    """The process stopped (SIGSTOP) for ``seconds`` (a deliberate freeze: the block's checks run
    meanwhile, then the rest of it is waited out), then continued (SIGCONT) whatever happened."""
    os.kill(pid, signal.SIGSTOP)
    until = time.monotonic() + seconds
    try:
        yield
        time.sleep(max(0.0, until - time.monotonic()))
    finally:
        os.kill(pid, signal.SIGCONT)


def alarm_codes(s: dict[str, Any]) -> list[str]:
    return [a["code"] for a in s["alarm_history"] or []]


def poll_failures_metric(rig: Rig) -> float:
    fams = {f.name: f for f in text_string_to_metric_families(rig.http.get("/metrics").text)}
    return next(x.value for x in fams["servo_alarm_poll_failures"].samples if x.name.endswith("_total"))


def test_embedded_controller_frozen_longer_than_a_call(tmp_path: Path) -> None:
    """The embedded simulator's process stopped (SIGSTOP) mid-jog for longer than a call to it may
    take, then continued: while frozen, a reset answers 503 within the call timeout, says what to do
    and changes nothing; the alarm monitor's polls time out and it polls on. Afterwards the pipe is
    in step again (before the fix, each call read the previous call's late reply: the monitor died,
    new alarms went unseen): reset, start and jog recover, and a new controller alarm is shown."""
    with running_rig(tmp_path) as rig:
        svc = rig.service
        timeout_s = svc.cfg.sim_call_timeout_s
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        assert svc.sim is not None
        with frozen(svc.sim.process.pid, timeout_s + 1.5):
            s = rig.wait_state("fault", timeout=5)
            t0 = time.monotonic()
            r = rig.post("/api/reset", h, expect=503)
            took = time.monotonic() - t0
            assert took < timeout_s + 1.0, took  # well inside the 10 s lease
            assert "did not answer reset" in r.json()["detail"] and "POST /api/reset" in r.json()["detail"], r.text
            after = rig.state()
            assert after["state"] == "fault" and after["servo_starts"] == s["servo_starts"] == 1, after
            assert eventually(lambda: svc.alarm_forwarder.poll_failures > 0, timeout=timeout_s + 1.0)
            assert svc.alarm_forwarder.alive
            # The operator sees it: the state says the alarm list cannot be read, /metrics counts it.
            s = rig.wait(lambda s: s["alarm_poll_error"] is not None, timeout=timeout_s + 1.0, what="poll error")
            assert "TimeoutError" in s["alarm_poll_error"], s["alarm_poll_error"]
            assert poll_failures_metric(rig) >= 1
        # The controller answers again: its alarm for the commands it missed is listed.
        rig.wait(lambda s: (s["fault"] or {}).get("code") == "MOTN-603", timeout=10, what="MOTN-603")
        assert svc.alarm_forwarder.alive and eventually(lambda: svc.alarm_forwarder.poll_error == "", timeout=5)
        assert rig.state()["alarm_poll_error"] is None
        recover(rig, h)
        # A new controller alarm after the recovery is seen (and a direct call gets its own reply).
        rig.start_streaming(h)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
            other.sendto(StatusStop().encode(), svc.robot_address)
        s = rig.wait(lambda s: (s["fault"] or {}).get("code") == "MOTN-608", timeout=5, what="MOTN-608")
        assert alarm_codes(s)[-1] == "MOTN-608", alarm_codes(s)
        assert rig.sim_alarms()[-1] == "MOTN-608"
        recover(rig, h)
        assert svc.alarm_forwarder.alive
    assert_logs_sound(tmp_path)
    no_children_left()


def test_embedded_controller_killed_then_reset_starts_it_again(tmp_path: Path) -> None:
    """The embedded simulator's process killed (SIGKILL) mid-jog: a named fault, the state says its
    alarm list cannot be read; reset starts a new controller at the same address (before the fix:
    every reset answered 503 "once the controller answers again", and only a restart got out), a
    start and jog move the arm, and a new alarm of the new controller is shown."""
    with running_rig(tmp_path) as rig:
        svc = rig.service
        assert svc.sim is not None
        address, old_pid = svc.sim.address, svc.sim.process.pid
        h = rig.lease()
        s0 = rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        os.kill(old_pid, signal.SIGKILL)
        s = rig.wait_state("fault", timeout=5)
        assert "status packets lost while streaming" in s["fault"]["message"], s["fault"]
        s = rig.wait(lambda s: "process has ended" in (s["alarm_poll_error"] or ""), timeout=5, what="poll error")
        last = s["q_servo"]  # where the controller last said the arm was (the jog moved it off its start)
        assert abs(last[0] - s0["q_servo"][0]) > 1.0, (s0["q_servo"], last)
        rig.post("/api/reset", h)
        assert svc.sim.process.pid != old_pid and svc.sim.address == address and svc.sim.alive
        # The new controller's arm is where the killed one's stopped, not back at the initial joints
        # (its status flows from the start; the stream holds it still until a jog).
        s = rig.start_streaming(h)
        assert s["q_servo"] == pytest.approx(last, abs=1e-3), (last, s["q_servo"])
        moves(rig, h)
        assert rig.state()["alarm_poll_error"] is None
        rig.start_streaming(h)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
            other.sendto(StatusStop().encode(), svc.robot_address)
        s = rig.wait(lambda s: (s["fault"] or {}).get("code") == "MOTN-608", timeout=5, what="MOTN-608")
        assert rig.sim_alarms() == ["MOTN-608"]  # the new controller's list, from the start
        recover(rig, h)
    assert_logs_sound(tmp_path)
    no_children_left()


def test_sigint_after_the_embedded_controller_was_frozen(tmp_path: Path) -> None:
    """`servo-app run`: the embedded simulator stopped (SIGSTOP) mid-jog for longer than a call
    timeout, continued, the operator recovers over REST, a new alarm is shown; then SIGINT ends it
    with exit code 0, the controller's alarms in its summary, nothing left running (before the fix:
    a TypeError in close() and exit code 1)."""
    proc, base, err = _serve([], tmp_path)
    out = ""
    try:
        with httpx.Client(base_url=base, timeout=15) as c:
            lease = c.post("/api/lease", json={"client": "ops"}, headers=AUTH).json()["lease_id"]
            h = {**AUTH, "X-Lease-Id": lease}

            def state() -> dict[str, Any]:
                return c.get("/api/state").json()  # type: ignore[no-any-return]

            def post(path: str, expect: int = 200, **kw: Any) -> httpx.Response:
                r = c.post(path, headers=h, **kw)
                assert r.status_code == expect, (path, r.status_code, r.text)
                return r

            post("/api/session/start")
            post("/api/jog", json={"joints": [30.0, 0, 0, 0, 0, 0], "hold_ms": 2000})
            assert eventually(lambda: state()["vel"][0] > 10.0, timeout=5)
            servo_pid = int(all_logs(tmp_path)[-1].name.split("-")[3])  # session-DATE-TIME-PID-N.srvlog
            kids = [p for p in children_of(proc.pid) if p != servo_pid
                    and b"resource_tracker" not in Path(f"/proc/{p}/cmdline").read_bytes()]
            (sim_pid,) = kids  # the embedded simulator
            timeout_s = ServiceConfig().sim_call_timeout_s
            with frozen(sim_pid, timeout_s + 1.5):
                assert eventually(lambda: state()["state"] == "fault", timeout=5)
                t0 = time.monotonic()
                post("/api/reset", expect=503)
                assert time.monotonic() - t0 < timeout_s + 1.0
            assert eventually(lambda: (state()["fault"] or {}).get("code") == "MOTN-603", timeout=10), state()
            post("/api/reset")
            assert eventually(lambda: state()["state"] in ("disconnected", "connected", "ready"), timeout=15)
            post("/api/session/start")
            q0 = state()["q_cmd"][0]
            post("/api/jog", json={"joints": JOG, "hold_ms": 300})
            assert eventually(lambda: abs(state()["q_cmd"][0] - q0) > 1.0, timeout=5), state()
            robot = state()["robot"]
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
                other.sendto(StatusStop().encode(), ("127.0.0.1", int(robot.rsplit(":", 1)[1])))
            assert eventually(lambda: (state()["fault"] or {}).get("code") == "MOTN-608", timeout=5), state()
            assert alarm_codes(state())[-1] == "MOTN-608"
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 0, out + "".join(err)
    assert "controller alarms ['MOTN-603', 'MOTN-608']" in out, out
    assert "Traceback" not in "".join(err), "".join(err)
    assert eventually(lambda: not children_of(proc.pid), timeout=5.0)
    assert_logs_sound(tmp_path)
