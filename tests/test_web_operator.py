"""The operator console (web/) against issue 14: continuous jog that keeps going while held, a header
that never contradicts itself, the Janome pose row, alarms with times, a layout where nothing covers
anything, the session-log plot's axes, target entry and the inputs card.

Same rig as tests/test_web_console.py (its fixtures and helpers are reused): a real ``servo-app run``
with its embedded simulator, headless Chromium, checks through /api/state over HTTP.
"""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_web_console import (  # noqa: F401 - fixtures are found by name
    TOKEN,
    Service,
    _service,
    at_rest_without_alarm,
    browser,
    fanuc,
    janome,
    page,
    shot,
    sign_in,
    take_control_and_stream,
)

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

# J2 leaning back: the flange ~220 mm from the base, pointing down; three +X holds (~225 mm) stay far
# from the stretched arm.
HOME = [0.0, -30.0, 0.0, 0.0, -90.0, 0.0]
WIDTHS = [{"width": 1280, "height": 800}, {"width": 1440, "height": 900}]


def call(svc: Service, method: str, path: str, body: Any = None, lease: str | None = None) -> Any:
    headers = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
    if lease:
        headers["X-Lease-Id"] = lease
    req = urllib.request.Request(svc.url + path, data=json.dumps(body).encode() if body is not None else None,
                                 method=method, headers=headers)
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.load(r)


def mouse_hold(pg: Any, selector: str, seconds: float) -> None:
    """A real press: the mouse moves onto the button's centre, goes down, stays ``seconds``, goes up."""
    box = pg.locator(selector).bounding_box()
    assert box is not None, selector
    pg.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    pg.mouse.down()
    pg.wait_for_timeout(seconds * 1000)
    pg.mouse.up()


def home(svc: Service) -> None:
    """Back to the simulator's start pose through the API (a joint target), so every test starts from
    the same place whatever the one before it did."""
    s = svc.state()
    lease = call(svc, "POST", "/api/lease", {"client": "pytest-home", "force": True})["lease_id"]
    try:
        if s["state"] in ("stopping", "stopped"):
            svc.wait(lambda s: s["state"] == "stopped", "stopped")
            call(svc, "POST", "/api/session/resume", {}, lease)
        elif s["state"] != "streaming":
            call(svc, "POST", "/api/session/start", {}, lease)
        svc.wait(lambda s: s["state"] == "streaming", "streaming", timeout=30)
        call(svc, "POST", "/api/target", {"joints": HOME}, lease)
        svc.wait(lambda s: s["at_rest"] and abs(s["q_cmd"][4] + 90.0) < 0.01, "home reached", timeout=30)
    finally:
        call(svc, "DELETE", "/api/lease", lease=lease)


# ---------------------------------------------------------------------------------- 1. jog
@pytest.mark.parametrize("viewport", WIDTHS, ids=lambda v: f"{v['width']}px")
def test_continuous_jog_keeps_moving_on_every_press(page: Any, fanuc: Service, viewport: dict[str, int]) -> None:
    """Three 1.5 s holds of +X with the real mouse: each moves the flange at least 40 mm (20 % of
    250 mm/s is 50 mm/s, so 75 mm asked). Before the fix, the stop reason shown after the first
    release wrapped the header; the next press cleared it, the page moved up under the mouse, and
    the button's pointerleave released the jog after ~3 mm."""
    home(fanuc)
    page.set_viewport_size(viewport)
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    header = page.locator("header.topbar")
    moved = []
    for i in range(3):
        before = at_rest_without_alarm(fanuc)
        h0 = header.bounding_box()
        box0 = page.locator("[data-jog='+X']").bounding_box()
        box = page.locator("[data-jog='+X']").bounding_box()
        assert box is not None
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.down()
        page.wait_for_timeout(1500)
        # Nothing moved on the page while the button was held.
        assert header.bounding_box() == h0, (h0, header.bounding_box())
        assert page.locator("[data-jog='+X']").bounding_box() == box0
        page.mouse.up()
        after = at_rest_without_alarm(fanuc)
        moved.append((round(after["cart_servo"][0] - before["cart_servo"][0], 1), after["stop_reason"]))
        shot(page, f"console-jog-hold-{viewport['width']}-{i + 1}")
    assert all(d >= 40.0 for d, _ in moved), moved
