"""End to end on loopback TCP: the Janome servo process serves the simulated point job."""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from servo_app.errors import CommandRejected
from servo_app.janome.runner import JanomeConfig, JanomeProcess
from servo_app.messages import (
    ConfigureInputs,
    End,
    Jog,
    JointTarget,
    PeerDisconnected,
    PeerRefused,
    Reset,
    SafetyChanged,
    Start,
    Stop,
)
from servo_app.sim.janome_sim import JanomeSimulator

pytestmark = pytest.mark.e2e


def wait_for(sp: JanomeProcess, cond: Any, what: str, timeout: float = 10.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        s = sp.state()
        if cond(s):
            return s
        time.sleep(0.01)
    raise AssertionError(f"{what} not reached; state {sp.state()['state']}; events {sp.events[-4:]}")


def wait_state(sp: JanomeProcess, state: str, timeout: float = 10.0) -> dict:
    return wait_for(sp, lambda s: s["state"] == state, f"state {state!r}", timeout)


def wait_safety(sp: JanomeProcess, timeout: float, **match: Any) -> dict[str, Any]:
    """The view of the first safety event whose view has every ``match`` item."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for ev in list(sp.events):
            if isinstance(ev, SafetyChanged) and all(ev.view.get(k) == v for k, v in match.items()):
                return ev.view
        time.sleep(0.01)
    raise AssertionError(f"no safety event {match} within {timeout} s; events {sp.events[-4:]}")


def last_safety(sp: JanomeProcess, state: str | None = None, timeout: float = 2.0) -> dict[str, Any] | None:
    """The view of the last safety event; with ``state``, once the reader thread has taken the event
    that shows it off the pipe (the state vector can show a mode before that)."""
    deadline = time.monotonic() + timeout
    while True:
        ev = sp.last_event(SafetyChanged)
        view = ev.view if isinstance(ev, SafetyChanged) else None
        if state is None or (view is not None and view.get("state") == state) or time.monotonic() > deadline:
            return view
        time.sleep(0.01)


@pytest.fixture
def rig(request: pytest.FixtureRequest) -> Iterator[tuple[JanomeProcess, JanomeSimulator]]:
    model = getattr(request, "param", "jr3000")
    sp = JanomeProcess(JanomeConfig(port=0, model=model))
    sp.start()
    sim = JanomeSimulator(sp.address, model).start()
    yield sp, sim
    sim.stop()
    sp.shutdown()


def test_start_jog_stop_end(rig: tuple[JanomeProcess, JanomeSimulator]) -> None:
    sp, sim = rig
    wait_state(sp, "ready")
    with pytest.raises(CommandRejected, match="jog refused in ready"):
        sp.request(Jog(joints=(10.0, 0.0, 0.0, 0.0)))
    # one robot per stream: a second connection is closed at once
    with socket.create_connection(sp.address, timeout=2.0) as other:
        assert other.recv(16) == b""
    refused = sp.wait_event(PeerRefused, 5.0)
    assert isinstance(refused, PeerRefused) and refused.reason.startswith("already serving")
    sp.request(Start())
    wait_state(sp, "streaming")
    x0 = sim.position[0]
    for _ in range(8):
        sp.request(Jog(joints=(40.0, 0.0, 0.0, 5.0), hold_s=0.5))
        time.sleep(0.1)
    sp.request(Stop())
    s = wait_state(sp, "stopped")
    assert sim.moves >= 3 and sim.position[0] > x0
    assert s["q_cmd"][:4] == pytest.approx(list(sim.position), abs=1e-3)
    assert s["q_servo"][:4] == pytest.approx(s["q_cmd"][:4], abs=1e-3)  # the robot ended its last step
    assert s["link"] == "streaming" and s["status_received"] > 3 and s["malformed"] == 0
    moves = sim.moves
    time.sleep(0.3)
    assert sim.moves == moves  # stopped: no new target
    sp.request(End())
    wait_state(sp, "ended")
    assert sim.wait_done(5.0) and sim.end_reason == "END received"
    disconnected = sp.wait_event(PeerDisconnected, 5.0)
    assert isinstance(disconnected, PeerDisconnected) and disconnected.reason


def test_link_loss_mid_motion_is_a_fault(rig: tuple[JanomeProcess, JanomeSimulator]) -> None:
    sp, sim = rig
    wait_state(sp, "ready")
    sp.request(Start())
    wait_state(sp, "streaming")
    deadline = time.monotonic() + 5.0
    while sim.plan is None and time.monotonic() < deadline:  # until a move is under way
        sp.request(Jog(joints=(0.0, 60.0, 0.0, 0.0), hold_s=0.5))
        time.sleep(0.02)
    sim.kill_link()
    wait_state(sp, "fault")
    safety = wait_safety(sp, 5.0, state="fault")
    assert safety["fault"]["message"].startswith("connection lost while streaming")
    assert "TCP connection closed or reset" in safety["fault"]["cause"]
    assert sim.wait_done(5.0) and sim.end_reason == "link killed"
    with pytest.raises(CommandRejected, match="refused in fault"):
        sp.request(Jog(joints=(0.0, 10.0, 0.0, 0.0)))
    sp.request(Reset())
    wait_state(sp, "disconnected")


def test_bad_frames_are_rejected_without_a_crash(rig: tuple[JanomeProcess, JanomeSimulator]) -> None:
    sp, sim = rig
    wait_state(sp, "ready")
    sp.request(Start())
    wait_state(sp, "streaming")
    sim.corrupt_next_status()  # one status with a flipped byte: servo_app rejects it, answers HOLD
    n = wait_for(sp, lambda s: s["malformed"] == 1, "the bad status counted")["status_received"]
    wait_for(sp, lambda s: s["status_received"] > n, "a good status after it")
    sim.inject(b"not a frame at all")  # no magic: skipped, counted
    wait_for(sp, lambda s: s["malformed"] == 2, "the garbage counted")
    sim.corrupt_next_target()  # one target garbled on the way: the robot rejects it, servo_app resends
    for _ in range(6):
        if sp.state()["state"] != "streaming":
            raise AssertionError(f"{last_safety(sp)} {[(e.kind, e.message) for e in sim.events()]}")
        sp.request(Jog(joints=(30.0, 0.0, 0.0, 0.0), hold_s=0.5))
        time.sleep(0.1)
    rejected = sim.events("rejected")
    assert rejected and rejected[0].error in ("BAD_CHECKSUM", "BAD_MAGIC", "BAD_TERMINATOR")
    s = sp.state()
    assert s["state"] == "streaming" and s["status_lost"] >= 1
    safety = last_safety(sp, "streaming") or {}
    assert "checksum=" in (safety.get("link_error") or "") or s["malformed"] == 2
    sp.request(Stop())
    wait_state(sp, "stopped")
    assert sim.moves >= 2 and not sim.done.is_set()


@pytest.mark.parametrize("rig", ["js3"], indirect=True)
def test_scara_target_keeps_its_arm_configuration(rig: tuple[JanomeProcess, JanomeSimulator]) -> None:
    sp, sim = rig
    wait_state(sp, "ready")
    sp.request(Start())
    wait_state(sp, "streaming")
    with pytest.raises(CommandRejected, match=r"target refused: X=400\.000 mm is outside the stroke"):
        sp.request(JointTarget(joints=(400.0, 0.0, 50.0, 0.0)))
    goal = [260.0, 120.0, 30.0, 20.0]
    sp.request(JointTarget(joints=tuple(goal), speed_scale=1.0))
    wait_for(sp, lambda s: np.allclose(s["q_servo"][:4], goal, atol=1e-3), "the target", timeout=15.0)
    _j1, j2, z, _r = sim.robot.joints()
    assert sim.robot.arm == 1 and j2 > 0 and z == pytest.approx(30.0)
    assert not sim.events("rejected")
    sp.request(End())
    wait_state(sp, "ended")


def test_input_twist_through_the_slot_moves_the_robot_and_stale_stops_it() -> None:
    """Input adapters drive Janome too: a twist's X Y Z and its rotation about Z become an X Y Z R jog."""
    from servo_app.input_slot import NONE, TWIST, InputCommand, InputSlotWriter

    writer = InputSlotWriter()
    sp = JanomeProcess(JanomeConfig(port=0, model="jr3000", input_slot=writer.name))
    sp.start()
    sim = JanomeSimulator(sp.address, "jr3000").start()
    try:
        wait_state(sp, "ready")
        sp.request(Start())
        wait_state(sp, "streaming")
        sp.request(ConfigureInputs(enable=True, sources=("spacemouse",)))
        x0 = sim.position[0]
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            writer.publish(InputCommand(kind=TWIST, frame="base", values=(40.0, 0, 0, 0, 0, 0), linear_speed=0,
                                        angular_speed=0, stamp=time.monotonic(), timeout_s=0.3, source=0,
                                        stale=False))
            time.sleep(0.05)
        assert sim.position[0] > x0 + 10.0
        writer.publish(InputCommand(kind=NONE, frame="base", values=(0,) * 6, linear_speed=0, angular_speed=0,
                                    stamp=time.monotonic(), timeout_s=0.3, source=0, stale=True))
        wait_state(sp, "stopped")
        ev = last_safety(sp, "stopped")
        assert ev is not None and ev["stop_reason"] == "input spacemouse stale" and ev["fault"] is None
    finally:
        sim.stop()
        sp.shutdown()
        writer.close()


def test_a_robot_is_refused_while_its_log_cannot_be_opened_and_served_once_it_can(tmp_path: Any) -> None:
    """Every frame of a connection is logged: a robot that connects while its session log cannot be
    opened (here its directory is blocked by a file; a full disk is refused the same way) is closed at
    once with the reason, and the process serves the next connection once the log can be opened."""
    blocker = tmp_path / "var"
    blocker.write_text("")
    sp = JanomeProcess(JanomeConfig(port=0, log_dir=str(blocker / "sessions")))
    sp.start()
    try:
        with socket.create_connection(sp.address, timeout=2.0) as robot:
            assert robot.recv(16) == b""  # closed at once
        refused = sp.wait_event(PeerRefused, 5.0)
        assert isinstance(refused, PeerRefused)
        assert refused.reason.startswith(f"the session log cannot be opened in {blocker / 'sessions'}")
        assert "Not a directory" in refused.reason and refused.reason.endswith("then let the robot reconnect")
        assert sp.alive and sp.state()["state"] == "disconnected"
        blocker.unlink()
        sim = JanomeSimulator(sp.address, "jr3000").start()
        try:
            wait_state(sp, "ready")
            assert (blocker / "sessions").is_dir() and any((blocker / "sessions").glob("janome-*.srvlog"))
        finally:
            sim.stop()
    finally:
        sp.shutdown()


@contextlib.contextmanager
def janome_with_file_size_limit(tmp_path: Any, limit: int) -> Iterator[tuple[JanomeProcess, JanomeSimulator]]:
    """A Janome servo process held to ``limit`` bytes per file (RLIMIT_FSIZE, inherited by the spawned
    process only: its log's writes past it fail as on a full disk), and a robot connected to it."""
    import resource

    sp = JanomeProcess(JanomeConfig(port=0, log_dir=str(tmp_path / "sessions")))
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    try:
        sp.start()
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    sim = JanomeSimulator(sp.address, "jr3000").start()
    try:
        wait_state(sp, "ready")
        yield sp, sim
    finally:
        sim.stop()
        sp.shutdown()


def test_a_connection_whose_log_fails_mid_stream_ends_it_softly_with_the_reason(tmp_path: Any) -> None:
    with janome_with_file_size_limit(tmp_path, 6000) as (sp, _):
        sp.request(Start())
        wait_state(sp, "streaming")
        deadline = time.monotonic() + 20.0
        while sp.state()["state"] == "streaming" and time.monotonic() < deadline:
            with contextlib.suppress(CommandRejected):
                sp.request(Jog(joints=(20.0, 0.0, 0.0, 0.0), hold_s=0.5))
            time.sleep(0.1)
        wait_state(sp, "ended")
        view = last_safety(sp, "ended")
        assert view is not None
        reason = view["stop_reason"]
        assert reason.startswith("session log: a write ") and ("File too large" in reason or "cut short" in reason)
        assert any(w["code"] == "SESSION-LOG" for w in view["warnings"]), view["warnings"]
        assert sp.alive


def test_a_connection_whose_log_failed_takes_no_stream(tmp_path: Any) -> None:
    """The log failed before any stream (the robot's statuses filled it): a start on that connection is
    refused with the reason, and nothing changes."""
    with janome_with_file_size_limit(tmp_path, 900) as (sp, _):
        wait_safety(sp, 20.0, state="ready")
        deadline = time.monotonic() + 20.0
        while not any(w["code"] == "SESSION-LOG" for w in (last_safety(sp) or {}).get("warnings", [])):
            assert time.monotonic() < deadline, "the log never failed"
            time.sleep(0.05)
        with pytest.raises(CommandRejected, match=r"start refused: the session log janome-.* cannot take a stream"):
            sp.request(Start())
        assert sp.alive and sp.state()["state"] == "ready"


def test_a_connection_closed_after_a_link_fault_shows_as_disconnected(
        rig: tuple[JanomeProcess, JanomeSimulator]) -> None:
    """A link fault closes the robot's connection (here: three malformed statuses in a row); the
    safety view then says the robot is not connected. (It kept robot_connected true until a reset: the
    close came after the fault, which changed no safety state, so no new view was sent.)"""
    from servo_app.janome.protocol import STATUS_MAGIC

    sp, sim = rig
    wait_state(sp, "ready")
    sp.request(Start())
    wait_state(sp, "streaming")
    for _ in range(3):  # the right magic and length, a wrong terminator: rejected frames
        sim.inject(STATUS_MAGIC + bytes(52) + b"\n\n")
    wait_state(sp, "fault")
    assert sp.wait_event(PeerDisconnected, 5.0) is not None
    deadline = time.monotonic() + 5.0
    while (view := last_safety(sp)) is None or view["robot_connected"]:
        assert time.monotonic() < deadline, view
        time.sleep(0.01)
    assert view["state"] == "fault" and "malformed" in view["fault"]["message"], view
    # Reset, and the robot's point job connects again: the old connection's end is no longer the
    # link's error (it stayed in link_error while the new connection streamed).
    sp.request(Reset())
    seen = len(sp.events)
    again = JanomeSimulator(sp.address, "jr3000").start()
    try:
        deadline = time.monotonic() + 10.0
        while not (views := [ev.view for ev in list(sp.events)[seen:] if isinstance(ev, SafetyChanged)
                             and ev.view.get("state") == "ready"]):
            assert time.monotonic() < deadline, sp.events[-4:]
            time.sleep(0.01)
        assert views[-1]["robot_connected"] and views[-1]["link_error"] == "", views[-1]
    finally:
        again.stop()


def test_a_scara_jog_held_along_the_reach_stops_softly_at_it() -> None:
    """JS3 from X=300 Y=0, a held jog at 95 deg in XY: it meets the outer reach at a slant. The jog's
    target, found again from each position, crept back there while the shaper braked to it; the shaper
    overshot it past the stretched-arm limit (J2 1.85 deg, under 2), that step was refused before it
    went out (warning "step refused: ..."): the jog stopped dead 3 mm short of the reach, and the held
    jog's renewals started it again from rest. Now that step ends on the limit and the jog rests there:
    no warning, the robot refusing nothing, the held jog moving nothing further."""
    sp = JanomeProcess(JanomeConfig(port=0, model="js3"))
    sp.start()
    sim = JanomeSimulator(sp.address, "js3", start=(300.0, 0.0, 50.0, 0.0)).start()
    try:
        wait_state(sp, "ready")
        sp.request(Start())
        wait_state(sp, "streaming")
        a = np.radians(95.0)
        jog = Jog(joints=(100.0 * np.cos(a), 100.0 * np.sin(a), 0.0, 0.0), hold_s=0.5)

        def reach() -> float:
            return float(np.hypot(*sim.position[:2]))

        def resting() -> bool:  # the service's last step done, none after it
            s = sp.state()
            return s["q_servo"][:4] == pytest.approx(s["q_cmd"][:4], abs=1e-6) and sim.plan is None

        deadline = time.monotonic() + 15.0
        sp.request(jog)
        while not (reach() > 349.0 and resting()):  # held: renewed as a button held down is
            assert time.monotonic() < deadline, f"no rest near the reach: {sim.position}, {sp.state()['state']}"
            time.sleep(0.05)
            sp.request(jog)
        at_rest = sim.position.copy()
        moves = sim.moves
        n = sp.state()["status_received"]
        while sp.state()["status_received"] < n + 5:  # still held: nothing more moves
            assert time.monotonic() < deadline, "no status while held at the reach"
            time.sleep(0.05)
            sp.request(jog)
        assert sim.moves == moves and sim.position == pytest.approx(at_rest, abs=1e-9)
        _j1, j2, _, _ = sim.robot.joints()
        assert reach() > 349.9 and 2.0 < j2 < 2.6 and sim.robot.arm == 1  # at the limit, with its margin
        assert not sim.events("rejected")
        assert sp.state()["state"] == "streaming"
        sp.request(Stop())  # (a warning alone sends no safety view: the stop's shows them)
        view = wait_safety(sp, 5.0, state="stopped")
        assert not view["link_error"] and not view["warnings"], view
    finally:
        sim.stop()
        sp.shutdown()
