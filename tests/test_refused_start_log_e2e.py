"""The session log of a start that is refused, end to end (service, servo process, a controller on
loopback): a start opens its log before the controller has answered, so a refusal used to leave it.

- Nothing came from the controller (it never answers): the log held its header alone, and
  GET /api/sessions listed it as a session. It is now deleted, with its live MCAP.
- Status packets and the controller's tables came before the refusal (SYSRDY off): the log stays, it
  records what was received, and ends with a note saying why the start was given up, which
  ``servo-app check`` reports.
- Janome (a log per connection, opened as the robot connects): a point job whose HELLO is refused
  (another robot kind) left a header-only log, the HELLO it sent unlogged; it now holds the HELLO and
  ends saying why. A connection that never says HELLO leaves none.
"""

from __future__ import annotations

import contextlib
import io
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_api_harness import TOKEN, LiveServer, Rig, running_rig

from servo_app import cli
from servo_app.api.app import create_app
from servo_app.messages import LogClosed, LogOpened
from servo_app.service import ServiceConfig, ServoService
from servo_app.session_log import read_session_log
from servo_app.sim.janome_sim import JanomeSimulator

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

MODEL = "lrmate200id"


def wait_log_closed(rig: Rig, timeout: float = 10.0) -> LogClosed:
    """The servo process's LogClosed for the log it opened last."""
    deadline = time.monotonic() + timeout
    while True:
        opened, closed = rig.service.last_event(LogOpened), rig.service.last_event(LogClosed)
        if isinstance(opened, LogOpened) and isinstance(closed, LogClosed) and closed.path == opened.path:
            return closed
        assert time.monotonic() < deadline, f"the session log was not closed (opened {opened}, closed {closed})"
        time.sleep(0.01)


def wait_recorders_done(rig: Rig, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not all(rec.done for rec in rig.service.recorders):
        assert time.monotonic() < deadline, "the live MCAP writer did not stop"
        time.sleep(0.01)


def test_a_start_no_controller_answers_leaves_no_session_log(tmp_path: Path) -> None:
    """A controller that never answers (a UDP socket that reads and says nothing): the start is refused
    after the status output start went unanswered, and no log, no MCAP, nothing listed is left (before:
    a 297-byte header-only .srvlog, listed by GET /api/sessions, and a header-only .mcap)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        port = silent.getsockname()[1]
        with running_rig(tmp_path, robot=f"fanuc:127.0.0.1:{port}", model=MODEL, mcap_live=True) as rig:
            h = rig.lease()
            r = rig.post("/api/session/start", h, expect=409)
            assert "no status packet" in r.json()["detail"], r.text
            silent.settimeout(1.0)
            assert silent.recvfrom(2048)[0], "the servo process sent no status output start"  # packets left
            closed = wait_log_closed(rig)
            assert closed.records == 0, closed
            assert not Path(closed.path).exists(), f"{closed.path} left: {Path(closed.path).stat().st_size} bytes"
            wait_recorders_done(rig)
            assert rig.http.get("/api/sessions").json() == []
            s = rig.state()
            assert s["state"] == "disconnected" and s["mcap_error"] is None, s
    assert sorted(p.name for p in (tmp_path / "sessions").iterdir()) == []


def test_a_start_refused_for_sysrdy_off_keeps_what_came_and_says_why(tmp_path: Path) -> None:
    """The embedded controller holds an alarm (MOTN-606: the override changed at its pendant), so its
    status shows SYSRDY off and the start is refused. The statuses received and the tables read stay
    in a log that ends with the reason, and ``servo-app check`` says it; a start after the reset
    streams into a log of its own."""
    with running_rig(tmp_path, model=MODEL) as rig:
        h = rig.lease()
        rig.service.sim_call("set_override", 50)
        assert [e["code"] for e in rig.service.sim_call("events")] == ["MOTN-606"]
        r = rig.post("/api/session/start", h, expect=409)
        assert "SYSRDY is off" in r.json()["detail"], r.text
        closed = wait_log_closed(rig)
        assert closed.records > 0, closed
        (listed,) = rig.http.get("/api/sessions").json()
        refused = tmp_path / "sessions" / listed["name"]
        assert str(refused) == closed.path
        log = read_session_log(refused)
        assert len(log.statuses) > 0 and len(log.commands) == 0, (len(log.statuses), len(log.commands))
        notes = [note for _, note in log.notes()]
        assert [list(note) for note in notes] == [["limit_tables"], ["ended", "streamed"]], notes
        why = notes[-1]["ended"]
        assert why.startswith("SYSRDY is off") and notes[-1]["streamed"] is False, notes[-1]
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            assert cli.main(["check", str(refused), "--model", MODEL]) == 0
        assert f"a start that never streamed: {why}): nothing the controller could refuse" in out.getvalue()
        # The override back at 100 %, the alarm reset as at the pendant: the next start streams into a
        # new log; the refused one stays as it was.
        size = refused.stat().st_size
        rig.service.sim_call("set_override", 100)
        rig.post("/api/reset", h)
        rig.wait(lambda s: s["state"] == "ready", timeout=10, what="ready")
        rig.start_streaming(h)
        rig.end_and_wait(h)
        names = {p["name"] for p in rig.http.get("/api/sessions").json()}
        assert len(names) == 2 and listed["name"] in names, names
        assert refused.stat().st_size == size


@contextlib.contextmanager
def janome_service(tmp: Path) -> Iterator[Rig]:
    """The service listening for a Janome JR3000 (a Cartesian robot) on a free port, no robot yet."""
    service = ServoService(ServiceConfig(robot="janome:127.0.0.1:0", model="jr3000", var_dir=tmp))
    service.open()
    try:
        server = LiveServer(create_app(service, TOKEN)).start()
        rig = Rig(service, server, tmp)
        try:
            yield rig
        finally:
            rig.http.close()
            server.stop()
    finally:
        service.close()


def test_a_janome_point_job_refused_at_its_hello_leaves_the_hello_and_why(tmp_path: Path) -> None:
    """A JS3 (SCARA) point job connects to a service for a JR3000: its HELLO is refused and the
    connection closed. The log holds the HELLO received and ends saying why (before: a 222-byte
    header-only log, listed as a session, the HELLO unlogged)."""
    with janome_service(tmp_path) as rig:
        assert rig.service.robot_address is not None
        sim = JanomeSimulator(rig.service.robot_address, "js3").start()
        try:
            assert sim.done.wait(15), "the point job was not closed"
            closed = wait_log_closed(rig)
        finally:
            sim.stop()
        (listed,) = rig.http.get("/api/sessions").json()
        assert str(tmp_path / "sessions" / listed["name"]) == closed.path
        log = read_session_log(Path(closed.path))
        assert len(log.statuses) == 1 and len(log.commands) == 0, (len(log.statuses), len(log.commands))
        ((_, note),) = log.notes()
        assert note["ended"].startswith("handshake refused: HELLO has detail=2 (robot kind SCARA)"), note
        assert note["streamed"] is False, note
        assert note["ended"] == rig.state()["link_error"]


def test_a_janome_connection_that_never_says_hello_leaves_no_log(tmp_path: Path) -> None:
    """A TCP connection that sends nothing is closed after the handshake time-out; nothing was
    received, so no log is left (before: a header-only log, listed as a session)."""
    with janome_service(tmp_path) as rig:
        assert rig.service.robot_address is not None
        with socket.create_connection(rig.service.robot_address, timeout=10) as mute:
            closed = wait_log_closed(rig)
            assert mute.recv(1) == b"", "the service did not close the connection"
        assert closed.records == 0, closed
        assert not Path(closed.path).exists(), f"{closed.path} left: {Path(closed.path).stat().st_size} bytes"
        assert rig.http.get("/api/sessions").json() == []
        assert "no HELLO frame" in rig.state()["link_error"], rig.state()["link_error"]
