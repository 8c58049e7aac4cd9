"""The console's tool selector and the TCP in the arm view, in headless Chromium against a real
``servo-app run --tools`` (the helpers of tests/test_web_console.py): the active tool shows, the
selector changes it at rest and is disabled while the arm moves, the TCP is drawn in its own colour;
zero alarms."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import test_web_console as console
from test_web_console import Service, at_rest_without_alarm, call, shot, sign_in, take_control_and_stream

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

browser = console.browser
page = console.page

TOOLS = """
active = "gripper"

[tools.gripper]
xyzwpr = [0, 0, 150, 0, 0, 0]
payload_kg = 2.5

[tools.probe]
xyzwpr = [0, 40, 220, 0, 0, 0]
payload_kg = 0.5
"""


@pytest.fixture(scope="module")
def tooled(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    d = tmp_path_factory.mktemp("tools-console")
    (d / "tools.toml").write_text(TOOLS)
    yield from console._service(tmp_path_factory, "tools-service", "--tools", str(Path(d / "tools.toml")))


def tcp_drawn(pg: Any) -> dict[str, Any]:
    """Where the side view drew the TCP (its data-tcp), once it has."""
    pg.wait_for_function("document.querySelector('#arm-side').dataset.tcp !== undefined")
    return json.loads(pg.get_attribute("#arm-side", "data-tcp") or "{}")


def pixel(pg: Any, x: float, y: float) -> list[int]:
    """The side view's colour at CSS pixel (x, y)."""
    return pg.evaluate("""([x, y]) => {
        const c = document.querySelector('#arm-side');
        const dpr = c.width / c.clientWidth;
        return Array.from(c.getContext('2d').getImageData(Math.round(x * dpr), Math.round(y * dpr), 1, 1).data);
    }""", [x, y])


def test_the_active_tool_shows_changes_at_rest_and_is_drawn(page: Any, tooled: Service) -> None:
    sign_in(page, tooled)
    page.wait_for_function("document.querySelector('#tool-select').options.length === 3")
    assert page.input_value("#tool-select") == "gripper"
    assert "150.0" in page.text_content("#tool-info") and "2.50 kg" in page.text_content("#tool-info")
    assert page.locator("#tool-select").is_disabled(), "no control: the selector is disabled"

    drawn = tcp_drawn(page)
    assert drawn["tool"] == "gripper"
    r, g, b, _ = pixel(page, drawn["x"], drawn["y"])
    assert (r, g, b) == (0xFF, 0x3D, 0xF5), "the TCP dot in its own colour"

    take_control_and_stream(page, tooled)
    at_rest_without_alarm(tooled)
    page.wait_for_function("!document.querySelector('#tool-select').disabled")
    page.select_option("#tool-select", "probe")
    page.wait_for_function("document.querySelector('#tool-message').textContent === 'tool probe active'")
    assert tooled.state()["tool"]["name"] == "probe"
    page.wait_for_function("JSON.parse(document.querySelector('#arm-side').dataset.tcp || '{}').tool === 'probe'",
                           timeout=5000)
    assert "0.50 kg" in page.text_content("#tool-info")

    # Moving: the selector is disabled; at rest again it is back.
    lease_id = page.evaluate("sessionStorage.getItem('servo.lease')")
    call(tooled, "POST", "/api/target", {"joints": [20.0, 5.0, -5.0, 0.0, -80.0, 10.0]}, lease=lease_id)
    page.wait_for_function("document.querySelector('#tool-select').disabled", timeout=5000)
    shot(page, "console-tool-moving")
    s = at_rest_without_alarm(tooled)
    page.wait_for_function("!document.querySelector('#tool-select').disabled", timeout=10000)
    page.select_option("#tool-select", "gripper")
    page.wait_for_function("document.querySelector('#tool-message').textContent === 'tool gripper active'")
    shot(page, "console-tool")
    assert s["alarms"] == [] and tooled.state()["alarms"] == []


LAPTOPS = [{"width": 1280, "height": 800}, {"width": 1366, "height": 768}, {"width": 1440, "height": 900}]


@pytest.mark.parametrize("viewport", LAPTOPS, ids=lambda v: f"{v['width']}x{v['height']}")
def test_the_tool_selector_is_on_the_first_screen_at_laptop_sizes(page: Any, tooled: Service,
                                                                  viewport: dict[str, int]) -> None:
    """The operator changes the tool without scrolling: at the top of the page the selector and its TCP
    line lie inside the window, clear of STOP, and a change made there takes effect. (Under the arm
    views it was 200-260 px below the window's bottom at these sizes.)"""
    page.set_viewport_size(viewport)
    sign_in(page, tooled)
    page.wait_for_function("document.querySelector('#tool-select').options.length === 3")
    take_control_and_stream(page, tooled)
    at_rest_without_alarm(tooled)
    page.wait_for_function("!document.querySelector('#tool-select').disabled", timeout=10000)
    page.evaluate("window.scrollTo(0, 0)")
    stop = page.locator("#stop").bounding_box()
    assert stop is not None
    for selector in ("#tool-select", "#tool-info"):
        box = page.locator(selector).bounding_box()
        assert box is not None, selector
        assert box["y"] >= 0 and box["y"] + box["height"] <= viewport["height"], (selector, box, viewport)
        assert box["x"] >= 0 and box["x"] + box["width"] <= viewport["width"], (selector, box, viewport)
        clear = (box["x"] + box["width"] <= stop["x"] or stop["x"] + stop["width"] <= box["x"]
                 or box["y"] + box["height"] <= stop["y"] or stop["y"] + stop["height"] <= box["y"])
        assert clear, (selector, box, stop)
    other = "probe" if tooled.state()["tool"]["name"] != "probe" else "gripper"
    page.select_option("#tool-select", other)
    page.wait_for_function(f"document.querySelector('#tool-message').textContent === 'tool {other} active'")
    assert tooled.state()["tool"]["name"] == other
    assert page.evaluate("window.scrollY") == 0, "the change needed no scrolling"
    shot(page, f"console-tool-{viewport['width']}x{viewport['height']}")
