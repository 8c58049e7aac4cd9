"""CAN sensors: DBC and layout decoding, the adapter on python-can's virtual bus, and on slcan over a
pseudo-terminal with the test playing the USB-CAN adapter on the master side."""

from __future__ import annotations

import os
import select
import struct
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import can
import pytest
from waiting import wait_for, wait_until

from servo_app.inputs import ConfigError, InputAdapter, Measurement, create_adapter, load_inputs_config
from servo_app.inputs.can_sensor.adapter import CanSensorAdapter
from servo_app.inputs.can_sensor.decoders import CanMessageLayout, DbcDecoder, FrameProblem, LayoutDecoder
from servo_app.inputs.can_sensor.slcan import MAX_LINE, SlcanBus
from servo_app.inputs.validate import ValueRejected

DBC = Path(__file__).resolve().parents[1] / "configs" / "inputs" / "sensors.dbc"
FORCE_ID, TORQUE_ID, DISTANCE_ID = 0x1A0, 0x1A1, 0x2B0


def force_frame(fx: float, fy: float, fz: float) -> bytes:
    return struct.pack("<3h", round(fx * 100), round(fy * 100), round(fz * 100))


def torque_frame(tx: float, ty: float, tz: float) -> bytes:
    return struct.pack("<3h", round(tx * 1000), round(ty * 1000), round(tz * 1000))


def ft_adapter(channel: str, **kw: Any) -> CanSensorAdapter:
    a = create_adapter({"type": "can", "name": "ft", "interface": "virtual", "channel": channel, "dbc": str(DBC),
                        "messages": ["FT_Force", "FT_Torque"], "poll_timeout_s": 0.02, **kw})
    assert isinstance(a, CanSensorAdapter)
    return a


# -- decoders --------------------------------------------------------------------------------------

def test_dbc_decoder_values_limits_and_malformed() -> None:
    d = DbcDecoder.from_file(str(DBC))
    name, v = d.decode(FORCE_ID, False, force_frame(12.5, -3.0, 150.0))
    assert name == "FT_Force" and v == pytest.approx({"Fx": 12.5, "Fy": -3.0, "Fz": 150.0})
    name, v = d.decode(DISTANCE_ID, False, bytes.fromhex("39 30 63 01"))
    assert name == "Distance" and v == pytest.approx({"Distance": 1234.5, "Quality": 99, "Counter": 1})
    assert d.decode(0x123, False, b"\x00") is None
    assert d.decode(FORCE_ID, True, force_frame(0, 0, 0)) is None  # same number, extended id: not ours
    with pytest.raises(FrameProblem, match="FT_Force") as ei:
        d.decode(FORCE_ID, False, b"\x01\x02\x03")
    assert ei.value.data == b"\x01\x02\x03"
    with pytest.raises(ValueRejected, match=r"field 'Fx' value 310\.0 rejected: out of range \[-300, 300\]"):
        d.decode(FORCE_ID, False, force_frame(310.0, 0, 0))
    with pytest.raises(ValueRejected, match=r"'Distance' value 6000\.0"):
        d.decode(DISTANCE_ID, False, struct.pack("<HBB", 60000, 0, 0))
    assert {f["can_id"] for f in d.can_filters()} == {FORCE_ID, TORQUE_ID, DISTANCE_ID}


def test_layout_decoder_offsets_sign_endianness_scale() -> None:
    layout = CanMessageLayout.model_validate({
        "id": 0x18FF0010, "extended": True, "name": "probe",
        "signals": {
            "distance": {"start": 0, "size": 2, "signed": False, "byte_order": "big", "scale": 0.1, "max": 5000},
            "temp": {"start": 2, "size": 1, "signed": True, "offset": 20.0},
            "force": {"start": 4, "size": 4, "signed": True, "byte_order": "little", "scale": 0.001},
        },
    })
    d = LayoutDecoder([layout])
    data = bytes.fromhex("30 39 fb 00") + struct.pack("<i", -2500)
    assert d.decode(0x18FF0010, True, data) == ("probe", pytest.approx({"distance": 1234.5, "temp": 15.0,
                                                                          "force": -2.5}))
    assert d.decode(0x18FF0010, False, data) is None
    with pytest.raises(FrameProblem, match="needs 8"):
        d.decode(0x18FF0010, True, data[:5])
    with pytest.raises(ValueRejected, match=r"'distance' value 6553\.5"):
        d.decode(0x18FF0010, True, b"\xff\xff" + data[2:])
    with pytest.raises(ValueError, match="needs extended"):
        CanMessageLayout.model_validate({"id": 0x800, "signals": {"a": {"start": 0}}})


def test_can_config_errors_name_the_key(tmp_path: Path) -> None:
    (tmp_path / "c.toml").write_text(
        '[adapters.a]\ntype = "can"\ninterface = "virtual"\ndbc = "missing.dbc"\n'
        f'[adapters.b]\ntype = "can"\ninterface = "virtual"\ndbc = "{DBC}"\nmessages = ["FT_Nope"]\n'
        '[adapters.c]\ntype = "can"\ninterface = "virtual"\n'
        '[[adapters.d.layout]]\nid = 0x100\n[adapters.d.layout.signals.x]\nstart = 0\nmin = 5\nmax = 1\n'
    )
    with pytest.raises(ConfigError) as ei:
        load_inputs_config(tmp_path / "c.toml")
    text = str(ei.value)
    assert "adapters.a.dbc = 'missing.dbc': Value error, DBC file" in text
    assert "adapters.b.messages = ['FT_Nope']: message 'FT_Nope' is not in" in text
    assert "adapters.c.dbc = None: give exactly one of dbc or layout" in text
    assert "adapters.d.type = '<missing>'" in text or "adapters.d.type = None" in text
    (tmp_path / "d.toml").write_text(
        '[adapters.d]\ntype = "can"\ninterface = "virtual"\n'
        '[[adapters.d.layout]]\nid = 0x100\n[adapters.d.layout.signals.x]\nstart = 0\nmin = 5\nmax = 1\n'
    )
    with pytest.raises(ConfigError, match=r"adapters\.d\.layout\.0\.signals\.x\.min = 5\.0: above max 1\.0"):
        load_inputs_config(tmp_path / "d.toml")


# -- adapter logic ---------------------------------------------------------------------------------

def test_merged_measurement_is_stamped_with_the_oldest_part() -> None:
    a = ft_adapter("unused")

    def msg(i: int, data: bytes) -> can.Message:
        return can.Message(arbitration_id=i, data=data, is_extended_id=False)

    a.process(msg(FORCE_ID, force_frame(1, 2, 3)), now=1.000)
    assert a.output.read() is None  # torques not seen yet: an incomplete wrench is not published
    a.process(msg(TORQUE_ID, torque_frame(0.1, 0.2, 0.3)), now=1.002)
    m = a.output.read().value
    assert dict(m.values) == pytest.approx({"Fx": 1, "Fy": 2, "Fz": 3, "Tx": 0.1, "Ty": 0.2, "Tz": 0.3})
    assert m.stamp == 1.000
    # The torque frame stops coming: the merged wrench keeps the torque's age and goes stale.
    a.process(msg(FORCE_ID, force_frame(4, 5, 6)), now=1.004)
    a.process(msg(FORCE_ID, force_frame(7, 8, 9)), now=1.5)
    cur = a.output.read()
    assert cur.value["Fx"] == 7 and cur.stamp == 1.002 and a.status(now=1.5).stale
    # Error frames and malformed frames are counted, never raised.
    a.process(can.Message(arbitration_id=0, is_error_frame=True), now=1.6)
    a.process(msg(TORQUE_ID, b"\x00"), now=1.6)
    assert a.problems.counts["bus_error"] == 1 and a.problems.counts["malformed"] == 1


def test_ft_sensor_on_virtual_bus() -> None:
    channel = f"ft-{uuid.uuid4().hex}"
    a = ft_adapter(channel, require_all=True)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        with a:
            wait_until(lambda: a.connected)
            sender.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))  # not ours
            sender.send(can.Message(arbitration_id=FORCE_ID, data=force_frame(10, 0, -20), is_extended_id=False))
            sender.send(can.Message(arbitration_id=TORQUE_ID, data=torque_frame(0, 1.5, 0), is_extended_id=False))
            m = wait_for(a.output, lambda m: True)
            assert isinstance(m, Measurement) and m["Fx"] == 10 and m["Fz"] == -20 and m["Ty"] == 1.5
            sender.send(can.Message(arbitration_id=FORCE_ID, data=force_frame(310, 0, 0), is_extended_id=False))
            sender.send(can.Message(arbitration_id=FORCE_ID, data=b"\x00\x01", is_extended_id=False))
            sender.send(can.Message(arbitration_id=FORCE_ID, data=force_frame(11, 0, 0), is_extended_id=False))
            wait_for(a.output, lambda m: m["Fx"] == 11)
            c = a.status().problems
            assert c["rejected"] == 1 and c["malformed"] == 1
            assert any("field 'Fx' value 310.0" in p.message for p in a.status().recent_problems)
            assert any(p.data_hex == "00 01" for p in a.status().recent_problems)
    finally:
        sender.shutdown()


def test_frames_queued_together_make_one_sample_of_the_newest_values() -> None:
    """A sensor's force and torque frames arrive together: one poll drains the queue and publishes
    once, so the bridge steps once per sensor sample, with the newest values."""
    channel = f"ft-{uuid.uuid4().hex}"
    a = ft_adapter(channel, require_all=True)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        a._open()
        for fx in (1, 2):
            sender.send(can.Message(arbitration_id=FORCE_ID, data=force_frame(fx, 0, 0), is_extended_id=False))
        sender.send(can.Message(arbitration_id=TORQUE_ID, data=torque_frame(0, 0.5, 0), is_extended_id=False))
        a._poll()
        assert a.output.seq == 1
        m = a.output.read().value
        assert m["Fx"] == 2 and m["Ty"] == 0.5
    finally:
        a._close()
        sender.shutdown()


# -- slcan over a pseudo-terminal ------------------------------------------------------------------

class SlcanDevice:
    """The USB-CAN adapter side of slcan on a pty master: answers commands with CR, sends frames."""

    def __init__(self) -> None:
        # Our own slave fd stays open: with no slave open, reads on the master fail with EIO.
        self.master, self.slave = os.openpty()
        self.path = os.ttyname(self.slave)
        self.commands: list[str] = []
        self._buf = b""

    def serve_until_open(self, timeout: float = 15.0) -> None:
        deadline = time.monotonic() + timeout
        while "O" not in self.commands:
            if time.monotonic() > deadline:
                raise AssertionError(f"no open command; got {self.commands}")
            r, _, _ = select.select([self.master], [], [], 0.1)
            if not r:
                continue
            self._buf += os.read(self.master, 1024)
            while b"\r" in self._buf:
                line, self._buf = self._buf.split(b"\r", 1)
                self.commands.append(line.decode())
                os.write(self.master, b"\r")  # OK

    def send_frame(self, can_id: int, data: bytes) -> None:
        os.write(self.master, f"t{can_id:03X}{len(data)}{data.hex().upper()}\r".encode())

    def close(self) -> None:
        os.close(self.master)
        os.close(self.slave)


def distance_over_slcan(dev: SlcanDevice) -> InputAdapter:
    """The DBC distance sensor's adapter on ``dev``'s pty (500 kbit/s)."""
    return create_adapter({"type": "can", "name": "dist", "interface": "slcan", "channel": dev.path,
                           "bitrate": 500000, "bus_options": {"sleep_after_open": 0}, "dbc": str(DBC),
                           "messages": ["Distance"], "poll_timeout_s": 0.02})


def test_distance_sensor_over_slcan_pty() -> None:
    dev = SlcanDevice()
    a = distance_over_slcan(dev)
    try:
        with a:
            dev.serve_until_open()
            assert "S6" in dev.commands  # 500 kbit/s
            wait_until(lambda: a.connected)
            dev.send_frame(DISTANCE_ID, bytes.fromhex("39 30 63 01"))
            m = wait_for(a.output, lambda m: True)
            assert dict(m.values) == pytest.approx({"Distance": 1234.5, "Quality": 99, "Counter": 1})
            dev.send_frame(0x7FF, b"\x01")  # someone else's frame on the bus
            dev.send_frame(DISTANCE_ID, struct.pack("<HBB", 60000, 50, 2))  # 6000 mm: beyond the DBC range
            dev.send_frame(DISTANCE_ID, struct.pack("<HBB", 1000, 80, 3))
            wait_for(a.output, lambda m: m["Counter"] == 3)
            assert a.status().problems["rejected"] == 1
    finally:
        dev.close()


def test_slcan_reads_what_has_arrived_at_once_and_waits_without_polling() -> None:
    """python-can's own slcan reader takes one byte per call and wakes every millisecond when idle;
    ours waits on the port and takes everything waiting (a 1 kHz sensor must not eat the GIL)."""
    dev = SlcanDevice()
    opener = threading.Thread(target=dev.serve_until_open)
    opener.start()
    bus = SlcanBus(channel=dev.path, bitrate=500000, sleep_after_open=0)
    opener.join()
    port = bus.serialPortOrig
    reads: list[int] = []
    read = port.read

    def counted(size: int = 1) -> bytes:
        reads.append(size)
        return read(size)

    port.read = counted  # type: ignore[method-assign]
    try:
        assert bus.recv(0.1) is None and len(reads) <= 1  # the replies to the set-up commands, in one read
        reads.clear()
        assert bus.recv(0.2) is None and reads == []  # idle: asleep in select, not polling the port
        # One burst (as a USB adapter hands over a packet of frames): a loaded machine cannot split it
        # into as many reads as frames by waking the reader between writes.
        os.write(dev.master, b"".join(f"t{0x100 + i:03X}2{i:02X}AB\r".encode() for i in range(50)))
        got = [bus.recv(1.0) for _ in range(50)]
        assert [m.arbitration_id for m in got if m is not None] == list(range(0x100, 0x132))
        assert all(m is not None and bytes(m.data) == bytes([i, 0xAB]) for i, m in enumerate(got))
        assert len(reads) <= 10 and sum(reads) >= 50 * 10  # ~650 bytes in a few calls, not one per byte
    finally:
        bus.shutdown()
        dev.close()


def test_garbled_slcan_lines_are_malformed_frames_and_the_port_stays_open() -> None:
    """A line the USB-CAN adapter garbled (a non-ASCII byte, a bad hex digit) is counted as malformed
    with its bytes; the port stays open and the frames around it are read. (A non-ASCII byte used to
    be taken for an unplugged sensor: the port was closed and reopened, the readings stale meanwhile.)"""
    dev = SlcanDevice()
    a = distance_over_slcan(dev)
    try:
        with a:
            dev.serve_until_open()
            wait_until(lambda: a.connected)
            dev.send_frame(DISTANCE_ID, struct.pack("<HBB", 1000, 80, 1))
            wait_for(a.output, lambda m: m["Counter"] == 1)
            os.write(dev.master, b"t2B04\xff\xfe\x00\x01\r" + b"tXYZ8zz\r")
            dev.send_frame(DISTANCE_ID, struct.pack("<HBB", 1000, 80, 2))
            wait_for(a.output, lambda m: m["Counter"] == 2)
            status = a.status()
            assert status.problems["malformed"] == 2, status.problems
            assert status.problems["disconnected"] == 0 and status.problems["error"] == 0, status.problems
            assert status.connects == 1 and status.connected
            bad = [p for p in status.recent_problems if p.kind == "malformed"]
            assert bad[0].data_hex == "74 32 42 30 34 ff fe 00 01 0d" and "does not parse" in bad[0].message
            assert "invalid literal for int() with base 16: 'XYZ'" in bad[1].message
            # Bytes that never end a line (a wrong serial speed): dropped past MAX_LINE as one malformed
            # problem, the buffer does not grow, and the port stays open.
            os.write(dev.master, b"\x55" * 3000 + b"\r")
            dev.send_frame(DISTANCE_ID, struct.pack("<HBB", 1000, 80, 3))
            wait_for(a.output, lambda m: m["Counter"] == 3)
            status = a.status()
            assert status.problems["disconnected"] == 0 and status.connects == 1, status.problems
            overlong = [p for p in status.recent_problems if "no line end" in p.message]
            assert overlong and all(p.kind == "malformed" for p in overlong), status.recent_problems
            assert a._bus is not None and len(a._bus._buffer) <= MAX_LINE
    finally:
        dev.close()
