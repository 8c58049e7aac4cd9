"""The console shows a trajectory replay's progress (POST /api/trajectory), in headless Chromium
against a real ``servo-app run`` (the helpers of tests/test_web_console.py): the bar fills as the replay
plays, says paused on a stop and done at the end; a replay another command ended says why; zero alarms."""

from __future__ import annotations

from typing import Any

import pytest
import test_web_console as console
from test_web_console import Service, at_rest_without_alarm, call, shot, sign_in, take_control_and_stream

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

browser = console.browser
page = console.page
fanuc = console.fanuc

GOAL = [35.0, 15.0, -5.0, 15.0, -65.0, 45.0]
HOME = [0.0, 10.0, -10.0, 0.0, -80.0, 0.0]


def progress(pg: Any) -> float:
    return float(pg.evaluate("document.querySelector('#replay-progress').value"))


def test_the_replay_progress_fills_pauses_and_ends(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    at_rest_without_alarm(fanuc)
    lease_id = page.evaluate("sessionStorage.getItem('servo.lease')")
    call(fanuc, "POST", "/api/trajectory", {"joints": [HOME, GOAL], "speed_scale": 0.5}, lease=lease_id)
    page.wait_for_function("!document.querySelector('#replay-row').hidden")
    page.wait_for_function("document.querySelector('#replay-progress').value > 0.3", timeout=15000)
    call(fanuc, "POST", "/api/session/stop", None, lease=lease_id)
    page.wait_for_function("document.querySelector('#replay-row').dataset.state === 'paused'", timeout=10000)
    paused_at = progress(page)
    assert 0.3 < paused_at < 1.0
    assert "paused (resume continues it)" in page.text_content("#replay-info")
    shot(page, "console-replay-paused")
    call(fanuc, "POST", "/api/session/resume", None, lease=lease_id)
    page.wait_for_function("document.querySelector('#replay-row').dataset.state === 'done'", timeout=20000)
    assert progress(page) == 1.0 and page.text_content("#replay-info").startswith("100 %")

    # Another command ends a replay: the row says why.
    call(fanuc, "POST", "/api/trajectory", {"joints": [HOME]}, lease=lease_id)
    page.wait_for_function("document.querySelector('#replay-row').dataset.state === 'playing'", timeout=10000)
    call(fanuc, "POST", "/api/jog", {"joints": [0.0, 0.0, 0.0, 0.0, 0.0, 5.0]}, lease=lease_id)
    page.wait_for_function("document.querySelector('#replay-row').dataset.state === 'ended'", timeout=10000)
    assert "ended: a jog took over" in page.text_content("#replay-info")
    s = at_rest_without_alarm(fanuc)
    assert s["alarms"] == []
