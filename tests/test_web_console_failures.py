"""The operator console (web/) when the service under it goes away or the telemetry socket goes
quiet: what it says and offers, and that a later message does not hide the cause shown before.

Same rig as tests/test_web_console.py (its browser and page fixtures and helpers are reused), but each
test that stops the service has a ``servo-app run`` of its own. The telemetry is silenced by routing
the page's WebSocket through Playwright (the socket to the service stays up, its messages are held).
"""

from __future__ import annotations

import re
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import test_web_console as console
from test_web_console import Service, hold, sign_in, take_control_and_stream

browser = console.browser
fanuc = console.fanuc
page = console.page

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


@pytest.fixture
def own(tmp_path: Path) -> Iterator[Service]:
    """A service for this test alone (it is stopped or restarted under the console)."""
    svc = Service(tmp_path)
    try:
        svc.wait_healthy()
        yield svc
    finally:
        svc.stop()


def test_a_service_gone_mid_jog_keeps_the_cause_beside_the_failed_stop(page: Any, own: Service) -> None:
    """The service stops while the operator holds a jog: the console stops the jog ("Jog stopped:
    telemetry connection closed") and sends STOP, which cannot reach the service. "STOP failed: ...
    Failed to fetch" then replaced the cause; now both are on screen."""
    sign_in(page, own)
    take_control_and_stream(page, own)
    page.check("input[name=jog-kind][value=joint]", force=True)
    hold(page, "[data-jog='+J1']", 0.3)
    try:
        own.proc.send_signal(signal.SIGINT)  # as from the terminal: the service ends and exits
        page.wait_for_function("document.querySelector('#message').textContent.includes('STOP failed')",
                               timeout=15000)
        text = page.text_content("#message") or ""
        # Whichever the console saw first: the telemetry socket closing or the jog getting no answer.
        assert re.fullmatch(r"Jog stopped: (telemetry connection closed|the service cannot be reached .*); "
                            r"STOP failed.*", text), text
        assert page.locator("button.jog.held").count() == 0
    finally:
        page.mouse.up()


def test_no_motion_starts_while_the_telemetry_is_lost(page: Any, fanuc: Service) -> None:
    """The console stops a held jog when its telemetry goes quiet (the operator can no longer see the
    arm), but Resume (button or R), Start, Go to target, a point's Go to and the jog pad stayed
    enabled: the arm could be set moving unseen. They are now disabled, saying why, until the
    telemetry is live again; STOP works throughout."""
    held = {"on": False}

    def route(ws: Any) -> None:
        server = ws.connect_to_server()
        server.on_message(lambda m: None if held["on"] else ws.send(m))

    page.route_web_socket("**/ws/telemetry*", route)
    resumes: list[str] = []
    page.on("request", lambda r: resumes.append(r.url) if r.url.endswith("/api/session/resume") else None)
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.click("#stop")
    fanuc.wait(lambda s: s["state"] == "stopped" and s["at_rest"], "stopped")
    page.wait_for_function("!document.querySelector('#resume').disabled")

    held["on"] = True
    page.wait_for_function("document.querySelector('#conn').textContent.startsWith('telemetry: lost')")
    page.wait_for_function("document.querySelector('#resume').disabled")
    for sel in ("#start", "#target-go"):
        assert page.locator(sel).is_disabled(), sel
    assert "disabled" in (page.get_attribute("#jog-pad", "class") or "")
    assert (page.get_attribute("#resume", "title") or "").startswith("telemetry lost: the console cannot show")
    page.keyboard.press("r")
    page.wait_for_function("document.querySelector('#message').textContent.startsWith('Resume: telemetry lost')")
    assert resumes == [] and fanuc.state()["state"] == "stopped"

    held["on"] = False
    page.wait_for_function("document.querySelector('#conn').textContent === 'telemetry: live'")
    page.click("#resume")  # waits until enabled again
    fanuc.wait(lambda s: s["state"] == "streaming", "streaming after resume")


def test_why_the_console_stopped_a_jog_stays_until_the_arm_moves_again(page: Any, fanuc: Service) -> None:
    """The console stops a held jog when its window loses focus and says so, but the message went
    away after 8 s, and the server's stop reason is only "stop requested": an operator back a little
    later saw a stopped arm and no cause. It now stays until the arm streams again. The page's clock
    is Playwright's, moved on 20 s at once rather than waited for."""
    page.clock.install()
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.check("input[name=jog-kind][value=joint]", force=True)
    hold(page, "[data-jog='+J1']", 0.3)
    try:
        page.evaluate("window.dispatchEvent(new Event('blur'))")
        said = "Jog stopped: the window lost focus (stop requested)"
        page.wait_for_function("said => document.querySelector('#message').textContent === said", arg=said)
    finally:
        page.mouse.up()
    fanuc.wait(lambda s: s["state"] == "stopped" and s["at_rest"], "stopped at rest")
    page.clock.fast_forward(20_000)
    assert page.locator("#message").is_visible() and page.text_content("#message") == said
    page.click("#resume")  # once the telemetry is live (the jump made it look stale)
    fanuc.wait(lambda s: s["state"] == "streaming", "streaming after resume")
    page.wait_for_function("document.querySelector('#message').hidden")


def test_a_held_jog_that_gets_no_answer_is_stopped_and_says_why(page: Any, fanuc: Service) -> None:
    """A held jog whose renewal got no answer (the network dropped it) only let go and said "Jog
    refused: POST /api/jog: Failed to fetch"; the arm went on until the service's hold-to-run ran out,
    and when the service itself had gone the STOP was never tried. It is now stopped as when the
    telemetry is lost: STOP, and the cause on screen. The jog requests alone are refused by routing
    them through Playwright; the STOP reaches the service."""
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.check("input[name=jog-kind][value=joint]", force=True)
    hold(page, "[data-jog='+J1']", 0.3)
    try:
        page.route("**/api/jog", lambda route: route.abort("connectionrefused"))
        said = "Jog stopped: the service cannot be reached (it has stopped, or the network is down) (stop requested)"
        page.wait_for_function("said => document.querySelector('#message').textContent === said", arg=said)
        assert page.locator("button.jog.held").count() == 0
    finally:
        page.mouse.up()
        page.unroute("**/api/jog")
    s = fanuc.wait(lambda s: s["state"] == "stopped" and s["at_rest"], "stopped")
    assert s["stop_reason"] == "stop requested", s["stop_reason"]
    page.click("#resume")
    fanuc.wait(lambda s: s["state"] == "streaming", "streaming after resume")


def test_a_service_restarted_under_the_console_shows_its_own_points(page: Any, own: Service,
                                                                    tmp_path: Path) -> None:
    """The service restarts on the same port with another var directory: the Points card went on
    listing the old service's points (Go to one: "no teach point named ..."). The console reads the
    list again when its telemetry comes back."""
    sign_in(page, own)
    take_control_and_stream(page, own)
    page.fill("#point-name", "before_restart")
    page.click("#point-teach")
    page.wait_for_selector("#point-list li[data-point='before_restart']")
    own.stop()
    page.wait_for_function("document.querySelector('#conn').textContent.startsWith('telemetry: lost')")
    (tmp_path / "again").mkdir()
    again = Service(tmp_path / "again", port=own.port)
    try:
        again.wait_healthy()
        page.wait_for_function("document.querySelector('#conn').textContent === 'telemetry: live'", timeout=20000)
        page.wait_for_selector("#point-list li.muted:text('no points taught')")
    finally:
        again.stop()


def test_control_lost_with_a_restarted_service_says_so(page: Any, own: Service, tmp_path: Path) -> None:
    """The console holds the lease when its service stops and another starts on the same port. While
    the telemetry was lost the control pill said "control: pytest" (its "you" dropped); once it came
    back the pill said "control: you" for a moment beside the Take control button, and the message
    said the lease "may have expired". Now the pill says "you" as long as the buttons do, and the
    message says the service restarted (the state's service_id changed). A MutationObserver records
    any moment where pill and buttons disagree."""
    sign_in(page, own)
    page.wait_for_selector("#signed:not([hidden])")
    page.click("#take")
    page.wait_for_selector("#release:not([hidden])")
    page.wait_for_function("document.querySelector('#lease-holder').textContent === 'control: you (pytest)'")
    page.evaluate("""() => {
        window.clashes = [];
        const check = () => {
            const pill = document.querySelector('#lease-holder').textContent;
            if (pill.startsWith('control: you') === document.querySelector('#release').hidden) {
                window.clashes.push(`${pill} / take ${document.querySelector('#take').hidden ? 'hidden' : 'shown'}`);
            }
        };
        new MutationObserver(check).observe(document.body, {subtree: true, childList: true, attributes: true,
                                                            characterData: true});
    }""")
    own.stop()
    page.wait_for_function("document.querySelector('#conn').textContent.startsWith('telemetry: lost')")
    assert page.text_content("#lease-holder") == "control: you (pytest)"
    (tmp_path / "again").mkdir()
    again = Service(tmp_path / "again", port=own.port)
    try:
        again.wait_healthy()
        page.wait_for_function("document.querySelector('#conn').textContent === 'telemetry: live'", timeout=20000)
        page.wait_for_selector("#take:not([hidden])")
        said = "control lost: the service restarted, and the control lease ended with it: take control again"
        page.wait_for_function("said => document.querySelector('#message').textContent === said", arg=said)
        page.wait_for_function("document.querySelector('#lease-holder').textContent === 'control: free'")
        assert page.evaluate("window.clashes") == []
    finally:
        again.stop()


def test_a_service_restarted_with_another_robot_rebuilds_the_jog_pad(page: Any, own: Service,
                                                                     tmp_path: Path) -> None:
    """The service restarts on the same port with --robot janome: the jog pad and the joint table
    were built once, for the FANUC arm, and stayed so until the page was reloaded (its jogs named
    axes the Janome has not). They are built again when the telemetry comes back from a service
    with another robot."""
    page.goto(own.url + "/")
    page.wait_for_selector("#joint-rows tr[data-joint='J6']")
    own.stop()
    page.wait_for_function("document.querySelector('#conn').textContent.startsWith('telemetry: lost')")
    (tmp_path / "again").mkdir()
    again = Service(tmp_path / "again", "--robot", "janome", port=own.port)
    try:
        again.wait_healthy()
        names = again.get("/api/robot")["joint_names"]
        page.wait_for_function("document.querySelector('#conn').textContent === 'telemetry: live'", timeout=20000)
        page.wait_for_function("names => [...document.querySelectorAll('#joint-rows tr')].map(r => r.dataset.joint)"
                               ".join() === names.join()", arg=names)
        jogs = page.eval_on_selector_all("#jog-pad [data-jog]", "bs => bs.map(b => b.dataset.jog)")
        assert jogs == [f"{sign}{n}" for n in names for sign in "-+"], jogs
        assert page.locator("#kind-group").is_hidden()  # the Janome jogs its axes: no Cartesian choice
    finally:
        again.stop()
