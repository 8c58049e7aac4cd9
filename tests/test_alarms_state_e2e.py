"""Alarms and the state view, end to end through the running service (issue 14, "Alarms and state"):
active alarms apart from their history, with the wall-clock and the controller's time; a state view
that does not contradict itself after a link fault; ``settled`` beside ``at_rest`` for both
backends; alarms and faults counted in /metrics."""

from __future__ import annotations

import os
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families
from test_api_harness import TOKEN, LiveServer, Rig, running_janome_rig, running_rig

from servo_app.api.app import create_app
from servo_app.fanuc.packets import StatusStop
from servo_app.service import ServiceConfig, ServoService
from servo_app.sim.fanuc_model import ControllerConfig
from servo_app.sim.janome_sim import JanomeSimulator

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

JOG = [20.0, 0, 0, 0, 0, 0]


def codes(items: list[dict[str, Any]]) -> list[str]:
    return [a["code"] for a in items]


def counters(rig: Rig, family: str, label: str) -> dict[str, float]:
    fams = {f.name: f for f in text_string_to_metric_families(rig.http.get("/metrics").text)}
    assert fams[family].type == "counter"
    return {s.labels[label]: s.value for s in fams[family].samples if s.name.endswith("_total")}


def wait_metric(rig: Rig, family: str, label: str, pred: Callable[[dict[str, float]], bool]) -> dict[str, float]:
    deadline = time.monotonic() + 5.0
    while not pred(c := counters(rig, family, label)):
        assert time.monotonic() < deadline, f"{family}: {c}"
        time.sleep(0.02)
    return c


# ------------------------------------------------------------------------------------------ alarms


def test_reset_and_a_new_stream_clear_the_active_alarms_the_history_keeps_them_with_both_times(
        tmp_path: Path) -> None:
    with running_rig(tmp_path) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        rig.jog_for(h, JOG, 0.3)
        before = rig.state()
        assert before["status_time_ms"] is not None
        t_kill = time.time()
        os.kill(rig.service.stream.pid, signal.SIGKILL)  # type: ignore[union-attr]
        # The controller misses the next command: MOTN-603, active, with its times.
        s = rig.wait(lambda s: "MOTN-603" in codes(s["alarms"]), 5.0, "MOTN-603 listed")
        a = s["alarms"][-1]
        assert a["code"] == "MOTN-603" and a["cause"] and a["remedy"] and a["warning"] is False
        assert t_kill <= a["time_unix"] <= time.time()
        # The controller's clock: just after the last status the service saw before the kill.
        assert 0 <= a["controller_time_ms"] - before["status_time_ms"] < 2000, (a, before["status_time_ms"])
        assert codes(s["alarm_history"]) == ["MOTN-603"]

        # The reset replaces the dead servo process (about a second): the state answers all along.
        answers: list[tuple[int, str]] = []
        done = threading.Event()

        def poll() -> None:
            with httpx.Client(base_url=rig.base_url, timeout=10.0) as c:
                while not done.is_set():
                    r = c.get("/api/state")
                    answers.append((r.status_code, "" if r.status_code == 200 else r.text[:300]))

        poller = threading.Thread(target=poll, daemon=True)
        poller.start()
        rig.post("/api/reset", h)
        done.set()
        poller.join(10.0)
        assert answers and {code for code, _ in answers} == {200}, sorted(set(answers))
        s = rig.wait_state("disconnected", "connected", "ready", timeout=15)
        assert s["alarms"] == [], s["alarms"]
        assert codes(s["alarm_history"]) == ["MOTN-603"] and s["alarm_history"][0] == a
        rig.start_streaming(h)  # a clean new stream: still nothing active
        rig.jog_for(h, [-v for v in JOG], 0.3)
        s = rig.state()
        assert s["state"] == "streaming" and s["alarms"] == [], s["alarms"]

        # A second alarm is the only active one; the history holds both, oldest first.
        rig.service.sim_call("set_override", 50)  # at the pendant, mid-stream: MOTN-606
        s = rig.wait(lambda s: (s["fault"] or {}).get("code") == "MOTN-606", 5.0, "fault with MOTN-606")
        assert codes(s["alarms"]) == ["MOTN-606"], s["alarms"]
        assert codes(s["alarm_history"]) == ["MOTN-603", "MOTN-606"]
        assert s["alarm_history"][0]["time_unix"] < s["alarm_history"][1]["time_unix"]
        assert s["alarm_history"][0]["controller_time_ms"] != s["alarm_history"][1]["controller_time_ms"]

        # /metrics: alarms by code, faults by cause (the controller's code, or what we detected).
        wait_metric(rig, "servo_alarms", "code", lambda c: c == {"MOTN-603": 1.0, "MOTN-606": 1.0})
        wait_metric(rig, "servo_faults", "cause",
                    lambda c: c.get("servo_process") == 1.0 and c.get("MOTN-606") == 1.0 and sum(c.values()) == 2)

        rig.service.sim_call("set_override", 100)
        rig.post("/api/reset", h)
        s = rig.wait_state("ready", timeout=5)
        assert s["alarms"] == [] and codes(s["alarm_history"]) == ["MOTN-603", "MOTN-606"]


def test_a_controller_warning_reaches_the_safety_views_warnings_while_the_stream_runs_on(tmp_path: Path) -> None:
    """A controller warning changes no safety state: it is in the state's ``warnings`` while the stream
    runs on ($WARN_LIM at 5 %: a joint target posts MOTN-612/613/614). Old code: only at the next state
    change (the servo process sent its safety view only then), though ``alarms`` listed it at once."""
    with running_rig(tmp_path, sim_options={"config": ControllerConfig(warn_lim_pct=5.0)}) as rig:
        h = rig.streaming()
        q = rig.state()["q_cmd"][:6]
        rig.post("/api/target", h, json={"joints": [q[0] + 20.0, *q[1:]], "speed_scale": 0.5})  # not held
        s = rig.wait(lambda s: bool(s["alarms"]), 10.0, "a warning listed")
        first = s["alarms"][0]
        assert first["warning"] and first["code"] in ("MOTN-612", "MOTN-613", "MOTN-614"), s["alarms"]
        s = rig.wait(lambda s: first["code"] in codes(s["warnings"]), 5.0, f"{first['code']} in the warnings")
        assert s["state"] == "streaming" and s["fault"] is None, s
        assert s["warnings"][0]["message"] == first["message"], s["warnings"]


def warned(rig: Rig, h: dict[str, str]) -> dict[str, Any]:
    """A joint target that posts MOTN-612/613/614 ($WARN_LIM at 5 %), run to rest: the state once its
    warnings are active in both lists and the arm settled (so that no more come)."""
    q = rig.state()["q_cmd"][:6]
    rig.post("/api/target", h, json={"joints": [q[0] + 20.0, *q[1:]], "speed_scale": 0.5})
    rig.wait(lambda s: bool(s["alarms"]) and bool(s["warnings"]), 10.0, "warnings listed")
    rig.wait_at_rest_settled(10.0)
    return rig.wait(lambda s: set(codes(s["warnings"])) == set(codes(s["alarms"])), 5.0, "both lists alike")


def test_a_reset_and_a_new_stream_clear_the_active_warnings_their_history_keeps_them(tmp_path: Path) -> None:
    """The state's ``warnings`` are those active now, as ``alarms`` are: a reset (here after a fast stop)
    or a new stream clears them, and ``warning_history`` keeps them. Old code: ``warnings`` (the servo
    process's last ten) was never cleared, so the console listed a warning acknowledged long ago as
    active beside an empty ``alarms``."""
    with running_rig(tmp_path, sim_options={"config": ControllerConfig(warn_lim_pct=5.0)}) as rig:
        h = rig.streaming()
        first = warned(rig, h)["warnings"]
        rig.post("/api/session/stop", h, {"fast": True})
        rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 5.0, "fast stop")
        rig.post("/api/reset", h)  # acknowledges the stop and the warnings
        s = rig.wait(lambda s: not s["stop_fast"], 5.0, "the reset's safety view")
        assert (s["alarms"], s["warnings"]) == ([], []), (s["alarms"], s["warnings"])
        assert s["warning_history"][-len(first):] == first, s["warning_history"]
        assert set(codes(first)) <= set(codes(s["alarm_history"])), s["alarm_history"]

        rig.post("/api/session/resume", h)
        second = warned(rig, h)["warnings"]
        rig.end_and_wait(h)
        s = rig.state()
        assert s["warnings"] == second, "an ended stream's warnings stay until the next one"
        rig.start_streaming(h)
        s = rig.wait(lambda s: s["alarms"] == [], 5.0, "the new stream's empty alarm list")
        assert s["warnings"] == [], s["warnings"]
        assert s["warning_history"][-len(second):] == second, s["warning_history"]


# ----------------------------------------------------------------------------- a consistent view


def test_after_a_link_fault_no_status_flag_is_reported_as_live(tmp_path: Path) -> None:
    """Another socket stops the controller's status output mid-stream: the link faults. From then on
    the last status bits (SYSRDY among them: "READY") are history, not the controller's state now."""
    with running_rig(tmp_path) as rig:
        h = rig.lease()
        s = rig.start_streaming(h)
        assert s["status_live"] is True and s["status_bits"] == s["status_bits_last"] and s["status_bits"] & 4
        assert s["status_age_s"] < 0.5
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
            other.sendto(StatusStop().encode(), rig.service.robot_address)
            rig.wait_state("fault", timeout=5)
        seen = []
        s = rig.wait(lambda s: seen.append(s) or (s["fault"] or {}).get("code") == "MOTN-608", 5.0, "MOTN-608")
        for s in seen:
            assert s["link"] == "fault", s["link"]
            assert s["status_live"] is False and s["status_bits"] is None, s
            assert s["status_bits_last"] & 4  # the last status, from before the fault
        first_age = seen[0]["status_age_s"]
        s = rig.wait(lambda s: s["status_age_s"] > first_age + 0.1, 5.0, "the last status ages")
        assert s["status_live"] is False and s["status_bits"] is None
        rig.post("/api/reset", h)
        s = rig.wait_state("disconnected", "connected", "ready", timeout=15)
        assert s["status_bits"] is None or s["status_live"], s
        rig.post("/api/session/start", h)
        s = rig.wait(lambda s: s["status_live"], 5.0, "status live again")
        assert s["status_bits"] & 4 and s["state"] == "streaming"


# ------------------------------------------------------------------------------------------ settled


def watch_settling(rig: Rig, axes: slice, tol: float, after_settled_s: float = 0.3) -> list[dict[str, Any]]:
    """States from the end of a motion until ``settled`` has held for ``after_settled_s`` of the servo
    process's own publishing time."""
    seen: list[dict[str, Any]] = []
    deadline = time.monotonic() + 10.0
    settled_at = None
    while time.monotonic() < deadline:
        s = rig.state()
        seen.append(s)
        if s["settled"] and settled_at is None:
            settled_at = s["published_unix"]
        if settled_at is not None and s["published_unix"] - settled_at >= after_settled_s:
            break
        time.sleep(0.005)
    assert settled_at is not None, "never settled"
    final = np.array(seen[-1]["q_servo"])[axes]
    for s in seen:
        if s["settled"]:
            assert s["at_rest"], s
            off = np.abs(np.array(s["q_servo"])[axes] - final).max()
            assert off <= tol, f"settled with the reported position still {off} from where it came to rest"
    return seen


def test_fanuc_settled_only_once_the_reported_joints_stop(tmp_path: Path) -> None:
    # A slower servo than the simulator's default (time constant 30 cycles, 240 ms, not 3): the reported
    # joints then trail the stopped command by more than 0.05 deg for ~0.5 s, and the states are watched
    # from the jog's end on, with no gap between a wait for rest and the watch. At 3 cycles the window was
    # ~40 ms, and a CI run on a busy machine once saw no state inside it; at 10 cycles, with the watch
    # starting only after a wait for rest, a fresh clone's first run (its first service) saw none either.
    with running_rig(tmp_path, sim_options={"config": ControllerConfig(servo_tau_cycles=30.0)}) as rig:
        h = rig.lease()
        rig.start_streaming(h)
        for _ in range(2):
            rig.jog_for(h, JOG, 0.5, hold_ms=200)
            seen = watch_settling(rig, slice(0, 6), tol=0.01)  # (settled implies at rest: checked there)
            # The servo lags the command: at rest, yet still moving, not settled.
            final = np.array(seen[-1]["q_servo"])
            lagging = [s for s in seen if s["at_rest"] and np.abs(np.array(s["q_servo"]) - final).max() > 0.05]
            assert lagging and not any(s["settled"] for s in lagging), len(lagging)
        fams = {f.name: f for f in text_string_to_metric_families(rig.http.get("/metrics").text)}
        assert fams["servo_settled"].samples[0].value == 1.0


@pytest.fixture
def janome(tmp_path: Path) -> Iterator[tuple[Rig, JanomeSimulator]]:
    with running_janome_rig(tmp_path) as rig_and_robot:
        yield rig_and_robot


def test_janome_settled_only_once_the_robot_reports_its_last_move_done(janome: tuple[Rig, JanomeSimulator]) -> None:
    rig, _ = janome
    h = rig.lease()
    rig.wait_state("ready")
    rig.start_streaming(h)
    for _ in range(2):
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            rig.post("/api/jog", h, {"joints": [40.0, 0.0, 0.0, 0.0], "hold_ms": 300})
            time.sleep(0.1)
        rig.wait(lambda s: s["at_rest"], 5.0, "at rest")
        watch_settling(rig, slice(0, 4), tol=0.01)


def test_janome_robot_error_is_an_active_alarm_until_reset(tmp_path: Path) -> None:
    """The robot's own error (a target beyond its stroke, reported over the link as OUT_OF_RANGE) is
    listed with the FANUC alarms' fields; Janome's status has no clock: controller_time_ms is null."""
    service = ServoService(ServiceConfig(robot="janome:127.0.0.1:0", model="jr3000", var_dir=tmp_path))
    service.open()
    server = LiveServer(create_app(service, TOKEN)).start()
    rig = Rig(service, server, tmp_path)
    assert service.robot_address is not None
    # The robot's X stroke ends 5 mm beyond where it starts (the service's profile allows more).
    prof = service.profile
    hi = list(prof.axis_max)
    hi[0] = prof.home[0] + 5.0
    sim = JanomeSimulator(service.robot_address, replace(prof, axis_max=tuple(hi))).start()
    try:
        h = rig.lease()
        rig.wait_state("ready")
        rig.start_streaming(h)
        t0 = time.time()
        end = time.monotonic() + 3.0
        while rig.state()["state"] != "fault" and time.monotonic() < end:
            rig.http.post("/api/jog", json={"joints": [40.0, 0.0, 0.0, 0.0], "hold_ms": 300}, headers=h)
            time.sleep(0.1)
        s = rig.wait(lambda s: s["alarms"], 5.0, "the robot's alarm listed")
        code = s["fault"]["code"]
        assert code and code.startswith("JNM-"), s["fault"]
        a = s["alarms"][0]
        assert codes(s["alarms"]) == [code] and a["cause"] and a["remedy"] and a["warning"] is False
        assert t0 <= a["time_unix"] <= time.time() and a["controller_time_ms"] is None
        wait_metric(rig, "servo_alarms", "code", lambda c: c == {code: 1.0})
        wait_metric(rig, "servo_faults", "cause", lambda c: c == {code: 1.0})
        rig.post("/api/reset", h)
        s = rig.wait(lambda s: s["state"] != "fault", 5.0, "out of fault")
        assert s["alarms"] == [] and codes(s["alarm_history"]) == [code]
    finally:
        rig.http.close()
        sim.stop()
        server.stop()
        service.close()


def test_metrics_agree_with_the_state_and_drop_the_status_interval_when_status_stops(tmp_path: Path) -> None:
    """/metrics kept servo_status_interval_seconds at its last value after status packets stopped (and
    before any stream, 0), as if the link were healthy. Now it is there only while status arrives, and
    servo_state reads what GET /api/state does."""
    def scrape() -> tuple[dict[str, Any], str]:
        fams = {f.name: f for f in text_string_to_metric_families(rig.http.get("/metrics").text)}
        on = [x.labels["state"] for x in fams["servo_state"].samples if x.value == 1.0]
        assert len(on) == 1, on
        return fams, on[0]

    with running_rig(tmp_path) as rig:
        fams, state = scrape()
        assert "servo_status_interval_seconds" not in fams and state == rig.state()["state"] == "disconnected"
        h = rig.lease()
        rig.start_streaming(h)
        fams, state = scrape()
        assert 0.0 < fams["servo_status_interval_seconds"].samples[0].value < 0.1 and state == "streaming"
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as other:
            other.sendto(StatusStop().encode(), rig.service.robot_address)
        rig.wait(lambda s: s["state"] == "fault" and not s["status_live"], 5.0, "the link faulted")
        fams, state = scrape()
        assert "servo_status_interval_seconds" not in fams, fams["servo_status_interval_seconds"]
        assert state == rig.state()["state"] == "fault"
