"""The operator console (web/) when the service under it goes away, restarts or drops the telemetry
socket: what it says, and that a later message does not hide the cause shown before.

Same rig as tests/test_web_console.py (its browser and page fixtures and helpers are reused), but each
test here has a ``servo-app run`` of its own, since it stops or restarts it.
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import test_web_console as console
from test_web_console import Service, hold, sign_in, take_control_and_stream

browser = console.browser
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
        assert text.startswith("Jog stopped: telemetry connection closed; STOP failed: "), text
        assert page.locator("button.jog.held").count() == 0
    finally:
        page.mouse.up()
