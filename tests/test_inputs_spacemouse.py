"""SpaceMouse: recorded HID report bytes through the parser, the drain, the shaping and the adapter;
a real UNIX socket speaking the spacenavd protocol to the client."""

from __future__ import annotations

import re
import socket
import struct
import subprocess
import sys
import threading
import time
import types
from collections import deque
from pathlib import Path
from typing import Any

import pytest
from waiting import assert_refreshed_within, wait_for

from servo_app.inputs import ButtonEvent, TwistSample, create_adapter
from servo_app.inputs.actions import OutputToggle, parse_action
from servo_app.inputs.bridge import InputsBridge
from servo_app.inputs.spacemouse.hid_adapter import (
    SpaceMouseHidAdapter,
    SpaceMouseHidConfig,
    find_spacemice,
    open_hid_device,
)
from servo_app.inputs.spacemouse.reader import drain
from servo_app.inputs.spacemouse.reports import (
    AxesReport,
    ButtonsReport,
    MalformedReport,
    decode_report,
    encode_axes,
    encode_buttons,
)
from servo_app.inputs.spacemouse.shaping import Shaping, shape
from servo_app.inputs.spacemouse.spacenav import (
    EVENT,
    ButtonChange,
    MalformedEvent,
    MotionEvent,
    decode_event,
    encode_button,
    encode_motion,
)

# -- recorded reports (old model, e.g. SpaceNavigator: translation, rotation, buttons apart) --------
# Pushing the cap right (+X): X 201, with a little cross-talk in Y and Z, rotation noise.
PUSH_X = [
    bytes.fromhex("01 c9 00 fd ff 05 00"),  # report 1: X=201 Y=-3 Z=5
    bytes.fromhex("02 01 00 ff ff 00 00"),  # report 2: RX=1 RY=-1 RZ=0
]
# Twisting the cap counter-clockwise seen from above: about HID Z (which points down) that is negative.
TWIST_CCW = [
    bytes.fromhex("01 02 00 00 00 fe ff"),  # X=2 Z=-2
    bytes.fromhex("02 00 00 03 00 6a ff"),  # RY=3 RZ=-150
]
BUTTON_0_PRESS = bytes.fromhex("03 01 00")
BUTTON_0_RELEASE = bytes.fromhex("03 00 00")
BUTTON_1_PRESS = bytes.fromhex("03 02 00")
TRAILING_ZEROS = [bytes.fromhex("01 00 00 00 00 00 00"), bytes.fromhex("02 00 00 00 00 00 00")] * 3
# New model (e.g. SpaceMouse Compact): all six axes in report 1, 12 bytes of payload. Pushing down (+Z HID).
NEW_PUSH_DOWN = bytes.fromhex("01 00 00 00 00 5e 01 00 00 00 00 00 00")  # Z=350
NEW_ZERO = bytes.fromhex("01" + "00" * 12)
BATTERY = bytes.fromhex("17 64")  # wireless models: battery level, not ours


class FakeHid:
    """Mimics hidapi's device.read(size, timeout_ms) on a non-blocking device, fed by the test."""

    def __init__(self) -> None:
        self.queue: deque[bytes] = deque()
        self.cond = threading.Condition()
        self.unplugged = False
        self.closed = False

    def feed(self, *reports: bytes) -> None:
        with self.cond:
            self.queue.extend(reports)
            self.cond.notify_all()

    def unplug(self) -> None:
        with self.cond:
            self.unplugged = True
            self.cond.notify_all()

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        with self.cond:
            if not self.queue and timeout_ms > 0 and not self.unplugged:
                self.cond.wait(timeout_ms / 1000.0)
            if self.unplugged:
                raise OSError("read error")
            return list(self.queue.popleft()[:max_length]) if self.queue else []

    def close(self) -> None:
        self.closed = True


def hid_config(**kw: Any) -> SpaceMouseHidConfig:
    base = {"name": "sm", "buttons": {0: "toggle_frame", 1: "toggle_output:DO[1]"}, "deadband": 0.05,
            "poll_timeout_s": 0.02, "reconnect_min_s": 0.01, "reconnect_max_s": 0.02}
    return SpaceMouseHidConfig.model_validate({**base, **kw})


# -- parsing ---------------------------------------------------------------------------------------

def test_decode_recorded_reports() -> None:
    assert decode_report(PUSH_X[0]) == AxesReport((201, -3, 5), None)
    assert decode_report(PUSH_X[1]) == AxesReport(None, (1, -1, 0))
    assert decode_report(TWIST_CCW[1]) == AxesReport(None, (0, 3, -150))
    assert decode_report(list(BUTTON_1_PRESS)) == ButtonsReport(0b10)
    assert decode_report(NEW_PUSH_DOWN) == AxesReport((0, 0, 350), (0, 0, 0))
    assert decode_report(BATTERY) is None
    for bad in (b"", b"\x01\x05\x00", b"\x02\x01", b"\x03"):
        with pytest.raises(MalformedReport):
            decode_report(bad)
    assert encode_axes((201, -3, 5), (1, -1, 0)) == PUSH_X
    assert encode_axes((0, 0, 350), six_axis=True) == [NEW_PUSH_DOWN]
    assert encode_buttons(1) == BUTTON_0_PRESS


def test_drain_returns_every_queued_report_and_empties_the_device() -> None:
    dev = FakeHid()
    assert drain(dev.read, wait_ms=1) == []  # nothing: waits at most 1 ms
    # A slow reader comes back to 40 queued translation reports and a button press among them.
    reports = [encode_axes((i, 0, 0))[0] for i in range(1, 41)]
    reports.insert(20, BUTTON_0_PRESS)
    dev.feed(*reports)
    got = drain(dev.read, wait_ms=1)
    assert got == reports and not dev.queue
    assert decode_report(got[-1]) == AxesReport((40, 0, 0), None)  # the newest, not the oldest
    dev.feed(*reports)
    assert len(drain(dev.read, wait_ms=1, max_reports=8)) == 8  # bounded against a flooding device


# -- shaping ---------------------------------------------------------------------------------------

def test_shape_scaling_deadband_curve_dominant_enable() -> None:
    s = Shaping(full_scale=350, deadband=0.05, max_linear_mm_s=100, max_angular_deg_s=30)
    lin, ang = shape([350, 0, 0, 0, 0, 0], s)
    assert lin == pytest.approx((100, 0, 0)) and ang == (0, 0, 0)
    lin, _ = shape([700, 0, 0, 0, 0, 0], s)  # beyond full scale is clipped
    assert lin[0] == pytest.approx(100)
    lin, ang = shape([15, -17, 10, 5, -12, 3], s)  # all inside 5 % of 350 = 17.5 counts
    assert not any(lin) and not any(ang)
    lin, _ = shape([0, 350, 350, 0, 0, 0], s)  # HID Y toward the user, Z down -> robot -Y, -Z
    assert lin == pytest.approx((0, -100, -100))
    half_lin = shape([175 + 0.05 * 350 / 2, 0, 0, 0, 0, 0], Shaping(deadband=0.05))[0][0]
    cubic = shape([175 + 0.05 * 350 / 2, 0, 0, 0, 0, 0], Shaping(deadband=0.05, curve=1.0))[0][0]
    assert cubic < half_lin and cubic == pytest.approx(half_lin ** 3 / 100 ** 2, rel=1e-6)
    lin, ang = shape([200, 30, 0, 0, 0, -250], Shaping(dominant_axis=True))
    assert lin == (0, 0, 0) and ang[2] > 0 and ang[:2] == (0, 0)
    lin, ang = shape([200, 30, 0, 0, 0, -250], Shaping(dominant_axis=True, rotation=False))
    assert lin[0] > 0 and lin[1] == 0 and ang == (0, 0, 0)  # a disabled group cannot win the lock
    lin, ang = shape([200, 0, 0, 0, 0, -250], Shaping(translation=False, scale=0.5))
    assert lin == (0, 0, 0) and ang[2] == pytest.approx(0.5 * 30 * (250 / 350 - 0.05) / 0.95)


# -- adapter logic (replayed bytes, no threads) ----------------------------------------------------

def test_hid_adapter_replay_push_twist_buttons_and_rest() -> None:
    a = SpaceMouseHidAdapter(hid_config(), open_device=lambda cfg: FakeHid())
    a.process(PUSH_X, now=1.000)
    s = a.output.read().value
    assert isinstance(s, TwistSample) and s.linear[0] == pytest.approx(100 * (201 / 350 - 0.05) / 0.95)
    assert s.linear[1:] == (0, 0) and s.angular == (0, 0, 0) and s.frame == "base" and s.stamp == 1.0
    a.process(TWIST_CCW, now=1.008)
    s = a.output.read().value
    assert s.angular[2] > 0 and s.linear == (0, 0, 0)  # counter-clockwise from above: +Z

    # Deflected, then silence (an empty drain): nothing is published, so the source will go stale.
    seq = a.output.seq
    a.process([], now=1.2)
    assert a.output.seq == seq

    # The three trailing zero reports, then silence: zero is refreshed, never stale.
    a.process(TRAILING_ZEROS, now=1.3)
    assert a.output.read().value.is_zero()
    a.process([], now=5.0)
    cur = a.output.read()
    assert cur.seq == seq + 2 and cur.stamp == 5.0 and cur.value.is_zero()

    # Buttons: 0 toggles the frame locally and is still reported; 1 is forwarded for the service.
    a.process([BUTTON_0_PRESS], now=6.0)
    a.process([BUTTON_0_RELEASE, BUTTON_1_PRESS], now=6.1)
    events = a.events.drain()
    assert events == [
        ButtonEvent(0, True, "toggle_frame", 6.0, "sm"),
        ButtonEvent(0, False, "toggle_frame", 6.1, "sm"),
        ButtonEvent(1, True, "toggle_output:DO[1]", 6.1, "sm"),
    ]
    a.process(PUSH_X, now=6.2)
    assert a.output.read().value.frame == "tool"


def test_hid_adapter_new_model_and_malformed_reports() -> None:
    a = SpaceMouseHidAdapter(hid_config(), open_device=lambda cfg: FakeHid())
    a.process([NEW_PUSH_DOWN, BATTERY, b"\x01\x05\x00"], now=2.0)
    s = a.output.read().value
    assert s.linear == pytest.approx((0, 0, -100))  # pushing down: robot -Z
    assert a.problems.counts["malformed"] == 1 and a.problems.recent[-1].data_hex == "01 05 00"
    a.process([NEW_ZERO], now=2.1)
    assert a.output.read().value.is_zero()


def test_hid_adapter_thread_drains_and_reconnects_after_unplug() -> None:
    devices: list[FakeHid] = []
    attempts = {"n": 0}

    def open_device(cfg: SpaceMouseHidConfig) -> FakeHid:
        attempts["n"] += 1
        if attempts["n"] == 1:
            raise OSError("open failed")  # not plugged in yet
        devices.append(FakeHid())
        return devices[-1]

    a = SpaceMouseHidAdapter(hid_config(), open_device=open_device)
    with a:
        wait_for(a.output, lambda s: s.is_zero())  # connected at rest: live zero
        dev = devices[-1]
        # A burst the reader has not kept up with: it must end on the newest report.
        dev.feed(*[encode_axes((i, 0, 0), (0, 0, 0))[0] for i in range(100, 351, 10)])
        s = wait_for(a.output, lambda s: s.linear[0] == pytest.approx(100.0))
        assert s.linear[0] == pytest.approx(100.0)
        dev.feed(*TRAILING_ZEROS)
        zero = wait_for(a.output, lambda s: s.is_zero())
        wait_for(a.output, lambda s: s.is_zero() and s.stamp > zero.stamp)  # silence after zeros: refreshed
        dev.feed(BUTTON_0_PRESS)
        ev = a.events.get(timeout=15.0)
        assert ev is not None and ev.action == "toggle_frame" and ev.pressed
        dev.unplug()
        wait_for(a.output, lambda s: len(devices) == 2)
        assert devices[0].closed and a.status().problems["disconnected"] == 1
        assert a.status().problems["open_failed"] == 1 and a.status().connects == 2


def test_a_button_held_at_unplug_is_heard_when_pressed_after_the_replug() -> None:
    """The device reports buttons only on change: the mask from before the unplug must not swallow
    the first press (a gripper's output, the frame toggle) of the button that was held then."""
    devices: list[FakeHid] = []

    def open_device(cfg: SpaceMouseHidConfig) -> FakeHid:
        devices.append(FakeHid())
        return devices[-1]

    a = SpaceMouseHidAdapter(hid_config(), open_device=open_device)
    with a:
        wait_for(a.output, lambda s: s.is_zero())
        devices[0].feed(BUTTON_1_PRESS)  # held while the cable is pulled
        assert (ev := a.events.get(timeout=15.0)) is not None and ev.pressed
        devices[0].unplug()
        wait_for(a.output, lambda s: len(devices) == 2 and a.connected)
        devices[1].feed(BUTTON_1_PRESS)  # released meanwhile, now pressed again
        ev = a.events.get(timeout=15.0)
        assert ev is not None and (ev.button, ev.pressed, ev.action) == (1, True, "toggle_output:DO[1]")


def test_a_cap_at_rest_stays_live_whatever_the_poll_timeout(tmp_path: Path) -> None:
    """A cap at rest is refreshed once per poll; a poll_timeout_s at or above stale_after_s let the
    resting source go stale between polls (the arm stopped for a lost input nobody had touched)."""
    slow = {"stale_after_s": 0.2, "poll_timeout_s": 1.0}
    with SpaceMouseHidAdapter(hid_config(**slow), open_device=lambda cfg: FakeHid()) as hid_mouse:
        wait_for(hid_mouse.output, lambda s: s.is_zero())
        assert_refreshed_within(hid_mouse.output, 0.2)
    path = str(tmp_path / "spnav.sock")
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as daemon:
        daemon.bind(path)
        daemon.listen(1)
        with create_adapter({"type": "spacenav", "name": "nav", "socket": path, **slow}) as nav:
            wait_for(nav.output, lambda s: s.is_zero())
            assert_refreshed_within(nav.output, 0.2)


def test_hid_enumeration_filter() -> None:
    cfg = hid_config()
    devices = [
        {"vendor_id": 0x046D, "product_id": 0xC52B, "product_string": "USB Receiver", "usage_page": 1, "usage": 2},
        {"vendor_id": 0x046D, "product_id": 0xC626, "product_string": "SpaceNavigator", "path": b"/dev/hidraw3"},
        {"vendor_id": 0x256F, "product_id": 0xC635, "product_string": "", "usage_page": 1, "usage": 8},
        {"vendor_id": 0x1234, "product_id": 0x0001, "product_string": "Space heater"},
    ]
    assert [d["product_id"] for d in find_spacemice(devices, cfg)] == [0xC626, 0xC635]
    assert [d["product_id"] for d in find_spacemice(devices, hid_config(vendor_id=0x1234, product_id=1))] == [1]


def test_open_hid_device_through_the_hid_module(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[str, Any]] = []

    class Device:
        def open_path(self, path: bytes) -> None:
            calls.append(("open_path", path))

        def set_nonblocking(self, on: int) -> None:
            calls.append(("set_nonblocking", on))

        def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
            return []

        def close(self) -> None:
            calls.append(("close", None))

    fake = types.ModuleType("hid")
    fake.enumerate = lambda vid, pid: [  # type: ignore[attr-defined]
        {"vendor_id": 0x256F, "product_id": 0xC635, "product_string": "SpaceMouse Compact", "path": b"/dev/hidraw7"}]
    fake.device = Device  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "hid", fake)
    dev = open_hid_device(hid_config())
    assert isinstance(dev.device, Device)  # type: ignore[attr-defined]
    dev.close()
    assert calls == [("open_path", b"/dev/hidraw7"), ("set_nonblocking", 1), ("close", None)]
    fake.enumerate = lambda vid, pid: []  # type: ignore[attr-defined]
    with pytest.raises(OSError, match="no SpaceMouse"):
        open_hid_device(hid_config())
    monkeypatch.setitem(sys.modules, "hid", None)  # hidapi not installed
    with pytest.raises(RuntimeError, match="needs hidapi"):
        open_hid_device(hid_config())


def test_two_spacemouse_inputs_read_two_devices_and_a_third_says_they_are_taken(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Both inputs used to open the first SpaceMouse found: the second device moved nothing."""
    opened: dict[bytes, FakeHid] = {}

    class Device(FakeHid):
        def open_path(self, path: bytes) -> None:
            opened[path] = self

        def set_nonblocking(self, on: int) -> None:
            pass

    fake = types.ModuleType("hid")
    fake.enumerate = lambda vid, pid: [  # type: ignore[attr-defined]
        {"vendor_id": 0x256F, "product_id": 0xC635, "product_string": "SpaceMouse Compact", "path": p}
        for p in (b"/dev/hidraw3", b"/dev/hidraw4")]
    fake.device = Device  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "hid", fake)
    with SpaceMouseHidAdapter(hid_config()) as a, SpaceMouseHidAdapter(hid_config(name="sm2")) as b:
        wait_for(a.output, lambda s: s.is_zero())
        wait_for(b.output, lambda s: s.is_zero())
        assert set(opened) == {b"/dev/hidraw3", b"/dev/hidraw4"}
        opened[b"/dev/hidraw4"].feed(*encode_axes((350, 0, 0)))  # the second device, pushed right
        moved, other = (a, b) if a._dev.path == b"/dev/hidraw4" else (b, a)  # type: ignore[attr-defined]
        s = wait_for(moved.output, lambda s: s.linear[0] > 0)
        assert s.linear[0] == pytest.approx(100.0)
        assert other.output.read().value.is_zero()  # the first device is still at rest: its input too
        with SpaceMouseHidAdapter(hid_config(name="sm3")) as c:
            assert c.first_attempt.wait(15.0) and not c.connected and c.failure is not None
            assert "already read by another SpaceMouse input" in c.failure.reason
            assert "[adapters.sm3]" in c.failure.fix
            other.stop()  # its device is free again: the third input takes it
            wait_for(c.output, lambda s: c.connected and s.is_zero())


def test_a_configured_hidraw_path_that_is_gone_is_named_as_gone(monkeypatch: pytest.MonkeyPatch,
                                                                  tmp_path: Path) -> None:
    """hidapi answers a missing path with "open failed" only, which read as a permission problem (add a
    udev rule); the usual cause is the SpaceMouse coming back under another hidraw number."""
    class Device:
        def open_path(self, path: bytes) -> None:
            raise OSError("open failed")  # what hidapi raises for any path it cannot open

    fake = types.ModuleType("hid")
    fake.device = Device  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "hid", fake)
    gone = tmp_path / "hidraw7"
    a = SpaceMouseHidAdapter(hid_config(path=str(gone)))
    with a:
        assert a.first_attempt.wait(15.0)
        f = a.failure
    assert f is not None and f.device == f"SpaceMouse (HID {gone})"
    assert "does not exist" in f.reason and "remove path from [adapters.sm]" in f.fix and "udev" not in f.fix
    gone.touch()  # a path that is there and still cannot be opened: the permission advice stands
    with SpaceMouseHidAdapter(hid_config(path=str(gone))) as b:
        assert b.first_attempt.wait(15.0) and b.failure is not None and "udev" in b.failure.fix


def test_hid_library_is_imported_only_on_open() -> None:
    code = (
        "import sys\n"
        "from servo_app.inputs import create_adapter\n"
        "a = create_adapter({'type': 'spacemouse', 'name': 'sm'})\n"
        "heavy = ['hid', 'can', 'serial', 'cantools', 'fastapi']\n"
        "print([m for m in heavy if m in sys.modules])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"


# -- spacenavd --------------------------------------------------------------------------------------

def test_spacenav_event_codec() -> None:
    raw = encode_motion((200, -3, 0), (0, 0, 120), 8)
    assert len(raw) == 32 and struct.unpack("=8i", raw) == (0, 200, -3, 0, 0, 0, 120, 8)
    assert decode_event(raw) == MotionEvent((200, -3, 0), (0, 0, 120), 8)
    assert decode_event(encode_button(3, True)) == ButtonChange(3, True)
    assert decode_event(encode_button(3, False)) == ButtonChange(3, False)
    with pytest.raises(MalformedEvent, match="unknown event type 7"):
        decode_event(EVENT.pack(7, 0, 0, 0, 0, 0, 0, 0))
    with pytest.raises(MalformedEvent):
        decode_event(raw[:20])


def test_spacenav_client_over_a_real_unix_socket(tmp_path: Path) -> None:
    path = str(tmp_path / "spnav.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    srv.bind(path)
    srv.listen(2)
    srv.settimeout(15.0)
    a = create_adapter({"type": "spacenav", "name": "nav", "socket": path, "poll_timeout_s": 0.02,
                        "reconnect_min_s": 0.01, "reconnect_max_s": 0.05,
                        "buttons": {"0": "toggle_frame", "1": "toggle_output:DO[1]"}})
    try:
        with a:
            conn, _ = srv.accept()
            wait_for(a.output, lambda s: s.is_zero())  # connected, at rest
            # Motion split across two sends: the client must reassemble the 32-byte event.
            ev = encode_motion((350, 0, 0), (0, 0, 0))
            conn.sendall(ev[:13])
            conn.sendall(ev[13:] + encode_button(1, True) + encode_button(1, False))
            s = wait_for(a.output, lambda s: s.linear[0] > 0)
            assert s.linear[0] == pytest.approx(100.0) and s.source == "nav"
            e1, e2 = a.events.get(timeout=15.0), a.events.get(timeout=15.0)
            assert (e1.button, e1.pressed, e1.action) == (1, True, "toggle_output:DO[1]")
            assert (e2.button, e2.pressed) == (1, False)
            conn.sendall(EVENT.pack(9, 1, 2, 3, 4, 5, 6, 7) + encode_motion((0, 0, 0), (0, 0, 0)))
            zero = wait_for(a.output, lambda s: s.is_zero())
            wait_for(a.output, lambda s: s.is_zero() and s.stamp > zero.stamp)  # idle daemon: zero held live
            assert a.status().problems["malformed"] == 1
            # The daemon restarts: the client reconnects by itself.
            conn.close()
            conn2, _ = srv.accept()
            conn2.sendall(encode_motion((0, 0, 0), (0, -350, 0)))  # spacenavd's Y is up: a turn about it, yaw
            s = wait_for(a.output, lambda s: s.angular[2] != 0)
            assert s.angular[2] == pytest.approx(-30.0) and a.status().connects == 2
            conn2.close()
    finally:
        srv.close()


def spacenavd_motion(hid_t: tuple[int, int, int], hid_r: tuple[int, int, int]) -> bytes:
    """The motion event spacenavd sends for these HID counts with its default configuration
    (cfgfile.c: def_axmap {0, 2, 1, 3, 5, 4}, def_axinv {0, 1, 1, 0, 1, 1}; event.c puts input axis i
    at out[map[i]] with the sign invert[map[i]]): X right, Y up, Z away from the user."""
    axmap, axinv = (0, 2, 1, 3, 5, 4), (0, 1, 1, 0, 1, 1)
    out = [0] * 6
    for i, v in enumerate((*hid_t, *hid_r)):
        out[axmap[i]] = -v if axinv[axmap[i]] else v
    return encode_motion((out[0], out[1], out[2]), (out[3], out[4], out[5]))


@pytest.mark.parametrize(("what", "hid_t", "hid_r"), [
    ("push right", (300, 0, 0), (0, 0, 0)),
    ("push away from the user", (0, -300, 0), (0, 0, 0)),
    ("lift", (0, 0, -300), (0, 0, 0)),
    ("twist counter-clockwise from above", (0, 0, 0), (0, 0, -300)),
    ("tilt to the right", (0, 0, 0), (0, 300, 0)),
    ("tilt away", (0, 0, 0), (-300, 0, 0)),
    ("a mix", (120, -250, 40), (-30, 200, -310)),
])
def test_the_same_push_moves_the_arm_the_same_way_through_spacenavd_and_hid(
        what: str, hid_t: tuple[int, int, int], hid_r: tuple[int, int, int]) -> None:
    """spacenavd reorders the axes (Y up, Z away): read as they came, pushing the cap away moved the
    arm up and lifting it moved the arm away, the opposite of the same SpaceMouse over HID."""
    hid = create_adapter({"type": "spacemouse", "name": "sm", "deadband": 0.0})
    nav = create_adapter({"type": "spacenav", "name": "sm", "deadband": 0.0})
    hid.process(encode_axes(hid_t, hid_r), now=1.0)  # type: ignore[attr-defined]
    nav.process([spacenavd_motion(hid_t, hid_r)], now=1.0)  # type: ignore[attr-defined]
    h, n = hid.output.read().value, nav.output.read().value
    assert n.linear == pytest.approx(h.linear) and n.angular == pytest.approx(h.angular), what
    if what == "push away from the user":
        assert h.linear[1] > 0 and h.linear[0] == h.linear[2] == 0  # robot +Y, away from the operator
    if what == "lift":
        assert h.linear[2] > 0 and h.linear[0] == h.linear[1] == 0  # robot +Z, up


def test_spacenav_hold_then_stale() -> None:
    a = create_adapter({"type": "spacenav", "name": "nav", "hold_s": 0.05})
    a.process([encode_motion((200, 0, 0), (0, 0, 0))], now=1.0)
    a.process([], now=1.04)  # within hold: the steady deflection is refreshed
    assert a.output.read().stamp == 1.04
    a.process([], now=1.2)  # no news for longer than hold: not refreshed, goes stale
    assert a.output.read().stamp == 1.04


def test_button_actions_are_checked_when_the_configuration_loads() -> None:
    assert parse_action("toggle_frame") == "toggle_frame"
    assert parse_action("toggle_output:DO[12]") == OutputToggle("DO", 12)
    assert str(OutputToggle("RO", 2)) == "toggle_output:RO[2]"
    for bad, why in (("open_gripper", "not a button action"), ("toggle_output:DI[1]", "DI is not an output type"),
                     ("toggle_output:DO[0]", "numbered from 1"), ("toggle_output:DO1", "not a button action")):
        with pytest.raises(ValueError, match=why):
            parse_action(bad)
        with pytest.raises(ValueError, match=f"button 3: '{re.escape(bad)}'"):
            create_adapter({"type": "spacenav", "name": "nav", "buttons": {3: bad}})


def test_output_presses_reach_the_bridge_and_are_refused_without_input_control(tmp_path: Path) -> None:
    """The bridge hears every press (through the adapter's event queue) and carries out only output
    actions, only with input control enabled; every outcome is listed."""
    path = tmp_path / "inputs.toml"
    path.write_text('[adapters.nav]\ntype = "spacenav"\nsocket = "/nonexistent"\n'
                    '[adapters.nav.buttons]\n0 = "toggle_frame"\n1 = "toggle_output:DO[5]"\n')
    done: list[OutputToggle] = []
    bridge = InputsBridge.from_file(path)
    try:
        bridge.start(act=lambda a: done.append(a) or 1)
        core = bridge.adapters[0].core  # type: ignore[attr-defined]
        core.button(0, True, time.monotonic())  # local: not the bridge's
        core.button(1, False, time.monotonic())  # a release does nothing
        core.button(1, True, time.monotonic())
        deadline = time.monotonic() + 5.0
        while not bridge.actions:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        row = bridge.describe()["button_actions"][-1]
        assert not row["ok"] and "input control is not enabled" in row["error"] and not done
        bridge.enabled = True  # as enable(True) leaves it (that also tells a servo process)
        core.button(1, True, time.monotonic())
        while len(bridge.actions) < 2:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert bridge.actions[-1]["ok"] and bridge.actions[-1]["result"] == 1 and done == [OutputToggle("DO", 5)]
        assert bridge.problems.snapshot()[0]["action_failed"] == 1
    finally:
        bridge.close()
