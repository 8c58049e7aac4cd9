"""The operator web console (web/), driven in headless Chromium against a running ``servo-app run``.

Each backend runs as a real subprocess (embedded simulator, loopback only, a temporary --var-dir and
a known token); the browser signs in, takes control and moves the simulated arm through the console's
own buttons and keys, and the checks read the service's /api/state. Screenshots go to tests/artifacts/.

Chromium is Debian's (/usr/bin/chromium, installed by ``scripts/install --test``); the tests are
skipped only if it is absent and cannot be installed here.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from servo_app.robots.conventions import wpr_to_rotation

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e .[test])")

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
TOKEN = "console-test-token"
ARTIFACTS = Path(__file__).resolve().parent / "artifacts"
LAPTOP = {"width": 1366, "height": 900}
TABLET = {"width": 820, "height": 1180}


# ----------------------------------------------------------------------------- chromium
def _chromium_or_reason() -> str | None:
    """None when /usr/bin/chromium is there (installing it if we can); else why the tests skip."""
    if CHROMIUM.exists():
        return None
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        return (f"{CHROMIUM} is absent and cannot be installed here (not root, or no apt-get): "
                "run scripts/install --test")
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "chromium"]):
        try:
            subprocess.run(cmd, env=env, check=True, capture_output=True, timeout=900)
        except (subprocess.SubprocessError, OSError) as exc:
            return f"{CHROMIUM} is absent and `{' '.join(cmd)}` failed: {exc}"
    return None if CHROMIUM.exists() else f"{CHROMIUM} is still absent after apt-get install chromium"


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    reason = _chromium_or_reason()
    if reason:
        pytest.skip(reason)
    with sync_api.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


# ------------------------------------------------------------------------------ service
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Service:
    """``servo-app run`` in a subprocess, and a tiny reader of its REST API."""

    def __init__(self, tmp: Path, *extra: str, port: int | None = None) -> None:
        self.port = port or _free_port()  # a port: a service restarted where the page knows it
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = tmp / "service.log"
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        cmd = [sys.executable, "-m", "servo_app.cli", "run", "--http-port", str(self.port),
               "--var-dir", str(tmp / "var"), "--token", TOKEN, *extra]
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT)

    def wait_healthy(self, timeout: float = 90.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"servo-app run exited with {self.proc.returncode}:\n{self.log()}")
            with contextlib.suppress(OSError):
                if self.get("/api/health").get("ok"):
                    return
            time.sleep(0.2)
        raise TimeoutError(f"/api/health did not answer within {timeout} s:\n{self.log()}")

    def get(self, path: str) -> Any:
        with urllib.request.urlopen(self.url + path, timeout=5) as r:
            return json.load(r)

    def state(self) -> dict[str, Any]:
        return self.get("/api/state")

    def wait(self, pred: Callable[[dict[str, Any]], bool], what: str, timeout: float = 20.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        s = self.state()
        while not pred(s):
            if time.monotonic() > deadline:
                raise AssertionError(f"{what}: not within {timeout} s; state {s.get('state')!r}, "
                                     f"stop_reason {s.get('stop_reason')!r}, fault {s.get('fault')!r}")
            time.sleep(0.05)
            s = self.state()
        return s

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")[-4000:]

    def stop(self) -> None:
        # SIGINT as from the terminal: uvicorn returns, the service ends the stream and exits.
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        self._log.close()


def _service(tmp_path_factory: pytest.TempPathFactory, name: str, *extra: str) -> Iterator[Service]:
    svc = Service(tmp_path_factory.mktemp(name), *extra)
    try:
        svc.wait_healthy()
        yield svc
    finally:
        svc.stop()


@pytest.fixture(scope="module")
def fanuc(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from _service(tmp_path_factory, "fanuc")


@pytest.fixture(scope="module")
def janome(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    yield from _service(tmp_path_factory, "janome", "--robot", "janome")


# --------------------------------------------------------------------------------- page
@pytest.fixture(scope="module")
def with_inputs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    feeds = Path(__file__).resolve().parents[1] / "configs" / "inputs" / "feeds.toml"
    yield from _service(tmp_path_factory, "inputs", "--inputs", str(feeds))


@contextlib.contextmanager
def console_page(browser: Any, on_dialog: Callable[[Any], None]) -> Iterator[Any]:
    """A fresh browser context (empty sessionStorage) whose dialogs go to ``on_dialog``; control is
    released after, and uncaught page errors fail the test."""
    context = browser.new_context(viewport=LAPTOP)
    pg = context.new_page()
    errors: list[str] = []
    pg.on("pageerror", lambda exc: errors.append(str(exc)))
    pg.on("dialog", on_dialog)
    try:
        yield pg
    finally:
        with contextlib.suppress(Exception):
            if pg.locator("#release").is_visible():
                pg.click("#release")
                pg.wait_for_selector("#take:not([hidden])", timeout=3000)
        context.close()
    assert errors == [], f"uncaught errors in the page: {errors}"


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    """A fresh browser context per test; "take control from ...?" (a previous test's lease lingers) is
    answered OK."""
    with console_page(browser, lambda d: d.accept()) as pg:
        yield pg


def call(svc: Service, method: str, path: str, body: Any = None, lease: str | None = None) -> Any:
    """An API request with the token (and a lease), as another client beside the console would send it."""
    headers = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
    if lease:
        headers["X-Lease-Id"] = lease
    req = urllib.request.Request(svc.url + path, data=json.dumps(body).encode() if body is not None else None,
                                 method=method, headers=headers)
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.load(r)


def shot(pg: Any, name: str, full_page: bool = False) -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    pg.screenshot(path=str(path), full_page=full_page)
    return path


def sign_in(pg: Any, svc: Service, token: str = TOKEN) -> None:
    pg.goto(svc.url + "/")
    pg.wait_for_function("document.querySelector('#conn').textContent.includes('live')")
    pg.fill("#operator", "pytest")
    pg.fill("#token", token)
    pg.click("#signin button[type=submit]")


def take_control_and_stream(pg: Any, svc: Service) -> dict[str, Any]:
    """Signed in: take the lease and get the session streaming (start, or resume after a stop)."""
    pg.wait_for_selector("#signed:not([hidden])")
    pg.click("#take")
    pg.wait_for_selector("#release:not([hidden])")
    # The jog pad is built once /api/robot answered.
    pg.wait_for_selector("#jog-pad button.jog:not([disabled])")
    s = svc.state()
    if s["state"] in ("stopped", "stopping"):
        svc.wait(lambda s: s["state"] == "stopped", "stopped")
        pg.click("#resume")
    elif s["state"] != "streaming":
        pg.click("#start")
    pg.wait_for_function("document.querySelector('#mode').textContent === 'streaming'", timeout=30000)
    return svc.wait(lambda s: s["state"] == "streaming" and s["at_rest"], "streaming at rest")


def rewrite_telemetry(pg: Any, rewrite: Callable[[dict[str, Any]], None]) -> None:
    """The page's telemetry socket through Playwright, each frame changed in place by ``rewrite``
    before the page sees it: the page shown a state the service has left (a frame behind it). Call
    before the page loads."""

    def route(ws: Any) -> None:
        server = ws.connect_to_server()

        def forward(m: str | bytes) -> None:
            frame = json.loads(m)
            if isinstance(frame, dict):
                rewrite(frame)
            ws.send(json.dumps(frame))

        server.on_message(forward)

    pg.route_web_socket("**/ws/telemetry*", route)


def hold(pg: Any, selector: str, seconds: float) -> None:
    """Press and hold a jog button with the mouse for ``seconds`` (released by the caller)."""
    pg.hover(selector)
    pg.mouse.down()
    pg.wait_for_timeout(seconds * 1000)


def at_rest_without_alarm(svc: Service) -> dict[str, Any]:
    """Commands at rest, then the (simulated) servo settled on them: it follows with a lag."""
    s = svc.wait(lambda s: s["at_rest"] and s["state"] in ("streaming", "stopped"), "at rest")
    assert s["fault"] is None and s["alarms"] == [], (s["fault"], s["alarms"])
    assert not any(s["vel"]), s["vel"]
    deadline = time.monotonic() + 3.0
    while True:
        time.sleep(0.05)
        now = svc.state()
        if np.abs(np.subtract(now["cart_servo"], s["cart_servo"])).max() < 1e-3:
            return now
        assert time.monotonic() < deadline, "the servo position did not settle"
        s = now


# -------------------------------------------------------------------------------- tests
def test_wrong_token_is_refused(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc, token="not-the-token")
    err = page.wait_for_selector("#signin-error:not([hidden])")
    assert "refused" in err.text_content() and "401" in err.text_content()
    assert page.evaluate("sessionStorage.getItem('servo.token')") is None
    assert page.locator("#signin").is_visible() and not page.locator("#signed").is_visible()
    assert page.locator("#take").is_disabled() and page.locator("#start").is_disabled()
    shot(page, "console-wrong-token")


def test_jog_plus_x_for_one_second_moves_the_flange(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    s0 = take_control_and_stream(page, fanuc)
    assert page.locator("input[name=jog-kind][value=cart]").is_checked()
    assert page.locator("input[name=frame][value=base]").is_checked()
    x0, y0, z0 = s0["cart_servo"][:3]

    hold(page, "[data-jog='+X']", 1.0)
    moving = fanuc.state()
    shot(page, "console-jog-plus-x")
    page.mouse.up()

    assert moving["state"] == "streaming" and moving["vel"] != [0.0] * 6
    s = at_rest_without_alarm(fanuc)
    x1, y1, z1 = s["cart_servo"][:3]
    # 20 % of 250 mm/s for ~1 s is ~50 mm; a loaded machine may drop a renewal or two, so only the
    # direction and a clear distance are asserted, with the other axes nearly unmoved.
    assert x1 - x0 > 10.0, (x0, x1)
    assert abs(y1 - y0) < 0.2 * (x1 - x0) and abs(z1 - z0) < 0.2 * (x1 - x0), (s0["cart_servo"], s["cart_servo"])
    # The console shows the new pose.
    page.wait_for_function(f"Math.abs(Number(document.querySelector('#pose-X').textContent) - {x1}) < 1")


def test_release_anywhere_stops_at_once(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.check("input[name=jog-kind][value=joint]", force=True)
    hold(page, "[data-jog='+J1']", 0.5)
    assert fanuc.state()["vel"][0] > 0
    # The press holds the pointer (pointer capture): sliding off the button with the mouse still down
    # goes on jogging (a page that moved under a still mouse cut jogs short), releasing it stops.
    page.mouse.move(5, 5)
    page.wait_for_timeout(400)  # longer than the server's 250 ms hold-to-run: renewals went on
    assert fanuc.state()["vel"][0] > 0 and page.locator("button.jog.held").count() == 1
    page.mouse.up()
    assert page.locator("button.jog.held").count() == 0
    s = at_rest_without_alarm(fanuc)
    # Released (zero-speed jog, then hold-to-run), not a STOP: the next press moves without a resume.
    assert s["stop_reason"] in (None, "") or s["stop_reason"].startswith("hold-to-run expired")
    q0 = s["q_cmd"][0]
    hold(page, "[data-jog='-J1']", 0.4)
    page.mouse.up()
    assert at_rest_without_alarm(fanuc)["q_cmd"][0] < q0


@pytest.mark.parametrize("how", ["space", "stop-button", "window-blur"])
def test_stop_mid_jog(page: Any, fanuc: Service, how: str) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.check("input[name=jog-kind][value=joint]", force=True)
    hold(page, "[data-jog='-J1']" if how == "space" else "[data-jog='+J1']", 0.5)
    assert fanuc.state()["state"] == "streaming"
    if how == "space":
        page.keyboard.press("Space")
    elif how == "stop-button":  # a second finger on STOP while the first still holds the jog button
        page.locator("#stop").dispatch_event("pointerdown")
    else:  # the operator switched to another window mid-jog
        page.evaluate("window.dispatchEvent(new Event('blur'))")
    s = fanuc.wait(lambda s: s["state"] in ("stopping", "stopped"), "stopping after STOP", timeout=5)
    assert s["stop_reason"] == "stop requested", s["stop_reason"]
    # The pad stopped renewing at once, though the mouse is still down on it.
    assert page.locator("button.jog.held").count() == 0
    s = fanuc.wait(lambda s: s["state"] == "stopped" and s["at_rest"], "stopped at rest")
    page.mouse.up()
    assert s["fault"] is None and s["alarms"] == []
    page.wait_for_function("document.querySelector('#mode').textContent === 'stopped'")
    assert "stop requested" in page.text_content("#stop-reason")
    shot(page, f"console-stopped-{how}")
    # A STOP needs a resume: the console's Resume brings the session back.
    page.click("#resume")
    fanuc.wait(lambda s: s["state"] == "streaming", "streaming after resume")


def test_connection_loss_mid_jog_stops_the_arm(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.check("input[name=jog-kind][value=joint]", force=True)
    hold(page, "[data-jog='-J1']", 0.4)
    assert fanuc.state()["vel"][0] < 0
    page.context.set_offline(True)  # the network goes: no more renewals, no telemetry
    try:
        # Nothing reaches the server any more: its hold-to-run stops the arm by itself.
        s = fanuc.wait(lambda s: s["state"] == "stopped" and s["at_rest"], "stopped by hold-to-run")
        assert s["stop_reason"].startswith("hold-to-run expired") and s["fault"] is None
        page.wait_for_function("document.querySelector('#conn').textContent.includes('lost')")
        assert page.locator("button.jog.held").count() == 0  # the console let go too
    finally:
        page.context.set_offline(False)
        page.mouse.up()
    page.wait_for_function("document.querySelector('#conn').textContent.includes('live')", timeout=15000)


def test_step_jog_moves_exactly_one_step(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.check("input[name=jog-mode][value=step]", force=True)
    page.select_option("#step-mm", "10")
    page.select_option("#step-deg", "1")

    def step(selector: str) -> tuple[dict[str, Any], dict[str, Any]]:
        before = at_rest_without_alarm(fanuc)
        page.click(selector)
        moved = lambda s: max(abs(a - b) for a, b in zip(s["q_cmd"], before["q_cmd"], strict=True)) > 1e-3  # noqa: E731
        fanuc.wait(lambda s: moved(s) and s["at_rest"], "the step done")
        return before, at_rest_without_alarm(fanuc)

    # Base frame: 10 mm along world X, nothing else.
    s0, s1 = step("[data-jog='+X']")
    d = np.subtract(s1["cart_servo"][:3], s0["cart_servo"][:3])
    np.testing.assert_allclose(d, [10.0, 0.0, 0.0], atol=0.3)
    # Tool frame: 10 mm along the tool's own z axis (where the flange points).
    page.check("input[name=frame][value=tool]", force=True)
    s0, s1 = step("[data-jog='+Z']")
    w, p, r = s0["cart_servo"][3:6]
    d = np.subtract(s1["cart_servo"][:3], s0["cart_servo"][:3])
    np.testing.assert_allclose(d, 10.0 * wpr_to_rotation(w, p, r)[:, 2], atol=0.3)
    # Joint: exactly one degree on J1.
    page.check("input[name=jog-kind][value=joint]", force=True)
    s0, s1 = step("[data-jog='+J1']")
    assert s1["q_cmd"][0] - s0["q_cmd"][0] == pytest.approx(1.0, abs=0.01)
    assert s1["q_cmd"][1:] == pytest.approx(s0["q_cmd"][1:], abs=0.01)


def _elsewhere(frame: dict[str, Any]) -> None:
    """The arm shown 5° further on J1 than it is (where it was a frame before)."""
    for key in ("q_servo", "q_cmd"):
        if frame.get(key):
            frame[key][0] += 5.0


def _stopped_by_hold_to_run(frame: dict[str, Any]) -> None:
    """The arm shown stopped by its hold-to-run (as a frame before a press resumed it)."""
    frame.update(state="stopped", stop_reason="hold-to-run expired")


# What the page shows once the rewritten frames reach it (arg: the service's J1).
SHOWS_ELSEWHERE = ("q => Math.abs(parseFloat(document.querySelector(\"#joint-rows tr[data-joint='J1'] td.num\")"
                   ".textContent) - (q + 5)) < 0.02")
SHOWS_STOPPED = "() => document.querySelector('#mode').textContent === 'stopped'"


@pytest.mark.parametrize(("rewrite", "shown"),
                         [(_elsewhere, SHOWS_ELSEWHERE), (_stopped_by_hold_to_run, SHOWS_STOPPED)],
                         ids=["position", "hold-to-run-stop"])
def test_a_step_goes_from_the_state_now_not_from_the_last_telemetry_frame(
        page: Any, fanuc: Service, rewrite: Callable[[dict[str, Any]], None], shown: str) -> None:
    """A step jog took the arm's position, and whether to resume first, from the console's last
    telemetry frame, which can be a frame behind the service. Every frame here shows the stale value:
    the arm 5° further on J1 (the step went to 6° from where it was), or stopped by its hold-to-run
    while it streams (the resume sent first was refused, "already streaming", and the step with it).
    The step now reads /api/state at the press and sends no resume (the server resumes a target after
    its hold-to-run, as a jog): exactly one degree on J1."""
    stale = threading.Event()  # from the stream on: the console waits for the stream in its header
    rewrite_telemetry(page, lambda frame: rewrite(frame) if stale.is_set() else None)
    resumes: list[str] = []
    page.on("request", lambda r: resumes.append(r.url) if r.url.endswith("/api/session/resume") else None)
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    stale.set()
    page.check("input[name=jog-mode][value=step]", force=True)
    page.check("input[name=jog-kind][value=joint]", force=True)
    page.select_option("#step-deg", "1")
    before = at_rest_without_alarm(fanuc)
    page.wait_for_function(shown, arg=before["q_servo"][0])
    sent = len(resumes)  # take_control_and_stream may have resumed through the button

    def step_done(s: dict[str, Any]) -> bool:
        said = page.text_content("#message") or ""
        assert "Step refused" not in said, said
        return abs(s["q_cmd"][0] - before["q_cmd"][0]) > 1e-3 and s["at_rest"]

    page.click("[data-jog='+J1']")
    fanuc.wait(step_done, "the step done")
    after = at_rest_without_alarm(fanuc)
    assert after["q_cmd"][0] - before["q_cmd"][0] == pytest.approx(1.0, abs=0.01)
    assert after["q_cmd"][1:] == pytest.approx(before["q_cmd"][1:], abs=0.01)
    assert resumes[sent:] == []


def test_digital_output_toggle_reads_back(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    do3 = page.locator("button.io[data-point='3']")
    page.wait_for_function("!document.querySelector(\"button.io[data-point='3']\").classList.contains('unknown')")
    before = do3.get_attribute("aria-pressed")
    do3.click()
    want = "false" if before == "true" else "true"
    page.wait_for_function(
        f"document.querySelector(\"button.io[data-point='3']\").getAttribute('aria-pressed') === '{want}'")
    assert (fanuc.state()["io_read_value"] >> 2) & 1 == (want == "true")


def test_jogging_into_the_stretched_arm_says_what_holds_it_back(page: Any, fanuc: Service) -> None:
    """Full speed +X until the arm is stretched: the jog card says the motion is held back and why,
    and the note goes once the jog is released."""
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.eval_on_selector("#speed", "e => { e.value = 100; e.dispatchEvent(new Event('input')); }")
    hold(page, "[data-jog='+X']", 0.0)
    page.wait_for_selector("#held-back:not([hidden])", timeout=10000)
    text = page.text_content("#held-back") or ""
    shot(page, "console-held-back")
    page.mouse.up()
    assert "held back" in text and ("singularity" in text or "configuration boundary" in text), text
    at_rest_without_alarm(fanuc)
    page.wait_for_selector("#held-back", state="hidden", timeout=5000)
    hold(page, "[data-jog='-X']", 1.0)  # back towards the middle for the tests after this one
    page.mouse.up()
    at_rest_without_alarm(fanuc)


def test_session_log_plot_and_layout(page: Any, fanuc: Service) -> None:
    sign_in(page, fanuc)
    take_control_and_stream(page, fanuc)
    page.check("input[name=jog-kind][value=joint]", force=True)
    hold(page, "[data-jog='+J2']", 0.5)
    page.mouse.up()
    at_rest_without_alarm(fanuc)
    page.click("#end")
    fanuc.wait(lambda s: s["state"] == "ended", "ended")
    logs = fanuc.get("/api/sessions")
    assert logs, "no session log written"
    newest = logs[0]["name"]
    page.click("#log-refresh")
    page.click(f"[data-log='{newest}']")
    page.wait_for_selector("#log-summary tr[data-joint='J2']")
    peak_j2 = float(page.text_content("#log-summary tr[data-joint='J2'] td.peak"))
    limit_j2 = fanuc.get("/api/limits")["vel_deg_s"][1]
    assert 0.0 < peak_j2 < limit_j2
    assert float(page.text_content("#log-summary tr[data-joint='J4'] td.peak")) == 0.0
    link = page.locator(f"a[download='{newest}']")
    assert link.get_attribute("href") == f"/api/sessions/{newest}"
    shot(page, "console-laptop", full_page=True)

    # Laptop and tablet: STOP on screen without scrolling, touch-sized jog buttons, no sideways scroll.
    for name, viewport in (("laptop", LAPTOP), ("tablet", TABLET)):
        page.set_viewport_size(viewport)
        page.evaluate("window.scrollTo(0, document.body.scrollHeight)")
        box = page.locator("#stop").bounding_box()
        assert box is not None and box["width"] >= 96
        assert box["x"] >= 0 and box["y"] >= 0
        assert box["x"] + box["width"] <= viewport["width"] and box["y"] + box["height"] <= viewport["height"]
        jb = page.locator("button.jog").first.bounding_box()
        assert jb is not None and jb["height"] >= 44 and jb["width"] >= 44
        assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth")
        page.evaluate("window.scrollTo(0, 0)")
        shot(page, f"console-{name}-top")


def test_janome_backend_jogs_its_axes(page: Any, janome: Service) -> None:
    sign_in(page, janome)
    janome.wait(lambda s: s["state"] == "ready", "the simulated robot's point job connected", timeout=30)
    s0 = take_control_and_stream(page, janome)
    # No twist jog on this backend: the pad shows the robot's own axes.
    assert page.locator("#kind-group").is_hidden()
    labels = page.locator("#jog-pad .jog-axis").all_text_contents()
    assert labels == ["X", "Y", "Z", "R"]
    assert page.locator("#io-card").is_hidden()
    # 20 % of the slider: 5 % of X's 100 mm/s (the link's step, GET /api/robot), 5 mm/s.
    hold(page, "[data-jog='+X']", 2.0)
    shot(page, "console-janome-jog")
    page.mouse.up()
    s = janome.wait(lambda s: s["at_rest"] and s["state"] in ("streaming", "stopped"), "at rest")
    assert s["fault"] is None
    assert s["cart_servo"][0] - s0["cart_servo"][0] > 5.0, (s0["cart_servo"], s["cart_servo"])
    assert abs(s["cart_servo"][1] - s0["cart_servo"][1]) < 1e-3


def test_input_sources_show_rate_and_staleness(page: Any, with_inputs: Service) -> None:
    svc = with_inputs
    stop = threading.Event()

    def feed_gauge() -> None:  # a distance sensor on the HTTP feed, ~20 Hz
        while not stop.is_set():
            body = json.dumps({"kind": "measurement", "values": {"distance": 12.5}, "stamp": time.time()}).encode()
            req = urllib.request.Request(svc.url + "/api/feed/gauge", data=body, method="POST", headers={
                "Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"})
            with contextlib.suppress(OSError), urllib.request.urlopen(req, timeout=2):
                pass
            stop.wait(0.05)

    feeder = threading.Thread(target=feed_gauge, daemon=True)
    feeder.start()
    try:
        page.goto(svc.url + "/")
        page.wait_for_selector("#inputs-card:not([hidden]) tr[data-source='gauge']")
        page.wait_for_function(
            "(() => { const c = document.querySelectorAll(\"tr[data-source='gauge'] td\");"
            " return c[2].textContent === 'live' && parseFloat(c[3].textContent) > 0; })()", timeout=15000)
        cells = page.locator("tr[data-source='vision'] td").all_text_contents()
        assert cells[:3] == ["vision", "pose", "stale"]

        # The lease holder gives one source exclusive control: the console says so, and when it ends.
        lease = call(svc, "POST", "/api/lease", {"client": "pytest-owner", "force": True})["lease_id"]
        try:
            call(svc, "POST", "/api/inputs/owner", {"source": "remote_jog"}, lease)
            page.wait_for_function("document.querySelector('#inputs-status').textContent"
                                   ".includes('only remote_jog may command')", timeout=15000)
            call(svc, "POST", "/api/inputs/owner", {"source": None}, lease)
            page.wait_for_function("!document.querySelector('#inputs-status').textContent.includes('only')",
                                   timeout=15000)
        finally:
            call(svc, "DELETE", "/api/lease", lease=lease)
        ARTIFACTS.mkdir(exist_ok=True)
        page.locator("#inputs-card").screenshot(path=str(ARTIFACTS / "console-inputs.png"))
    finally:
        stop.set()
        feeder.join(timeout=5)
