"""The operator console (web/) against issue 14: continuous jog that keeps going while held, a header
that never contradicts itself, the Janome pose row, alarms with times, a layout where nothing covers
anything, the session-log plot's axes, target entry and the inputs card.

Same rig as tests/test_web_console.py (its fixtures and helpers are reused): a real ``servo-app run``
with its embedded simulator, headless Chromium, checks through /api/state over HTTP.
"""

from __future__ import annotations

import os
import re
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import test_web_console as console
from test_web_console import (
    Service,
    _service,
    at_rest_without_alarm,
    call,
    shot,
    sign_in,
    take_control_and_stream,
)

# The console tests' fixtures, found by pytest under these names: one browser and one service per module.
browser = console.browser
fanuc = console.fanuc
janome = console.janome
page = console.page

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

# J2 leaning back: the flange ~220 mm from the base, pointing down; three +X holds (~225 mm) stay far
# from the stretched arm.
HOME = [0.0, -30.0, 0.0, 0.0, -90.0, 0.0]
WIDTHS = [{"width": 1280, "height": 800}, {"width": 1440, "height": 900}]


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


# --------------------------------------------------------------------------- 2. the header
def test_header_never_shows_ready_beside_a_dead_link(page: Any, fanuc: Service) -> None:
    page.goto(fanuc.url + "/")
    page.wait_for_function("document.querySelector('#conn').textContent.includes('live')")
    # The view as it renders a state whose link has failed (the controller's last word was READY).
    shown = page.evaluate("""async () => {
        const v = await import('/web/views.js');
        v.renderStatus({state: 'ready', link: 'fault', link_error: 'no status for 1000 ms'});
        return [document.querySelector('#mode').textContent, document.querySelector('#stop-reason').textContent];
    }""")
    assert shown[0].lower() != "ready" and "fault" in shown[0].lower(), shown
    assert "no status for 1000 ms" in shown[1], shown
    # Status flowing but not ready (an alarm held at the controller): the header says why a start waits.
    why = page.evaluate("""async () => {
        const v = await import('/web/views.js');
        v.renderStatus({state: 'connected', link: 'connected', not_ready: 'SYSRDY is off (servo power not ready)'});
        return document.querySelector('#stop-reason').textContent;
    }""")
    assert why == "not ready: SYSRDY is off (servo power not ready)", why
    # The embedded controller's alarm list unreadable (its process stopped or gone): the alarms say so.
    item = page.evaluate("""async () => {
        const v = await import('/web/views.js');
        v.renderAlarms({state: 'fault', alarm_poll_error: 'TimeoutError: the embedded simulator process has ended'});
        return document.querySelector('#alarm-list').textContent;
    }""")
    assert "alarm list cannot be read: TimeoutError: the embedded simulator process has ended" in item, item
    # And live: the telemetry goes, the last state heard is not shown as the present one.
    live = fanuc.state()["state"]
    page.wait_for_function(f"document.querySelector('#mode').textContent === '{live}'")
    page.context.set_offline(True)
    try:
        page.wait_for_function("document.querySelector('#conn').textContent.includes('lost')")
        mode = page.text_content("#mode") or ""
        assert mode != live and "no telemetry" in mode, mode
    finally:
        page.context.set_offline(False)
    page.wait_for_function("document.querySelector('#conn').textContent.includes('live')", timeout=15000)
    page.wait_for_function("!document.querySelector('#mode').textContent.includes('telemetry')")


# ----------------------------------------------------------------------------- 3. Janome R
def test_janome_pose_row_shows_r_from_its_own_slot(page: Any, janome: Service) -> None:
    sign_in(page, janome)
    janome.wait(lambda s: s["state"] == "ready", "the simulated robot's point job connected", timeout=30)
    take_control_and_stream(page, janome)
    lease = page.evaluate("sessionStorage.getItem('servo.lease')")
    q = janome.state()["q_servo"][:4]
    call(janome, "POST", "/api/target", {"joints": [q[0], q[1], q[2], 45.0]}, lease)
    s = janome.wait(lambda s: s["at_rest"] and abs(s["q_servo"][3] - 45.0) < 0.05, "R at 45°", timeout=30)
    assert abs(s["cart_servo"][5] - 45.0) < 0.05, s["cart_servo"]  # R is the rotation about Z: slot 5
    page.wait_for_function("Math.abs(Number(document.querySelector('#pose-R').textContent) - 45) < 0.1")
    assert page.locator("#pose-head th").all_text_contents() == ["X", "Y", "Z", "R"]
    shot(page, "console-janome-pose-r")


# --------------------------------------------------------------------------------- 4. alarms
def test_alarms_show_times_and_keep_active_apart_from_history(page: Any, fanuc: Service) -> None:
    page.goto(fanuc.url + "/")
    page.wait_for_function("document.querySelector('#conn').textContent.includes('live')")
    # 2026-01-02 03:04:05.678 local time, as the service stamps it (time_unix) and the controller's stamp.
    out = page.evaluate("""async () => {
        const v = await import('/web/views.js');
        const t = new Date(2026, 0, 2, 3, 4, 5, 678).getTime() / 1000;
        const old = {code: 'SRVO-001', message: 'Operator panel E-stop', cause: 'c', remedy: 'r', warning: false,
                     time_unix: t - 60, controller_time_ms: 1000};
        const now = {code: 'MOTN-603', message: 'ONLINE: Stream start failed', cause: 'late packets',
                     remedy: 'reset', warning: false, time_unix: t, controller_time_ms: 123456};
        const text = (sel) => [...document.querySelectorAll(sel)].map((e) => e.textContent);
        v.renderAlarms({state: 'stopped', alarms: [now], alarm_history: [old, now]});
        const during = {active: text('#alarm-list li'), codes: text('#alarm-list li .code'),
                        history: text('#alarm-history li .code'), count: text('#alarm-count')[0],
                        when: text('#alarm-list li .when')};
        v.renderAlarms({state: 'streaming', alarms: [], alarm_history: [old, now]});   // after a reset
        const after = {active: text('#alarm-list li'), history: text('#alarm-history li .code'),
                       count: text('#alarm-count')[0]};
        return {during, after};
    }""")
    during, after = out["during"], out["after"]
    assert during["codes"] == ["MOTN-603"] and during["count"] == "1", during
    assert "03:04:05.678" in during["when"][0] and "controller 123456 ms" in during["when"][0], during
    assert during["history"] == ["MOTN-603", "SRVO-001"], during  # newest first
    assert after["active"] == ["no alarms"] and after["count"] == "0", after
    assert after["history"] == ["MOTN-603", "SRVO-001"], after


def _servo_process_pid(svc: Service) -> int:
    """The service's servo process: the spawned child that does not hold the simulated controller's
    UDP port (the embedded simulator does)."""
    robot_port = int(svc.state()["robot"].rsplit(":", 1)[1])
    inodes = set()
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        f = line.split()
        if int(f[1].split(":")[1], 16) == robot_port:
            inodes.add(f[9])
    children = [int(c) for t in Path(f"/proc/{svc.proc.pid}/task").iterdir()
                for c in (t / "children").read_text().split()]
    spawned = [c for c in children if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]

    def holds_robot_port(pid: int) -> bool:
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            try:
                link = os.readlink(fd)
            except OSError:
                continue
            if link.startswith("socket:[") and link[8:-1] in inodes:
                return True
        return False

    servo = [c for c in spawned if not holds_robot_port(c)]
    assert len(servo) == 1, (children, spawned, servo)
    return servo[0]


def test_a_real_alarm_is_listed_with_its_times_and_kept_in_history_after_reset(page: Any, fanuc: Service) -> None:
    """The servo process dies mid-stream: the controller posts MOTN-603. The console lists it as
    active with the wall clock and the controller's time stamp; Reset clears the active list, the
    history keeps it."""
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    if "alarm_history" not in fanuc.state():
        pytest.skip("this service has no alarm_history yet")
    os.kill(_servo_process_pid(fanuc), signal.SIGKILL)
    page.wait_for_selector("#alarm-list li[data-code='MOTN-603']", timeout=15000)
    when = page.text_content("#alarm-list li[data-code='MOTN-603'] .when") or ""
    assert re.search(r"\d\d:\d\d:\d\d\.\d{3}", when) and "controller" in when, when
    shot(page, "console-alarm-active")
    page.click("#reset")
    page.wait_for_function("!document.querySelector(\"#alarm-list li[data-code='MOTN-603']\")", timeout=30000)
    assert page.locator("#alarm-history li[data-code='MOTN-603']").count() >= 1
    assert page.text_content("#alarm-count") == "0"
    fanuc.wait(lambda s: s["state"] not in ("fault",), "the fault reset", timeout=30)


# -------------------------------------------------------------------------------- 5. layout
def _overlap(a: dict[str, float], b: dict[str, float]) -> bool:
    return (a["x"] < b["x"] + b["width"] and b["x"] < a["x"] + a["width"]
            and a["y"] < b["y"] + b["height"] and b["y"] < a["y"] + a["height"])


def _single_line(pg: Any, selector: str) -> bool:
    return pg.eval_on_selector(selector, """e => { const cs = getComputedStyle(e);
        const line = cs.lineHeight === 'normal' ? 1.25 * parseFloat(cs.fontSize) : parseFloat(cs.lineHeight);
        return e.getBoundingClientRect().height < 1.6 * line; }""")


@pytest.mark.parametrize("viewport", WIDTHS, ids=lambda v: f"{v['width']}px")
def test_nothing_covers_anything(page: Any, fanuc: Service, viewport: dict[str, int]) -> None:
    page.set_viewport_size(viewport)
    sign_in(page, fanuc)
    page.wait_for_selector("#message:not([hidden])")  # "signed in as pytest"
    take_control_and_stream(page, fanuc)
    page.wait_for_selector("#joint-rows tr")
    page.wait_for_selector("#message:not([hidden])")  # "you have control"
    height = page.evaluate("document.documentElement.scrollHeight")
    for y in range(0, height, viewport["height"] // 2):
        page.evaluate(f"window.scrollTo(0, {y})")
        # Messages go after a few seconds: show the last one again wherever it sits.
        page.evaluate("document.querySelector('#message').hidden = false")
        toast = page.locator("#message").bounding_box()
        stop = page.locator("#stop").bounding_box()
        assert toast is not None and stop is not None
        assert not _overlap(toast, stop)
        for i, do in enumerate(page.locator("button.io").all()):
            box = do.bounding_box()
            assert box is not None and not _overlap(toast, box), (f"the message covers DO{i + 1}", y, toast, box)
        # STOP covers no card (the session-log table among them), at any scroll position.
        for card in page.locator("section.card:visible").all():
            box = card.bounding_box()
            assert box is not None and not _overlap(stop, box), (card.get_attribute("id"), y, stop, box)
    page.evaluate("window.scrollTo(0, 0)")
    # The speed label is one line, for Cartesian and joint jog.
    for kind in ("cart", "joint"):
        page.check(f"input[name=jog-kind][value={kind}]", force=True)
        assert _single_line(page, "#speed-out"), kind
        assert _single_line(page, "label.speed"), kind
    # Every jog button lies inside its card.
    card = page.locator("#jog-card").bounding_box()
    assert card is not None
    for b in page.locator("button.jog").all():
        box = b.bounding_box()
        assert box is not None and card["x"] <= box["x"] and box["x"] + box["width"] <= card["x"] + card["width"], box
    # The joint-range marker never lies on its text.
    for row in page.locator("#joint-rows tr").all():
        marker = row.locator("td:nth-child(3) .marker, td:nth-child(3) .fill").first.bounding_box()
        label = row.locator("td:nth-child(3) .label").first.bounding_box()
        assert marker is not None and label is not None
        assert not _overlap(marker, label), (row.get_attribute("data-joint"), marker, label)
    shot(page, f"console-layout-{viewport['width']}", full_page=True)


# ----------------------------------------------------------------------- 6. session-log plot
def test_session_log_plot_has_a_time_axis_and_units(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.check("input[name=jog-kind][value=joint]", force=True)
    mouse_hold(page, "[data-jog='+J1']", 0.6)
    at_rest_without_alarm(fanuc)
    page.click("#end")
    fanuc.wait(lambda s: s["state"] == "ended", "ended")
    newest = fanuc.get("/api/sessions")[0]["name"]
    page.click("#log-refresh")
    page.click(f"[data-log='{newest}']")
    page.wait_for_selector("#log-summary tr[data-joint='J1']")
    # A time axis: ticks in seconds from 0, and the axes named with their units.
    ticks = [float(t) for t in (page.get_attribute("#log-plot", "data-ticks") or "").split()]
    assert ticks and ticks[0] == 0.0 and len(ticks) >= 2 and ticks == sorted(ticks), ticks
    axes = page.text_content("#log-axes") or ""
    assert "time" in axes and "(s)" in axes and "% of each axis' limit" in axes, axes
    # Every column of the summary says its unit.
    heads = page.locator("#log-summary thead th").all_text_contents()
    assert heads[0] == "axis" and heads[1] == "unit", heads
    assert all("(" in h and ")" in h for h in heads[2:]), heads
    units = page.locator("#log-summary tbody td.unit").all_text_contents()
    assert units == ["°/s"] * 6, units
    assert float(page.text_content("#log-summary tr[data-joint='J1'] td.peak")) > 0.0
    page.locator("#logs-card").screenshot(path=str(console.ARTIFACTS / "console-log-plot.png"))


# ----------------------------------------------------------------------------- 7. targets
def test_target_entry_goes_and_shows_refusals(page: Any, fanuc: Service) -> None:
    home(fanuc)
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    # A joint target: from the current position, J1 to 20°.
    page.click("#target-fill")
    page.fill("[data-target='J1']", "20")
    page.click("#target-go")
    s = fanuc.wait(lambda s: s["at_rest"] and abs(s["q_cmd"][0] - 20.0) < 0.01, "J1 at 20°", timeout=30)
    assert abs(s["q_cmd"][4] - HOME[4]) < 0.01
    page.wait_for_function("document.querySelector('#target-error').textContent.startsWith('going to')")
    # A pose target: 30 mm lower than where the flange is. "From current" fills from the page's
    # telemetry, which can be a frame behind the service (and the servo follows the commands with a
    # lag): the fill waits until the page shows the flange where it settled.
    s = at_rest_without_alarm(fanuc)
    page.wait_for_function("xyz => ['X', 'Y', 'Z'].every((n, i) =>"
                           " Math.abs(Number(document.querySelector(`#pose-${n}`).textContent) - xyz[i]) < 0.1)",
                           arg=s["cart_servo"][:3])
    page.check("input[name=target-kind][value=xyzwpr]", force=True)
    page.click("#target-fill")
    z0 = float(page.input_value("[data-target='Z']"))
    page.fill("[data-target='Z']", str(z0 - 30.0))
    page.click("#target-go")
    fanuc.wait(lambda s: s["at_rest"] and abs(s["cart_servo"][2] - (z0 - 30.0)) < 0.5, "Z 30 mm lower", timeout=30)
    s1 = at_rest_without_alarm(fanuc)
    assert np.allclose(s1["cart_servo"][:2], s["cart_servo"][:2], atol=0.5), (s["cart_servo"], s1["cart_servo"])
    # Refused: J1 beyond its range. The server's words are shown, and nothing moved.
    page.check("input[name=target-kind][value=joints]", force=True)
    page.click("#target-fill")
    before = fanuc.state()["q_cmd"]
    page.fill("[data-target='J1']", "500")
    page.click("#target-go")
    page.wait_for_function("document.querySelector('#target-error').textContent.startsWith('Target refused')")
    text = page.text_content("#target-error") or ""
    assert text.startswith("Target refused: J1=500.000 deg"), text  # the axis by name: not joints[0], no (422)
    assert fanuc.state()["q_cmd"] == pytest.approx(before, abs=1e-6)
    shot(page, "console-target-refused")


# An API client's words in the console: a route, a header, a body path or an HTTP status.
REST_WORDS = re.compile(r"/api/|X-Lease-Id|body\.|\[\d+\]|\(4\d\d\)")

# The console's own API client (web/api.js) sends a request and returns what it would show.
REFUSAL = """async ([method, path, body]) => {
  const { Api } = await import('/web/api.js');
  const api = new Api();
  api.axes = ['J1', 'J2', 'J3', 'J4', 'J5', 'J6'];
  try { await api.call(method, path, body); return null; } catch (e) { return [e.status, e.message, e.detail]; }
}"""


def test_refusals_are_shown_in_the_operators_words(page: Any, fanuc: Service) -> None:
    """Refusals were shown as the REST API words them for a client program: "body.joints.4: ...",
    "joints[0]=...", "(422)", and next steps as routes ("start a new session: POST
    /api/session/start"). The console now names the axis and the button to press."""
    home(fanuc)
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    # A body the server's model refuses (422, a list of field errors).
    status, message, detail = page.evaluate(REFUSAL, ["POST", "/api/target", {"joints": [0, 0, 0, 0, "x", 0]}])
    assert status == 422 and message.startswith("J5: "), (message, detail)
    # The next step as a button.
    page.click("#end")
    fanuc.wait(lambda s: s["state"] == "ended", "ended")
    page.click("#resume")
    page.wait_for_function("document.querySelector('#message').textContent.startsWith('Resume: ')")
    text = page.text_content("#message") or ""
    assert text.endswith("start a new session: press Start"), text
    page.click("#target-fill")
    page.click("#target-go")
    page.wait_for_function("document.querySelector('#target-error').textContent.startsWith('Target refused')")
    target = page.text_content("#target-error") or ""
    assert target.endswith("press Start"), target
    # Control taken by another client: the console says so, and how to take it back.
    call(fanuc, "POST", "/api/lease", {"client": "intruder", "force": True})
    page.wait_for_function("document.querySelector('#message').textContent.startsWith('control lost')")
    lost = page.text_content("#message") or ""
    assert "'intruder' holds it" in lost and lost.endswith("press Take control"), lost
    for shown in (message, text, target, lost):
        assert not REST_WORDS.search(shown), shown


# The widest value "From current" writes into a target field: -1811.123, a pose within an M-20's reach
# (fmt(v, 3)); a field must show it whole beside the number input's spin buttons (~15 px).
FITS = """() => [...document.querySelectorAll('#target-fields input')].map((input) => {
  const cs = getComputedStyle(input);
  const ctx = document.createElement('canvas').getContext('2d');
  ctx.font = `${cs.fontWeight} ${cs.fontSize} ${cs.fontFamily}`;
  const need = ctx.measureText('-1811.123').width + parseFloat(cs.paddingLeft) + parseFloat(cs.paddingRight)
    + parseFloat(cs.borderLeftWidth) + parseFloat(cs.borderRightWidth) + 15;
  return [input.name, Math.round(need), input.offsetWidth];
})"""


@pytest.mark.parametrize("width", [800, 1280, 1366, 1440])
def test_target_fields_show_a_whole_value_at_laptop_widths(page: Any, fanuc: Service, width: int) -> None:
    """At 800 px the six target fields were 71 px wide in three fixed columns: "-169.500" was cut."""
    page.set_viewport_size({"width": width, "height": 900})
    sign_in(page, fanuc)
    page.click("#take")  # the form takes input with control only
    page.wait_for_selector("#release:not([hidden])")
    page.wait_for_selector("#target-fields input[name='J6']")
    for kind in ("joints", "xyzwpr"):
        page.check(f"input[name=target-kind][value={kind}]", force=True)
        fields = page.evaluate(FITS)
        assert len(fields) == 6 and all(need <= have for _, need, have in fields), (width, kind, fields)
    assert page.evaluate("document.documentElement.scrollWidth <= document.documentElement.clientWidth")


# ------------------------------------------------------------------------------ 8. inputs
@pytest.fixture(scope="module")
def failing_inputs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """Inputs with a serial distance sensor whose port does not exist here, and the HTTP feeds."""
    configs = Path(__file__).resolve().parents[1] / "configs" / "inputs"
    toml = tmp_path_factory.mktemp("inputs-cfg") / "inputs.toml"
    toml.write_text((configs / "serial_distance.toml").read_text() + "\n" + (configs / "feeds.toml").read_text())
    yield from _service(tmp_path_factory, "failing-inputs", "--inputs", str(toml))


def test_inputs_card_enables_inputs_and_says_why_a_source_failed(page: Any, failing_inputs: Service) -> None:
    svc = failing_inputs
    sign_in(page, svc)
    page.wait_for_selector("#signed:not([hidden])")
    page.click("#take")
    page.wait_for_selector("#release:not([hidden])")
    # The sensor that cannot be opened: failed, with the port and the reason.
    row = page.wait_for_selector("#inputs-failures li[data-source='distance']", timeout=15000)
    why = row.text_content() or ""
    assert "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART-if00-port0" in why and "Fix:" in why, why
    page.wait_for_function("document.querySelectorAll(\"tr[data-source='distance'] td\")[2].textContent === 'failed'")
    # The feeds that merely have not sent are stale, not failed.
    assert page.locator("tr[data-source='vision'] td").all_text_contents()[2] == "stale"
    assert page.locator("#inputs-failures li[data-source='vision']").count() == 0
    # Enable and disable input control from the card.
    assert not svc.state()["inputs"]["enabled"]
    page.click("#inputs-enable")
    svc.wait(lambda s: s["inputs"]["enabled"], "inputs enabled")
    # The answer to enabling says the sensor cannot be used, naming its port.
    page.wait_for_function("document.querySelector('#inputs-error').textContent.includes('usb-FTDI')")
    page.wait_for_function("document.querySelector('#inputs-enable').textContent === 'Disable inputs'")
    page.locator("#inputs-card").screenshot(path=str(console.ARTIFACTS / "console-inputs-failed.png"))
    page.click("#inputs-enable")
    svc.wait(lambda s: not s["inputs"]["enabled"], "inputs disabled")
