"""The operator console (web/) through faults and another client: what it says and offers when the servo
process dies, a start cannot stream, the lease is taken over mid-jog, or the page loses the operator's
attention mid-jog.

Same rig as tests/test_web_console.py (its fixtures and helpers are reused): a real ``servo-app run``
with its embedded simulator, headless Chromium, checks through /api/state over HTTP.
"""

from __future__ import annotations

import os
import re
import signal
from pathlib import Path
from typing import Any

import pytest
import test_web_console as console
from test_web_console import Service, sign_in, take_control_and_stream

# The console tests' fixtures, found by pytest under these names: one browser and one service per module.
browser = console.browser
fanuc = console.fanuc
page = console.page

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def servo_pid(svc: Service) -> int:
    """The servo process streaming now: its pid is in the name of the session log it writes."""
    newest = svc.get("/api/sessions")[0]["name"]
    m = re.match(r"session-\d{8}-\d{6}-(\d+)-", newest)
    assert m, newest
    pid = int(m.group(1))
    assert f"PPid:\t{svc.proc.pid}\n" in Path(f"/proc/{pid}/status").read_text(), (pid, newest)
    return pid


def streaming_again(pg: Any, svc: Service) -> None:
    """Back to streaming through the console's own buttons: Reset (which also clears the embedded
    controller's alarm, as at its pendant, even where the service has no fault to reset), then Start."""
    pg.click("#reset")
    svc.wait(lambda s: s["state"] != "fault" and not s["not_ready"], "the fault and the alarm reset", timeout=15)
    pg.click("#start")
    svc.wait(lambda s: s["state"] == "streaming", "streaming again", timeout=30)


def test_a_start_that_cannot_stream_shows_the_services_reason(page: Any, fanuc: Service) -> None:
    """The servo process is killed mid-stream; Start alone brings up a new one, but the controller still
    holds the alarm of the stream it was starved of (SYSRDY off), so the service answers 409 with that
    reason after its 5 s start timeout. The console gave up after 3 s ("no answer in 3000 ms") and never
    showed the reason."""
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    os.kill(servo_pid(fanuc), signal.SIGKILL)
    fanuc.wait(lambda s: s["state"] == "fault" and s["servo_process"], "the servo process's death as a fault")
    page.wait_for_function("document.querySelector('#mode').textContent === 'fault'")
    page.click("#start")
    page.wait_for_function("document.querySelector('#message').textContent.includes('Start: start failed')",
                           timeout=20000)
    text = page.text_content("#message") or ""
    assert "no answer" not in text and "SYSRDY is off" in text, text
    streaming_again(page, fanuc)
