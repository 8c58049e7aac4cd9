"""Serial sensors: parsers on byte streams, and the adapters on real pseudo-terminal pairs
(including unplugging: the pty goes away and comes back under the same symlink, like a udev path)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from waiting import wait_for, wait_until

from servo_app.inputs import ConfigError, Measurement, create_adapter
from servo_app.inputs.serial_sensor.adapter import SerialBinaryAdapter, SerialLineAdapter
from servo_app.inputs.serial_sensor.binary import BinaryFrameParser, FrameLayout
from servo_app.inputs.serial_sensor.checksums import crc16_modbus, sum8, xor8
from servo_app.inputs.serial_sensor.line import LineParser
from servo_app.inputs.serial_sensor.parsing import Bad, Decoded

LAYOUT = FrameLayout(b"\xaa\x55", "<3hB", ("fx", "fy", "fz", "status"), "crc16_modbus")


class PtyDevice:
    """A serial device on a pseudo-terminal, reachable through a stable symlink."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.master = -1
        self.plug()

    def plug(self) -> None:
        self.master, slave = os.openpty()
        target = os.ttyname(slave)
        os.close(slave)  # the adapter opens the slave by path, as it would a real port
        tmp = self.link.with_suffix(".new")
        os.symlink(target, tmp)
        os.replace(tmp, self.link)

    def unplug(self) -> None:
        os.close(self.master)
        self.master = -1
        self.link.unlink()

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def close(self) -> None:
        if self.master >= 0:
            os.close(self.master)
            self.master = -1


# -- checksums and parsers -------------------------------------------------------------------------

def test_checksums_known_values() -> None:
    assert crc16_modbus(b"123456789") == 0x4B37  # the CRC-16/MODBUS check value
    assert crc16_modbus(bytes.fromhex("01 03 00 00 00 0a")) == 0xCDC5  # read holding registers request
    assert sum8(b"\x01\x02\xff") == 0x02 and xor8(b"\x0f\xf0\xff") == 0x00


def test_line_parser_fields_garbage_partial_overflow() -> None:
    p = LineParser({"distance": r"D=\s*([-+0-9.eEnaif]+)", "temp": r"T=(?P<value>[-0-9.]+)"},
                   terminator=b"\n", max_line=32)
    out = p.feed(b"D=123.45\r\nD=12")
    assert out == [Decoded({"distance": 123.45}, b"D=123.45")]
    out = p.feed(b"3.5 T=21.5\r\n\x00\xff@@\r\nhello\r\nD=1.2.3\r\n")
    assert out[0] == Decoded({"distance": 123.5, "temp": 21.5}, b"D=123.5 T=21.5")
    assert [type(r) for r in out[1:]] == [Bad, Bad, Bad]
    assert "not ascii" in out[1].message and out[1].raw == b"\x00\xff@@"
    assert out[2].message == "no field matched the line"
    assert "field 'distance' value '1.2.3' is not a number" in out[3].message
    out = p.feed(b"x" * 40)
    assert len(out) == 1 and out[0].kind == "overflow"
    assert p.feed(b"D=7\n") == [Decoded({"distance": 7.0}, b"D=7")]
    # A line longer than max_line that does end, read at once: refused whole, not searched for a field
    # (its D=5 was taken as a reading).
    out = p.feed(b"@" * 40 + b"D=5\r\nD=6\n")
    assert [r.kind for r in out if isinstance(r, Bad)] == ["overflow"] and "43 bytes" in out[0].message
    assert out[1:] == [Decoded({"distance": 6.0}, b"D=6")]


def test_problem_log_keeps_a_bounded_sample_of_the_bytes() -> None:
    import logging

    from servo_app.inputs.problems import MAX_DATA, ProblemLog

    log = ProblemLog(logging.getLogger("test"), lambda: 0.0)
    small = log.record("malformed", "short", b"\x01\x02")
    assert small.data_hex == "01 02"
    big = log.record("malformed", "a flood", bytes(range(256)) * 40)
    assert big.data_hex is not None and big.data_hex.endswith(" ... (10240 bytes)")
    assert big.data_hex.startswith(bytes(range(MAX_DATA)).hex(" ")) and len(big.data_hex) < 4 * MAX_DATA


def test_problem_counts_held_back_by_the_rate_limit_reach_the_log(caplog: pytest.LogCaptureFixture) -> None:
    """The log takes one line per kind a second; the number held back was only told on the next line of
    the same kind, so a burst that never recurred left the log saying one problem where there were
    five. Now the count comes with the next line of any kind once the second has passed, from a poll
    (report_due), or at close (flush); each kind's count at most once a second."""
    import logging

    from servo_app.inputs.problems import ProblemLog

    t = [0.0]
    log = ProblemLog(logging.getLogger("test.problems"), lambda: t[0])

    def lines() -> list[str]:
        out = [r.getMessage() for r in caplog.records if r.name == "test.problems"]
        caplog.clear()
        return out

    with caplog.at_level(logging.INFO, logger="test.problems"):
        for i in range(5):
            log.record("checksum", f"frame {i}")
        assert lines() == ["checksum: frame 0"]
        t[0] = 0.5
        log.record("garbage", "3 bytes")  # within the second: the checksum count waits
        log.report_due()
        assert lines() == ["garbage: 3 bytes"]
        t[0] = 1.6
        log.record("garbage", "4 bytes")  # another kind's next line brings the count
        assert lines() == ["garbage: 4 bytes", "checksum: 4 more since last report, the last: frame 4"]
        for i in range(3):
            log.record("checksum", f"late {i}")  # within a second of its count: held back again
        log.report_due()
        assert lines() == []
        t[0] = 2.7
        log.report_due()  # a poll brings it once the second has passed
        assert lines() == ["checksum: 3 more since last report, the last: late 2"]
        log.report_due()
        log.record("checksum", "again")
        log.record("checksum", "and again")
        log.flush()  # at close, whatever the interval
        assert lines() == ["checksum: 2 more since last report, the last: and again"]
        log.flush()
        assert lines() == []


def test_an_adapter_reports_the_count_of_a_burst_that_did_not_recur(tmp_path: Path,
                                                                     caplog: pytest.LogCaptureFixture) -> None:
    """A serial sensor sending a burst of bad lines, then good ones: the log said one 'malformed' line and
    never how many followed it. Now the adapter's thread reports the count once the second has passed."""
    import logging

    dev = PtyDevice(tmp_path / "ttyBURST")
    a = create_adapter({"type": "serial_line", "name": "burst", "port": str(dev.link), "poll_timeout_s": 0.02,
                        "fields": {"distance": {"pattern": r"D=\s*([-0-9.]+)"}}})
    try:
        with caplog.at_level(logging.INFO, logger="servo_app.inputs.serial_line.burst"), a:
            wait_until(lambda: a.connected)
            dev.write(b"hello\r\n" * 6)
            wait_until(lambda: sum(a.status().problems.values()) == 6)
            kinds = set(a.status().problems)
            assert len(kinds) == 1, kinds
            kind = kinds.pop()
            dev.write(b"D=5\r\n")
            wait_for(a.output, lambda m: True)

            def said() -> list[str]:
                return [r.getMessage() for r in caplog.records if r.name == "servo_app.inputs.serial_line.burst"
                        and r.getMessage().startswith(f"{kind}:")]
            wait_until(lambda: any("5 more since last report" in m for m in said()), 5.0)
            assert len(said()) == 2, said()  # the first line, then the count once: no spam
    finally:
        dev.close()


def test_binary_parser_garbage_partial_and_bad_checksum() -> None:
    p = BinaryFrameParser(LAYOUT)
    good = LAYOUT.encode([100, -200, 300, 1])
    assert len(good) == LAYOUT.length == 2 + 7 + 2
    bad = bytearray(LAYOUT.encode([1, 2, 3, 0]))
    bad[4] ^= 0x40  # a bit flipped on the line
    out = p.feed(b"\x13\x37\xaa" + good[:5])
    assert out == [Bad("garbage", "3 bytes before a header", b"\x13\x37\xaa")]
    out = p.feed(good[5:] + bytes(bad) + good)
    assert out[0] == Decoded({"fx": 100.0, "fy": -200.0, "fz": 300.0, "status": 1.0}, good)
    assert out[1].kind == "checksum" and out[1].raw == bytes(bad) and "mismatch" in out[1].message
    assert isinstance(out[2], Decoded) and len(out) == 3
    # Pure garbage: reported, but a trailing 0xAA is kept in case it starts a header.
    out = p.feed(b"\x00\x01\x02\xaa")
    assert out == [Bad("garbage", "3 bytes without a header", b"\x00\x01\x02")]
    assert isinstance(p.feed(b"\x55" + good[2:])[0], Decoded)


@st.composite
def frame_values(draw: st.DrawFn) -> list[tuple[int, ...]]:
    i16 = st.integers(-32768, 32767)
    values = draw(st.lists(st.tuples(i16, i16, i16, st.integers(0, 255)), min_size=1, max_size=6))
    # Some payloads carry the header bytes themselves (0x55AA as int16 LE is AA 55).
    return [(0x55AA, *v[1:]) if i % 2 else v for i, v in enumerate(values)]


@given(frame_values(), st.lists(st.floats(0, 1), max_size=8),
       st.sampled_from(["none", "sum8", "xor8", "crc16_modbus"]))
def test_binary_parser_any_chunking_gives_the_same_frames(values: list[tuple[int, ...]], fractions: list[float],
                                                         checksum: str) -> None:
    layout = FrameLayout(b"\xaa\x55", "<3hB", ("fx", "fy", "fz", "status"), checksum, checksum_covers_header=True)
    stream = b"".join(layout.encode(v) for v in values)
    cuts = sorted(int(f * len(stream)) for f in fractions)
    p = BinaryFrameParser(layout)
    out = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        out += p.feed(stream[a:b])
    assert [tuple(r.values.values()) for r in out if isinstance(r, Decoded)] == [
        tuple(float(x) for x in v) for v in values]
    assert not [r for r in out if isinstance(r, Bad)]


def test_frame_layout_validation() -> None:
    with pytest.raises(ValueError, match="header byte"):
        FrameLayout(b"", "<h", ("a",))
    with pytest.raises(ValueError, match="2 values but 1 fields"):
        FrameLayout(b"\xaa", "<hh", ("a",))
    with pytest.raises(ValueError, match="byte order"):
        FrameLayout(b"\xaa", "hh", ("a", "b"))
    with pytest.raises(ValueError, match="only hold numbers"):
        FrameLayout(b"\xaa", "<4s", ("a",))
    with pytest.raises(ConfigError, match=r"adapters\.ft\.length = .*does not match the layout's 11 bytes"):
        create_adapter({"type": "serial_binary", "name": "ft", "port": "/dev/null", "header": "AA 55",
                        "format": "<3hB", "fields": ["fx", "fy", "fz", "status"], "checksum": "crc16_modbus",
                        "length": 12})


# -- adapters on pseudo-terminals ------------------------------------------------------------------

def test_line_sensor_on_pty_rejects_bad_values_and_survives_unplug(tmp_path: Path) -> None:
    dev = PtyDevice(tmp_path / "ttyDIST")
    a = create_adapter({
        "type": "serial_line", "name": "distance", "port": str(dev.link), "baudrate": 115200,
        "terminator": "\n", "poll_timeout_s": 0.02, "reconnect_min_s": 0.02, "reconnect_max_s": 0.05,
        "fields": {"distance": {"pattern": r"D=\s*([^\s]+)", "min": 0.0, "max": 500.0}},
    })
    assert isinstance(a, SerialLineAdapter)
    try:
        with a:
            wait_until(lambda: a.connected)
            dev.write(b"D=123.45\r\n")
            m = wait_for(a.output, lambda m: True)
            assert isinstance(m, Measurement) and m["distance"] == 123.45 and m.source == "distance"
            dev.write(b"\x00\xfe garbage\r\nD=nan\r\nD=999.0\r\nD=4")
            dev.write(b"2.5\r\n")
            wait_for(a.output, lambda m: m["distance"] == 42.5)
            counts = a.status().problems
            assert counts["malformed"] == 1 and counts["rejected"] == 2
            messages = [p.message for p in a.status().recent_problems]
            assert any("field 'distance' value nan rejected: not finite" in s for s in messages)
            assert any("field 'distance' value 999.0 rejected: out of range [0.0, 500.0]" in s for s in messages)
            assert any(p.data_hex == "00 fe 20 67 61 72 62 61 67 65" for p in a.status().recent_problems)

            # Unplug: reads fail, the adapter drops the port and keeps retrying while the path is gone.
            last = a.output.read()
            dev.unplug()
            wait_until(lambda: not a.connected and a.status().problems["open_failed"] >= 1)
            assert a.status().problems["disconnected"] == 1 and a.output.read() == last
            assert a.status(now=last.stamp + 1.0).stale
            # Plugged back in (maybe another /dev/pts number, same link): it reconnects and reads again.
            dev.plug()
            wait_until(lambda: a.connected)
            dev.write(b"D=7.5\r\n")
            wait_for(a.output, lambda m: m["distance"] == 7.5)
            assert a.status().connects == 2 and a.running
    finally:
        dev.close()


def test_binary_sensor_on_pty_frames_garbage_checksums(tmp_path: Path) -> None:
    dev = PtyDevice(tmp_path / "ttyFT")
    a = create_adapter({
        "type": "serial_binary", "name": "ft", "port": str(dev.link), "baudrate": 921600, "header": "AA 55",
        "format": "<3hB", "fields": ["fx", "fy", "fz", "_"], "checksum": "crc16_modbus", "length": 11,
        "poll_timeout_s": 0.02, "field_options": {"fx": {"scale": 0.01, "min": -300, "max": 300},
                                                   "fy": {"scale": 0.01}, "fz": {"scale": 0.01}},
    })
    assert isinstance(a, SerialBinaryAdapter)
    layout = a.config.layout()
    try:
        with a:
            wait_until(lambda: a.connected)
            frame = layout.encode([1250, -50, 981, 0])
            dev.write(b"\xde\xad" + frame[:4])  # garbage, then half a frame
            dev.write(frame[4:])
            m = wait_for(a.output, lambda m: True)
            assert dict(m.values) == pytest.approx({"fx": 12.5, "fy": -0.5, "fz": 9.81})
            corrupt = bytearray(layout.encode([1, 2, 3, 0]))
            corrupt[-1] ^= 0xFF
            over = layout.encode([31000, 0, 0, 0])  # 310 N: beyond the configured 300 N
            dev.write(bytes(corrupt) + over + layout.encode([-100, 0, 0, 0]))
            assert wait_for(a.output, lambda m: m["fx"] == -1.0)["fx"] == -1.0
            c = a.status().problems
            assert c["garbage"] == 1 and c["checksum"] == 1 and c["rejected"] == 1
            bad = next(p for p in a.status().recent_problems if p.kind == "checksum")
            assert bad.data_hex == bytes(corrupt).hex(" ")
            assert any("field 'fx' value 310.0 rejected" in p.message for p in a.status().recent_problems)
    finally:
        dev.close()


def test_a_reading_that_overflows_once_scaled_is_rejected_and_the_next_is_read(tmp_path: Path) -> None:
    """A huge reading (finite, but not once the adapter's scale is applied) is rejected naming the field
    and the value; the line after it, in the same read, is published. (The overflow used to escape as
    an unnamed "error" with a traceback, and took the lines read with it.)"""
    dev = PtyDevice(tmp_path / "ttyBIG")
    a = create_adapter({"type": "serial_line", "name": "distance", "port": str(dev.link), "poll_timeout_s": 0.02,
                        "scale": 10.0, "fields": {"distance": {"pattern": r"D=\s*([^\s]+)"}}})
    try:
        with a:
            wait_until(lambda: a.connected)
            dev.write(b"D=1e308\r\nD=5\r\n")
            assert wait_for(a.output, lambda m: True)["distance"] == 50.0
            status = a.status()
            assert status.problems["rejected"] == 1 and status.problems["error"] == 0, status.problems
            message = status.last_problem.message if status.last_problem else None
            assert message == "field 'distance' value 1e+308 rejected: not finite once scaled by 10.0"
    finally:
        dev.close()
