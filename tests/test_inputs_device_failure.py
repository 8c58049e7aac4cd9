"""Input devices that cannot be opened: the adapter names the device, the reason and the fix (issue 14).

The explanations are pure (table tests); the adapters' threads are real: a spacenav adapter on a
socket path nobody listens on, then spacenavd appearing there."""

from __future__ import annotations

import errno
import os
import socket
from pathlib import Path

import pytest
from waiting import wait_until

from servo_app.inputs.device_failure import can_failure, hid_failure, serial_failure, spacenav_failure
from servo_app.inputs.spacemouse.spacenav_adapter import SpaceNavAdapter, SpaceNavConfig


def oserror(code: int) -> OSError:
    return OSError(code, os.strerror(code))


@pytest.mark.parametrize(("exc", "reason", "fix"), [
    (FileNotFoundError(errno.ENOENT, "No such file or directory"), "spacenavd is not running", "systemctl start"),
    (ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused"), "nothing listens", "systemctl restart"),
    (PermissionError(errno.EACCES, "Permission denied"), "permission denied", "socket's mode"),
    (TimeoutError("timed out"), "did not accept", "restart spacenavd"),
])
def test_spacenav(exc: BaseException, reason: str, fix: str) -> None:
    f = spacenav_failure("mouse", "/run/spnav.sock", exc)
    assert f.device == "spacenavd's socket /run/spnav.sock"
    assert reason in f.reason and fix in f.fix
    assert f.message.startswith("spacenavd's socket /run/spnav.sock: ") and ". Fix: " in f.message


def test_serial_errors_wrapped_by_pyserial_are_read_through() -> None:
    import serial

    try:
        serial.Serial("/dev/ttyUSB-not-here-42")
    except serial.SerialException as exc:
        f = serial_failure("distance", "/dev/ttyUSB-not-here-42", exc)
    assert f.device == "serial port /dev/ttyUSB-not-here-42"
    assert "not plugged in" in f.reason and "[adapters.distance]" in f.fix and "SerialException" in f.error
    assert "dialout" in serial_failure("d", "/dev/ttyS0", oserror(errno.EACCES)).fix
    assert "fuser /dev/ttyS0" in serial_failure("d", "/dev/ttyS0", oserror(errno.EBUSY)).fix


@pytest.mark.parametrize(("code", "reason"), [
    (errno.EAFNOSUPPORT, "no SocketCAN support"),
    (errno.ENODEV, "no such network interface"),
    (errno.ENETDOWN, "the interface is down"),
])
def test_socketcan(code: int, reason: str) -> None:
    f = can_failure("ft", "socketcan", "can0", oserror(code))
    assert f.device == "CAN interface can0 (socketcan)" and reason in f.reason
    assert "ip link set can0 up type can" in f.fix


def test_slcan_names_its_serial_port() -> None:
    f = can_failure("ft", "slcan", "/dev/ttyACM9", oserror(errno.ENOENT))
    assert f.device == "slcan adapter on serial port /dev/ttyACM9" and "plug it in" in f.fix


def test_hid() -> None:
    assert "servo_app[hid]" in hid_failure("m", "", RuntimeError("needs hidapi (pip install ...)")).fix
    assert "no SpaceMouse is plugged in" in hid_failure("m", "", OSError("no SpaceMouse found among the HID "
                                                                        "devices")).reason
    assert "udev" in hid_failure("m", " /dev/hidraw3", OSError("open failed")).fix


def test_an_adapter_reports_its_device_until_it_opens(tmp_path: Path) -> None:
    path = tmp_path / "spnav.sock"
    a = SpaceNavAdapter(SpaceNavConfig(name="mouse", socket=str(path), realtime_priority=0, reconnect_min_s=0.05,
                                       reconnect_max_s=0.1))
    a.start()
    try:
        assert a.first_attempt.wait(10)
        st = a.status()
        assert st.failure is not None and st.failure.device == f"spacenavd's socket {path}"
        assert "spacenavd is not running" in st.last_problem.message  # the log says it too, not just "[Errno 2]"
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as daemon:  # spacenavd starts
            daemon.bind(str(path))
            daemon.listen(1)
            wait_until(lambda: a.connected, 10)
            assert a.status().failure is None
    finally:
        a.stop()
