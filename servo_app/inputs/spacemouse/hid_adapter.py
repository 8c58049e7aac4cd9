"""SpaceMouse read directly over HID through hidapi (the optional `hid` extra, imported on open).

Rest versus stale: the device reports every 8 ms while deflected, then three zero reports, then
nothing. So silence while the axes are at zero means "at rest" and the zero twist is refreshed on
every poll; silence while deflected means the device or the link is gone, nothing is published and
the source goes stale.
"""

from __future__ import annotations

import errno
import os
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Literal, Protocol

from servo_app.inputs.adapter import Clock, InputAdapter
from servo_app.inputs.device_failure import DeviceFailure, hid_failure
from servo_app.inputs.spacemouse.core import SpaceMouseConfig, SpaceMouseCore
from servo_app.inputs.spacemouse.reader import drain
from servo_app.inputs.spacemouse.reports import AxesReport, ButtonsReport, MalformedReport, decode_report

# 3Dconnexion devices enumerate under Logitech's vendor ID (older) or 3Dconnexion's own (newer).
KNOWN_VENDOR_IDS = (0x046D, 0x256F)
# HID usage page 1 (generic desktop), usage 8 (multi-axis controller).
MULTI_AXIS_USAGE = (0x01, 0x08)


class HidDevice(Protocol):
    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]: ...
    def close(self) -> None: ...


class SpaceMouseHidConfig(SpaceMouseConfig):
    type: Literal["spacemouse"] = "spacemouse"
    vendor_id: int | None = None
    product_id: int | None = None
    path: str | None = None  # a path from hid.enumerate(); chosen automatically when unset


def find_spacemice(devices: Iterable[Mapping[str, Any]], cfg: SpaceMouseHidConfig) -> list[Mapping[str, Any]]:
    """The enumerated HID devices that look like the configured SpaceMouse."""
    out = []
    for d in devices:
        if cfg.vendor_id is not None and d.get("vendor_id") != cfg.vendor_id:
            continue
        if cfg.product_id is not None and d.get("product_id") != cfg.product_id:
            continue
        if cfg.vendor_id is None and d.get("vendor_id") not in KNOWN_VENDOR_IDS:
            continue
        usage = (d.get("usage_page"), d.get("usage"))
        named = "space" in str(d.get("product_string") or "").lower()
        if usage == MULTI_AXIS_USAGE or named or cfg.product_id is not None:
            out.append(d)
    return out


# The HID paths open through open_hid_device in this process: each SpaceMouse is read by one input
# only, so a second SpaceMouse input takes the next device instead of the first one again.
_claimed: set[bytes] = set()
_claim_lock = threading.Lock()


class ClaimedDevice:
    """A device open_hid_device opened: its path is free for another input once this is closed."""

    def __init__(self, dev: Any, path: bytes) -> None:
        self.device = dev
        self.path = path
        self.read = dev.read  # bound once: the reader calls it for every report

    def close(self) -> None:
        try:
            self.device.close()
        finally:
            with _claim_lock:
                _claimed.discard(self.path)


def _as_bytes(path: str | bytes) -> bytes:
    return path.encode() if isinstance(path, str) else path


def open_hid_device(cfg: SpaceMouseHidConfig) -> HidDevice:
    try:
        import hid  # optional dependency: pip install 'servo_app[hid]'
    except ImportError as exc:
        raise RuntimeError("the SpaceMouse HID adapter needs hidapi (pip install 'servo_app[hid]')") from exc
    path: str | bytes | None = cfg.path
    if isinstance(path, str) and path.startswith("/") and not os.path.exists(path):
        # hidapi says only "open failed" (read as a permission problem); a hidraw number often
        # changes when the device is plugged in again.
        raise FileNotFoundError(errno.ENOENT, "no such HID device", path)
    with _claim_lock:
        if path is None:
            found = find_spacemice(hid.enumerate(cfg.vendor_id or 0, cfg.product_id or 0), cfg)
            if not found:
                raise OSError("no SpaceMouse found among the HID devices")
            free = [d for d in found if _as_bytes(d["path"]) not in _claimed]
            if not free:
                raise OSError(f"every SpaceMouse found ({len(found)}) is already read by another input")
            path = free[0]["path"]
        key = _as_bytes(path)
        if key in _claimed:
            raise OSError(f"{key.decode(errors='replace')} is already read by another input")
        dev = hid.device()
        dev.open_path(key)
        # Non-blocking, so read(n, 0) returns at once and read(n, t) waits at most t ms.
        dev.set_nonblocking(1)
        _claimed.add(key)
    return ClaimedDevice(dev, key)


class SpaceMouseHidAdapter(InputAdapter):
    config_model = SpaceMouseHidConfig
    config: SpaceMouseHidConfig

    def __init__(self, config: SpaceMouseHidConfig, *, clock: Clock = time.monotonic,
                 open_device: Callable[[SpaceMouseHidConfig], HidDevice] = open_hid_device) -> None:
        super().__init__(config, clock=clock)
        self._open_device = open_device
        self._dev: HidDevice | None = None
        self.core = SpaceMouseCore(config, self._publish, self._emit)

    def _open(self) -> None:
        self._dev = self._open_device(self.config)
        # Whatever was deflected or held before an unplug is not now.
        self.core.reset()

    def explain_open_failure(self, exc: BaseException) -> DeviceFailure:
        c = self.config
        what = f" {c.path}" if c.path else (f" {c.vendor_id:04x}:{c.product_id or 0:04x}" if c.vendor_id else "")
        return hid_failure(self.name, what, exc)

    def _close(self) -> None:
        dev, self._dev = self._dev, None
        if dev is not None:
            dev.close()

    def _poll(self) -> None:
        assert self._dev is not None
        reports = drain(self._dev.read, max(1, int(self.core.rest_wait_s * 1000)))
        self.process(reports, self.clock())

    def process(self, reports: list[bytes], now: float) -> None:
        """Apply one drained batch of reports and publish; separate from I/O so tests can replay bytes."""
        got_axes = False
        for raw in reports:
            try:
                rep = decode_report(raw)
            except MalformedReport as exc:
                self.problems.record("malformed", str(exc), exc.data)
                continue
            if isinstance(rep, AxesReport):
                self.core.set_axes(rep.translation, rep.rotation)
                got_axes = True
            elif isinstance(rep, ButtonsReport):
                self.core.set_buttons(rep.mask, now)
        if got_axes or self.core.at_rest:
            self.core.publish(now)
