"""The console's Points card in headless Chromium against a real ``servo-app run`` (the rig and helpers
of tests/test_web_console.py): teach the arm's position under a name, see it listed, move away, "Go
to" brings the arm back, a refusal shows the server's words, delete removes it; zero alarms."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import test_web_console as console
from test_web_console import (
    Service,
    at_rest_without_alarm,
    call,
    console_page,
    rewrite_telemetry,
    shot,
    sign_in,
    take_control_and_stream,
)

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
    page.wait_for_function("document.querySelector('#point-message').textContent.startsWith('Go to bench_1 refused')")
    assert page.text_content("#point-message").endswith("start a new session: press Start")

    page.click("#point-list li[data-point='bench_1'] button[aria-label='delete bench_1']")
    page.wait_for_selector("#point-list li.muted:text('no points taught')")
    assert fanuc.get("/api/points") == [] and s["alarms"] == []


def test_the_points_buttons_need_control(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    page.wait_for_selector("#signed:not([hidden])")
    assert page.locator("#point-teach").is_disabled()


@pytest.fixture
def asking_page(browser: Any) -> Iterator[tuple[Any, list[str], list[bool]]]:
    """A page whose dialogs are answered from ``answers`` (True: OK), their texts kept in ``asked``."""
    asked: list[str] = []
    answers: list[bool] = []

    def answer(d: Any) -> None:
        asked.append(d.message)
        d.accept() if (answers.pop(0) if answers else True) else d.dismiss()

    with console_page(browser, answer) as pg:
        yield pg, asked, answers


def test_teaching_a_name_again_asks_before_replacing(asking_page: tuple[Any, list[str], list[bool]],
                                                     fanuc: Service) -> None:
    """Teaching under a name already listed replaced that point silently; now the console asks, and
    keeps the point unless the operator says to replace it."""
    page, asked, answers = asking_page
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    lease_id = page.evaluate("sessionStorage.getItem('servo.lease')")
    with contextlib.suppress(Exception):
        call(fanuc, "DELETE", "/api/points/twice", lease=lease_id)
    page.fill("#point-name", "twice")
    page.click("#point-teach")
    page.wait_for_selector("#point-list li[data-point='twice']")
    first = fanuc.get("/api/points")
    assert asked == []

    q_away = [20.0, 5.0, -5.0, 0.0, -80.0, 10.0]
    call(fanuc, "POST", "/api/target", {"joints": q_away}, lease=lease_id)
    fanuc.wait(lambda s: s["settled"] and np.allclose(s["q_cmd"], q_away, atol=1e-3), "away, settled")
    answers.append(False)  # Cancel: the point stays as taught
    page.click("#point-teach")
    page.wait_for_function("document.querySelector('#point-message').textContent === 'kept twice: nothing taught'")
    assert len(asked) == 1 and asked[0].startswith("Replace the point twice (taught by pytest@"), asked
    assert fanuc.get("/api/points") == first

    answers.append(True)  # OK: replaced by the arm's position now
    page.click("#point-teach")
    page.wait_for_function("document.querySelector('#point-message').textContent === 'taught twice'")
    assert len(asked) == 2
    (point,) = [p for p in fanuc.get("/api/points") if p["name"] == "twice"]
    assert np.allclose(point["joints"], q_away, atol=1e-3)

    # Where no point can be taught (no stream), the console does not ask first: the refusal says why.
    page.click("#end")
    fanuc.wait(lambda s: s["state"] == "ended", "ended")
    page.wait_for_function("document.querySelector('#mode').textContent === 'ended'")
    page.click("#point-teach")
    page.wait_for_function("document.querySelector('#point-message').textContent.startsWith('Teach refused')")
    assert page.text_content("#point-message").endswith("start one: press Start")
    assert len(asked) == 2, asked
    call(fanuc, "DELETE", "/api/points/twice", lease=lease_id)


def test_teaching_again_asks_from_the_state_now_not_from_the_last_telemetry_frame(
        asking_page: tuple[Any, list[str], list[bool]], fanuc: Service) -> None:
    """The console chose whether to ask from its last telemetry frame, which can be a frame behind the
    service: an arm that had just settled was taken for a moving one, the teach went out without
    replacing and the server refused the name (a CI run failed so). Here every frame says the arm is
    not settled, while the service says it is: the console still asks, and replaces on OK."""
    page, asked, answers = asking_page

    def not_settled(frame: dict[str, Any]) -> None:
        if "settled" in frame:
            frame["settled"] = False

    rewrite_telemetry(page, not_settled)
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    lease_id = page.evaluate("sessionStorage.getItem('servo.lease')")
    with contextlib.suppress(Exception):
        call(fanuc, "DELETE", "/api/points/lagging", lease=lease_id)
    fanuc.wait(lambda s: s["settled"], "settled")
    call(fanuc, "POST", "/api/points/lagging", lease=lease_id)

    answers.append(True)
    page.fill("#point-name", "lagging")
    page.click("#point-teach")
    page.wait_for_function("document.querySelector('#point-message').textContent === 'taught lagging'")
    assert len(asked) == 1 and asked[0].startswith("Replace the point lagging"), asked
    call(fanuc, "DELETE", "/api/points/lagging", lease=lease_id)


@pytest.mark.parametrize("width", [800, 1280, 1366, 1440])
def test_a_long_point_name_stays_inside_the_card(page: Any, fanuc: Service, width: int) -> None:
    """A name of 64 characters (the most allowed) without a space ran out of the Points card at every
    laptop width: the list scrolled sideways and the name was cut at the card's edge."""
    name = f"{'L' * 60}_{width}"[-64:]
    page.set_viewport_size({"width": width, "height": 900})
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    lease_id = page.evaluate("sessionStorage.getItem('servo.lease')")
    page.fill("#point-name", name)
    page.click("#point-teach")
    try:
        page.wait_for_selector(f"#point-list li[data-point='{name}']")
        fits = page.evaluate("""(name) => {
          const list = document.querySelector('#point-list');
          const b = list.querySelector(`li[data-point='${name}'] b`);
          const card = document.querySelector('#points-card').getBoundingClientRect();
          const r = b.getBoundingClientRect();
          return [list.scrollWidth <= list.clientWidth, b.scrollWidth <= b.clientWidth,
                  r.left >= card.left && r.right <= card.right];
        }""", name)
        assert fits == [True, True, True], (width, fits)
    finally:
        call(fanuc, "DELETE", f"/api/points/{name}", lease=lease_id)
