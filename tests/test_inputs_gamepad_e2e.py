"""The gamepad end to end: SDL's virtual joystick (a real SDL device, in the test process where the
service's inputs bridge runs) drives the simulated arm through the service (`servo-app run --inputs` in
the test harness: uvicorn on loopback, the servo process and the simulator in processes of their own).
Hold-to-run, an output button, a pad unplugged mid-jog. Zero controller alarms."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np
import pytest
from test_api_harness import AUTH, Rig, running_rig

from servo_app.inputs.gamepad.adapter import GamepadAdapter
from servo_app.inputs.gamepad.mapping import BUTTON_NAMES
from servo_app.inputs.gamepad.sdl import VirtualPad

pytestmark = pytest.mark.e2e

# A little more staleness margin than a pad needs: the adapter is a thread of a busy test process.
INPUTS = """
[adapters.gamepad]
type = "gamepad"
stale_after_s = 0.25
realtime_priority = 0
reconnect_min_s = 0.05
reconnect_max_s = 0.2
deadband = 0.1
expo = 0.5
max_linear_mm_s = 60.0
frames = ["base", "tool"]
[adapters.gamepad.buttons]
a = "toggle_output:DO[2]"
b = "stop"

# An automatic source below the pad (priority 0): it commands while the pad yields.
[feeds.auto]
kind = "twist"
stale_after_s = 0.25
"""


@dataclass
class Cell:
    rig: Rig
    pads: list[VirtualPad]  # every pad plugged in; the last is the one in use

    @property
    def pad(self) -> VirtualPad:
        return self.pads[-1]

    @property
    def adapter(self) -> GamepadAdapter:
        (a,) = self.rig.service.inputs.adapters
        assert isinstance(a, GamepadAdapter)
        return a

    def pose(self) -> np.ndarray:
        return np.array(self.rig.state()["cart_servo"])

    def source(self) -> dict[str, Any]:
        r = self.rig.http.get("/api/inputs")
        assert r.status_code == 200, r.text
        return next(s for s in r.json()["sources"] if s["name"] == "gamepad")  # type: ignore[no-any-return]

    def read_by_the_adapter(self, button: str, held: bool) -> None:
        """Set a button and wait until the adapter has read it (a person's press outlasts a poll)."""
        self.pad.button(button, held)
        bit = 1 << BUTTON_NAMES.index(button)
        wait(lambda: bool(self.adapter.logic.buttons & bit) == held, f"{button} {'held' if held else 'released'}")


def wait(pred: Any, what: str, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    tmp = tmp_path_factory.mktemp("gamepad")
    path = tmp / "inputs.toml"
    path.write_text(INPUTS)
    pads = [VirtualPad("Virtual Xbox pad")]  # plugged in before the service starts: SDL starts in this thread first
    try:
        with running_rig(tmp, inputs_config=path) as rig:
            c = Cell(rig, pads)
            wait(lambda: c.adapter.connected, "the pad opened", 10.0)
            yield c
            assert rig.sim_alarms() == [], rig.sim_alarms()
            assert rig.state()["faults"] == []
            assert c.pad.rumbles == []  # no fault, no rumble
            bridge = rig.service.inputs
        assert not any(a.running or a.connected for a in bridge.adapters)
    finally:
        for pad in pads:
            pad.close()


def ready(cell: Cell) -> dict[str, str]:
    """Hold the lease, have a stream running, enable input control; the pad at rest and connected."""
    rig = cell.rig
    h = rig.streaming("operator")
    rig.post("/api/inputs/enable", h, {"enable": True})
    return h


def done(cell: Cell, h: dict[str, str]) -> None:
    for name in ("leftx", "lefty", "rightx", "righty", "lefttrigger", "righttrigger"):
        cell.pad.axis(name, 0.0)
    cell.rig.post("/api/inputs/enable", h, {"enable": False})
    assert cell.rig.sim_alarms() == [], cell.rig.sim_alarms()


def at_rest(cell: Cell, timeout: float = 3.0) -> dict[str, Any]:
    return cell.rig.wait_at_rest_settled(timeout)


def moving(cell: Cell) -> None:
    cell.rig.wait(lambda s: max(map(abs, s["vel"])) > 1.0, 3.0, "moving")


def cosine(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))


def test_sticks_move_the_arm_only_while_the_deadman_is_held(cell: Cell) -> None:
    h = ready(cell)
    p0 = cell.pose()
    cell.pad.axis("lefty", -1.0)  # left stick forward: +X in the base frame, deadman not held
    time.sleep(0.3)  # a while with the stick forward and no deadman: the arm must not move
    assert np.allclose(cell.pose()[:3], p0[:3], atol=1e-3) and cell.rig.state()["at_rest"]
    cell.read_by_the_adapter("leftshoulder", True)
    moving(cell)
    time.sleep(0.4)
    cell.read_by_the_adapter("leftshoulder", False)  # released, the stick still forward: the arm stops
    s = at_rest(cell)
    assert s["state"] == "streaming" and s["inputs"]["active"] == "gamepad"  # at rest, not stopped
    p1 = cell.pose()
    d = p1[:3] - p0[:3]
    print(f"gamepad +x: moved {d.round(2)} mm")
    assert np.linalg.norm(d) > 10 and cosine(d, np.array([1.0, 0.0, 0.0])) > 0.99
    time.sleep(0.3)
    assert np.allclose(cell.pose()[:3], p1[:3], atol=1e-3)

    cell.pad.axis("lefty", 0.0)
    cell.pad.axis("righty", -1.0)  # right stick forward: +Z
    cell.read_by_the_adapter("leftshoulder", True)
    moving(cell)
    time.sleep(0.4)
    cell.read_by_the_adapter("b", True)  # stop: the arm comes to rest with the deadman still held
    at_rest(cell)
    p2 = cell.pose()
    d = p2[:3] - p1[:3]
    print(f"gamepad +z, then stop: moved {d.round(2)} mm")
    assert np.linalg.norm(d) > 10 and cosine(d, np.array([0.0, 0.0, 1.0])) > 0.99
    time.sleep(0.3)
    assert np.allclose(cell.pose()[:3], p2[:3], atol=1e-3)
    cell.read_by_the_adapter("b", False)
    cell.read_by_the_adapter("leftshoulder", False)
    done(cell, h)


def test_a_button_toggles_an_output_under_input_control(cell: Cell) -> None:
    service = cell.rig.service

    def actions() -> list[dict[str, Any]]:
        return cell.rig.http.get("/api/inputs").json()["button_actions"]  # type: ignore[no-any-return]

    def press_and_wait() -> dict[str, Any]:
        n = len(actions())
        cell.read_by_the_adapter("a", True)
        cell.read_by_the_adapter("a", False)
        wait(lambda: len(actions()) > n, "the press was acted on")
        return actions()[-1]

    h = ready(cell)
    before = service.io_read("DO", 1, 0xFFFF)
    row = press_and_wait()
    assert row["ok"] and row["source"] == "gamepad" and row["action"] == "toggle_output:DO[2]"
    assert service.io_read("DO", 1, 0xFFFF) == before ^ 0b10  # DO[2] flipped, its neighbours untouched
    assert press_and_wait()["ok"]
    assert service.io_read("DO", 1, 0xFFFF) == before
    done(cell, h)


def test_a_pad_unplugged_mid_jog_stops_the_arm_and_is_reported(cell: Cell) -> None:
    h = ready(cell)
    cell.pad.axis("leftx", -1.0)  # +Y
    cell.read_by_the_adapter("leftshoulder", True)
    moving(cell)
    stale_before = cell.rig.http.get("/api/inputs").json()["stale_events"].get("gamepad", 0)
    cell.pad.detach()  # mid-jog
    s = cell.rig.wait(lambda s: s["state"] == "stopped" and s["stop_reason"] is not None, 3.0, "stopped")
    assert s["stop_reason"] == "input gamepad stale" and not s["stop_fast"]
    wait(lambda: cell.source()["failure"] is not None, "the failure reported")
    src = cell.source()
    assert src["stale"] and not src["connected"]
    assert "no game controller is plugged in" in src["failure"]["reason"] and src["failure"]["fix"]
    assert cell.rig.http.get("/api/inputs").json()["stale_events"]["gamepad"] == stale_before + 1
    at_rest(cell)
    assert cell.rig.sim_alarms() == []
    # Plugged in again with the deadman held and the stick deflected: it reconnects and does not move.
    cell.pad.close()
    cell.pads.append(VirtualPad("Virtual Xbox pad"))
    cell.pad.button("leftshoulder", True)
    cell.pad.axis("leftx", -1.0)
    wait(lambda: cell.source()["connected"] and cell.source()["failure"] is None, "reconnected")
    h = ready(cell)
    p = cell.pose()
    time.sleep(0.3)
    assert np.allclose(cell.pose()[:3], p[:3], atol=1e-3)
    cell.read_by_the_adapter("leftshoulder", False)
    done(cell, h)


def test_the_stop_button_holds_the_arm_while_a_lower_priority_source_commands(cell: Cell) -> None:
    """The pad yields to lower-priority sources while idle; its stop used to be idle too, so a live
    automatic source took the arm the operator had just stopped. Now the stop holds until the deadman
    is pressed anew; a plain release still hands the arm over, as configured."""
    h = ready(cell)
    feed = httpx.Client(base_url=cell.rig.base_url, timeout=5.0, headers=AUTH)
    quit_feed = threading.Event()
    errors: list[str] = []

    def auto() -> None:  # +Y at 30 mm/s all along, 20 times a second
        while not quit_feed.wait(0.05):
            r = feed.post("/api/feed/auto", json={"kind": "twist", "linear": [0.0, 30.0, 0.0], "stamp": time.time()})
            if r.status_code != 200:
                errors.append(r.text)

    poster = threading.Thread(target=auto, name="auto-feed", daemon=True)
    poster.start()
    try:
        cell.pad.axis("lefty", -1.0)  # +X
        cell.read_by_the_adapter("leftshoulder", True)
        moving(cell)
        assert cell.rig.state()["inputs"]["active"] == "gamepad"
        cell.read_by_the_adapter("b", True)  # stop, the deadman still held
        s = at_rest(cell)
        assert s["state"] == "streaming" and s["inputs"]["active"] == "gamepad"
        p = cell.pose()
        time.sleep(0.4)  # a while with the automatic source live: the arm must stay where it stopped
        assert np.allclose(cell.pose()[:3], p[:3], atol=1e-3) and cell.rig.state()["inputs"]["active"] == "gamepad"
        cell.read_by_the_adapter("b", False)
        cell.read_by_the_adapter("leftshoulder", False)  # released too: the stop still holds
        cell.pad.axis("lefty", 0.0)
        time.sleep(0.3)
        assert np.allclose(cell.pose()[:3], p[:3], atol=1e-3) and cell.rig.state()["inputs"]["active"] == "gamepad"
        cell.read_by_the_adapter("leftshoulder", True)  # pressed anew (sticks centred): the stop is over
        cell.read_by_the_adapter("leftshoulder", False)  # a plain release: the pad yields, as configured
        cell.rig.wait(lambda s: s["inputs"]["active"] == "auto", 3.0, "the pad yields once released")
        s = cell.rig.wait(lambda s: s["cart_servo"][1] - p[1] > 5.0, 5.0, "the automatic source moves the arm")
        d = np.array(s["cart_servo"][:3]) - p[:3]
        assert cosine(d, np.array([0.0, 1.0, 0.0])) > 0.99, d  # its +Y
    finally:  # whatever happened, the next test finds the pad released and input control off
        cell.pad.button("b", False)
        cell.pad.button("leftshoulder", False)
        cell.rig.post("/api/inputs/enable", h, {"enable": False})  # before the feed ends: no stale stop
        quit_feed.set()
        poster.join(5.0)
        feed.close()
    assert not errors, errors
    at_rest(cell)
    done(cell, h)


def test_the_pad_follows_the_robots_state_for_its_rumble(cell: Cell) -> None:
    """The bridge hands the service's published state to the adapter; with no fault nothing rumbles
    (the rumble itself is tested on the virtual pad in test_inputs_gamepad)."""
    adapter = cell.adapter
    assert adapter.robot_state is not None and adapter.robot_state()["state"] in ("streaming", "stopped", "ready",
                                                                                   "connected", "ended")
    checked = adapter._robot_checked_at
    wait(lambda: adapter._robot_checked_at > checked, "the adapter looked at the robot's state")
    assert adapter.rumbles == 0 and cell.pad.rumbles == []
