"""The console's Points card in headless Chromium against a real ``servo-app run`` (the rig and helpers
of tests/test_web_console.py): teach the arm's position under a name, see it listed, move away, "Go
to" brings the arm back, a refusal shows the server's words, delete removes it; zero alarms."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import test_web_console as console
from test_web_console import Service, at_rest_without_alarm, call, shot, sign_in, take_control_and_stream

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

# The console tests' fixtures, found by pytest under these names.
browser = console.browser
fanuc = console.fanuc
page = console.page


def test_teach_go_to_and_delete_from_the_points_card(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.wait_for_selector("#point-list li.muted:text('no points taught')")
    lease_id = page.evaluate("sessionStorage.getItem('servo.lease')")

    page.fill("#point-name", "bench_1")
    page.click("#point-teach")
    page.wait_for_selector("#point-list li[data-point='bench_1']")
    assert page.text_content("#point-message") == "taught bench_1"
    taught = fanuc.get("/api/points")[0]
    assert taught["name"] == "bench_1" and taught["taught_by"].startswith("pytest@")
    # The pose is the active tool's TCP: the list says which tool.
    assert taught["tool"] == "flange"
    assert page.text_content("#point-list li[data-point='bench_1'] .point-tool") == "@flange"

    # Somewhere else, then back with "Go to".
    q_away = [30.0, 10.0, -10.0, 0.0, -70.0, 20.0]
    call(fanuc, "POST", "/api/target", {"joints": q_away}, lease=lease_id)
    fanuc.wait(lambda s: s["at_rest"] and np.allclose(s["q_cmd"], q_away, atol=1e-3), "away")
    page.click("#point-list li[data-point='bench_1'] button:text('Go to')")
    s = fanuc.wait(lambda s: s["at_rest"] and np.allclose(s["q_cmd"], taught["joints"], atol=1e-3), "back at bench_1")
    assert page.text_content("#point-message") == "going to bench_1"
    at_rest_without_alarm(fanuc)
    shot(page, "console-points")

    # A refusal: the server's sentence, with what to do next.
    page.click("#end")
    fanuc.wait(lambda s: s["state"] == "ended", "ended")
    page.click("#point-list li[data-point='bench_1'] button:text('Go to')")
    page.wait_for_function("document.querySelector('#point-message').textContent.includes('refused (409)')")
    assert "start a new session: POST /api/session/start" in page.text_content("#point-message")

    page.click("#point-list li[data-point='bench_1'] button[aria-label='delete bench_1']")
    page.wait_for_selector("#point-list li.muted:text('no points taught')")
    assert fanuc.get("/api/points") == [] and s["alarms"] == []


def test_the_points_buttons_need_control(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    page.wait_for_selector("#signed:not([hidden])")
    assert page.locator("#point-teach").is_disabled()
