"""Why an input device could not be opened, in words an operator can act on: the device, the reason
and the fix. Each adapter names its own device (``InputAdapter.explain_open_failure``); these turn the
operating system's error into the sentence (``[Errno 2] No such file or directory`` alone says neither
which device nor what to do). Pure: no I/O.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class DeviceFailure:
    device: str  # "spacenavd's socket /var/run/spnav.sock"
    reason: str  # "it does not exist: spacenavd is not running"
    fix: str  # "start spacenavd (sudo systemctl start spacenavd), or ..."
    error: str  # the exception as raised, for the record

    @property
    def message(self) -> str:
        return f"{self.device}: {self.reason}. Fix: {self.fix}"

    def view(self) -> dict[str, str]:
        return {"device": self.device, "reason": self.reason, "fix": self.fix, "error": self.error,
                "message": self.message}


def _errno(exc: BaseException) -> int | None:
    """The errno of ``exc`` or of the error it wraps (pyserial and python-can wrap OSError)."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno is not None:
            return int(e.errno)
        e = e.__cause__ or e.__context__
    return None


def _raw(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _section(name: str) -> str:
    return f"[adapters.{name}]"


def _permission(device: str, exc: BaseException, who: str) -> DeviceFailure:
    return DeviceFailure(device, "permission denied",
                         f"let the user running servo-app open it ({who}), then restart servo-app", _raw(exc))


def spacenav_failure(name: str, socket_path: str, exc: BaseException) -> DeviceFailure:
    device = f"spacenavd's socket {socket_path}"
    code = _errno(exc)
    where = f'or set socket = "..." in {_section(name)} to where spacenavd listens'
    if code == errno.ENOENT:
        return DeviceFailure(device, "it does not exist: spacenavd is not running (or listens elsewhere)",
                             f"install and start spacenavd (sudo apt-get install spacenavd; sudo systemctl start "
                             f"spacenavd), {where}", _raw(exc))
    if code == errno.ECONNREFUSED:
        return DeviceFailure(device, "nothing listens on it: spacenavd has stopped and left its socket file",
                             "restart spacenavd (sudo systemctl restart spacenavd)", _raw(exc))
    if code in (errno.EACCES, errno.EPERM):
        return _permission(device, exc, "the socket's mode or group")
    if isinstance(exc, TimeoutError):
        return DeviceFailure(device, "spacenavd did not accept the connection in time",
                             "restart spacenavd (sudo systemctl restart spacenavd)", _raw(exc))
    return DeviceFailure(device, f"cannot connect ({_raw(exc)})", f"check that spacenavd runs, {where}", _raw(exc))


def serial_failure(name: str, port: str, exc: BaseException) -> DeviceFailure:
    device = f"serial port {port}"
    code = _errno(exc)
    if code in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
        return DeviceFailure(device, "it does not exist: the sensor (or its USB adapter) is not plugged in",
                             f"plug it in (ls /dev/serial/by-id/ lists the ports present), or set port = \"...\" "
                             f"in {_section(name)}", _raw(exc))
    if code in (errno.EACCES, errno.EPERM):
        return _permission(device, exc, "sudo usermod -aG dialout $USER, then log in again")
    if code == errno.EBUSY:
        return DeviceFailure(device, "another program holds it open",
                             f"close that program (fuser {port} names it)", _raw(exc))
    return DeviceFailure(device, f"cannot open it ({_raw(exc)})",
                         f"check the sensor's cable and the port settings in {_section(name)}", _raw(exc))


def can_failure(name: str, interface: str, channel: Any, exc: BaseException) -> DeviceFailure:
    if interface == "slcan":
        failure = serial_failure(name, str(channel), exc)
        return DeviceFailure(f"slcan adapter on {failure.device}", failure.reason, failure.fix, failure.error)
    device = f"CAN interface {channel} ({interface})"
    code = _errno(exc)
    up = f"sudo ip link set {channel} up type can bitrate 500000 (the sensor's bitrate)"
    if interface == "socketcan" and code == errno.EAFNOSUPPORT:
        return DeviceFailure(device, "this kernel has no SocketCAN support loaded",
                             f"load it (sudo modprobe can_raw) and bring the interface up: {up}; or set interface "
                             f"and channel in {_section(name)}", _raw(exc))
    if code in (errno.ENODEV, errno.ENXIO, errno.ENOENT):
        return DeviceFailure(device, "no such network interface: the CAN adapter is not plugged in or not set up",
                             f"plug it in and bring it up: {up} (ip link lists the interfaces); or set channel in "
                             f"{_section(name)}", _raw(exc))
    if code == errno.ENETDOWN:
        return DeviceFailure(device, "the interface is down", f"bring it up: {up}", _raw(exc))
    if code in (errno.EACCES, errno.EPERM):
        return _permission(device, exc, "CAP_NET_RAW, or run as root")
    return DeviceFailure(device, f"cannot open it ({_raw(exc)})",
                         f"check the adapter and interface, channel and bitrate in {_section(name)}", _raw(exc))


def hid_failure(name: str, what: str, exc: BaseException) -> DeviceFailure:
    device = f"SpaceMouse (HID{what})"
    text = str(exc)
    if "hidapi" in text:
        return DeviceFailure(device, "the hidapi package is not installed",
                             "pip install 'servo_app[hid]' (or use spacenavd: type = \"spacenav\")", _raw(exc))
    if "already read by another input" in text:
        return DeviceFailure(device, "it is already read by another SpaceMouse input of this service",
                             f"plug in another SpaceMouse, or set path (hid.enumerate() lists them) in "
                             f"{_section(name)} and in the other input's section to tell them apart", _raw(exc))
    if "no SpaceMouse found" in text:
        return DeviceFailure(device, "no SpaceMouse is plugged in (none among the HID devices)",
                             f"plug it in, or set vendor_id and product_id in {_section(name)}", _raw(exc))
    if _errno(exc) in (errno.ENOENT, errno.ENODEV):
        return DeviceFailure(device, "it does not exist: the SpaceMouse is unplugged, or it came back under "
                             "another hidraw number", f"plug it in, or remove path from {_section(name)} so it is "
                             "found by its vendor and product (hidraw numbers change when it is plugged in again)",
                             _raw(exc))
    if _errno(exc) in (errno.EACCES, errno.EPERM) or "open failed" in text:
        return _permission(device, exc, "a udev rule giving your user access to the hidraw device")
    return DeviceFailure(device, f"cannot open it ({_raw(exc)})", f"check the device and {_section(name)}", _raw(exc))


def generic_failure(name: str, type_name: str, exc: BaseException) -> DeviceFailure:
    return DeviceFailure(f"{type_name} device of input {name!r}", f"cannot open it ({_raw(exc)})",
                         f"check the device and {_section(name)} in the inputs file", _raw(exc))
