"""The console's alarm card and the servo process's warnings: its history shows them after a reset,
beside the controller's alarms (which ``alarm_history`` keeps), each once.

Since GET /api/state's ``warnings`` became those active now (a reset or a new stream clears them;
``warning_history`` keeps the last 20), a warning only the servo process raises (a Janome link
warning, the session log's) was gone from the console at the first reset: its history read
``alarm_history`` alone. A controller's warning (MOTN-612/613/614) is in both the controller's lists
and the servo process's, and was listed twice as active.

A running service (tests/test_api_harness.py's rigs: uvicorn on loopback, the servo process, the
simulators) and headless Chromium (tests/test_web_console.py's browser and page fixtures).
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import pytest
import test_web_console as console
from test_alarms_state_e2e import codes, warned
from test_api_harness import Rig, running_janome_rig, running_rig

from servo_app.sim.fanuc_model import ControllerConfig

browser = console.browser
page = console.page

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

HMS = re.compile(r"\d\d:\d\d:\d\d\.\d{3}")


def open_console(pg: Any, rig: Rig) -> None:
    pg.goto(rig.base_url + "/")
    pg.wait_for_function("document.querySelector('#conn').textContent.includes('live')")


def listed(pg: Any, box: str) -> list[dict[str, str]]:
    """The items of ``#alarm-list`` or ``#alarm-history``, top (newest) first."""
    return pg.eval_on_selector_all(f"#{box} li.alarm", """items => items.map((li) => ({
        code: li.dataset.code, kind: li.dataset.kind, tag: li.querySelector('.kind')?.textContent ?? '',
        when: li.querySelector('.when')?.textContent ?? '', text: li.textContent}))""")


def fast_stop_and_reset(rig: Rig, h: dict[str, str]) -> dict[str, Any]:
    """A fast stop, acknowledged by a reset: the state once the reset cleared the active lists."""
    rig.post("/api/session/stop", h, {"fast": True})
    rig.wait(lambda s: s["state"] == "stopped" and s["at_rest"], 10.0, "fast stop")
    rig.post("/api/reset", h)
    return rig.wait(lambda s: not s["stop_fast"] and s["warnings"] == [] and s["alarms"] == [], 10.0, "reset")


def test_a_servo_process_warning_stays_in_the_console_history_after_a_reset(page: Any, tmp_path: Path) -> None:
    """A Janome link warning (the robot rejected a corrupted target, which was sent again) is the
    servo process's alone: listed as an active warning, with its wall-clock time; after a reset
    nothing is active, and the history still lists it, once, marked as a warning. Old code: the
    history was ``alarm_history`` alone, so it was gone, and the link's last error (the rejection
    again, ``link_error``) stayed in the active list until the next connection."""
    with running_janome_rig(tmp_path) as (rig, sim):
        h = rig.lease()
        rig.wait_state("ready")
        rig.start_streaming(h)
        open_console(page, rig)
        sim.corrupt_next_target()
        s = rig.wait(lambda s: bool(s["warnings"]), 5.0, "the link warning")
        w = s["warnings"][-1]
        assert w["code"] == "link" and w["message"].startswith("robot rejected target"), w
        assert abs(w["time_unix"] - time.time()) < 5.0, (w, time.time())  # the servo clock, as wall clock
        assert "link" not in codes(s.get("alarm_history") or []), s["alarm_history"]

        page.wait_for_selector("#alarm-list li[data-code='link']", timeout=10000)
        active = [a for a in listed(page, "alarm-list") if a["code"] == "link"]
        assert len(active) == 1 and w["message"] in active[0]["text"] and HMS.search(active[0]["when"]), active
        console.shot(page, "console-warning-active")

        s = fast_stop_and_reset(rig, h)
        assert codes(s["warning_history"]).count("link") == 1, s["warning_history"]
        # The link's last error (the same rejection), listed as active too, is acknowledged with it.
        assert s["link_error"] == "", s["link_error"]
        page.wait_for_selector("#alarm-list li.muted", timeout=10000)  # "no alarms"
        assert listed(page, "alarm-list") == [], listed(page, "alarm-list")
        page.click("#alarm-history-box summary")
        past = [a for a in listed(page, "alarm-history") if a["code"] == "link"]
        assert len(past) == 1, listed(page, "alarm-history")  # old code: [] (alarm_history alone)
        assert past[0]["kind"] == "warning" and past[0]["tag"] == "warning", past
        assert w["message"] in past[0]["text"] and HMS.search(past[0]["when"]), past
        assert page.text_content("#alarm-history-count") == f"({len(s.get('alarm_history') or []) + 1})"
        assert page.text_content("#alarm-count") == "0"
        # At common laptop widths the marked item stays inside its card, and nothing scrolls sideways.
        for width in (1280, 1366, 1440):
            page.set_viewport_size({"width": width, "height": 800})
            card = page.locator("#alarms-card").bounding_box()
            item = page.locator("#alarm-history li[data-code='link']").bounding_box()
            assert card is not None and item is not None
            assert card["x"] <= item["x"] and item["x"] + item["width"] <= card["x"] + card["width"], (width, item)
            assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth"), width
            console.shot(page, f"console-warning-history-{width}")


def test_a_controller_warning_is_listed_once_active_and_in_the_history(page: Any, tmp_path: Path) -> None:
    """MOTN-612/613/614 (the embedded controller at $WARN_LIM 5 %) are in ``alarms`` and
    ``alarm_history`` and, forwarded to the servo process, in ``warnings`` and ``warning_history``
    too: the console lists each once, active and then (after a reset) in the history. Old console:
    each active one twice."""
    with running_rig(tmp_path, sim_options={"config": ControllerConfig(warn_lim_pct=5.0)}) as rig:
        h = rig.streaming()
        open_console(page, rig)
        s = warned(rig, h)
        want = sorted(codes(s["alarms"]))
        assert want and all(a["warning"] for a in s["alarms"]), s["alarms"]
        page.wait_for_function("n => document.querySelectorAll('#alarm-list li.alarm').length >= n",
                               arg=len(want), timeout=10000)
        active = listed(page, "alarm-list")
        assert sorted(a["code"] for a in active) == want, active
        assert all(a["tag"] == "warning" for a in active), active

        s = fast_stop_and_reset(rig, h)
        history = codes(s["alarm_history"])
        assert sorted(codes(s["warning_history"])) == want, s["warning_history"]  # the same, in both
        page.wait_for_selector("#alarm-list li.muted", timeout=10000)  # "no alarms"
        past = listed(page, "alarm-history")
        assert [a["code"] for a in past] == history[::-1], (past, history)  # newest first, each once
        assert page.text_content("#alarm-history-count") == f"({len(history)})"


def test_the_history_merges_both_lists_by_time_and_pairs_repeats_one_to_one(page: Any, tmp_path: Path) -> None:
    """The merge itself, on made-up lists (renderAlarms in the page): the servo process's own warnings
    take their place by time among the alarms; a controller warning posted three times, the last two
    of which the servo process lists too, shows three times; a controller warning whose copy in
    ``alarm_history`` fell off (it keeps 50) shows once, from ``warning_history``."""
    with running_rig(tmp_path) as rig:
        open_console(page, rig)
        out = page.evaluate("""async () => {
            const v = await import('/web/views.js');
            const t = 1767322800;  // any wall clock
            const a = (code, dt, warning = true) => ({code, message: `${code} text`, warning, time_unix: t + dt});
            const w = (code, dt) => ({code, message: `${code} text`, t: dt, time_unix: t + dt + 0.01});
            const alarm_history = [a('MOTN-612', 10), a('SRVO-001', 20, false), a('MOTN-612', 30), a('MOTN-612', 40)];
            const warning_history = [w('MOTN-613', 1), w('SESSION-LOG', 15), w('MOTN-612', 30), w('link', 35),
                                     w('MOTN-612', 40)];
            v.renderAlarms({state: 'streaming', alarms: [], warnings: [], alarm_history, warning_history});
            return [...document.querySelectorAll('#alarm-history li')].map((li) =>
                `${li.dataset.code}@${li.querySelector('.when').textContent.slice(6, 8)}:${li.dataset.kind}`);
        }""")
    seconds = [time.strftime("%S", time.localtime(1767322800 + dt)) for dt in (40, 35, 30, 20, 15, 10, 1)]
    assert out == [f"MOTN-612@{seconds[0]}:warning", f"link@{seconds[1]}:warning", f"MOTN-612@{seconds[2]}:warning",
                   f"SRVO-001@{seconds[3]}:alarm", f"SESSION-LOG@{seconds[4]}:warning",
                   f"MOTN-612@{seconds[5]}:warning", f"MOTN-613@{seconds[6]}:warning"], out
