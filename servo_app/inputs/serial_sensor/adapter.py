"""Serial-port sensor adapters: bytes from pyserial -> parser -> checked Measurement.

Unplugging makes pyserial raise (SerialException is an OSError): the base class closes the port and
reopens it with backoff until the path is back; a new parser starts with an empty buffer so half a
frame from before the unplug cannot join bytes from after it.
"""

from __future__ import annotations

import re
import struct
import time
from typing import Any, Literal

import serial
from pydantic import Field, PositiveInt, field_validator, model_validator

from servo_app.inputs.adapter import AdapterConfig, Clock, InputAdapter
from servo_app.inputs.device_failure import DeviceFailure, serial_failure
from servo_app.inputs.errors import KeyedError
from servo_app.inputs.fields import DEFAULT_FIELD, FieldConfig
from servo_app.inputs.samples import Measurement
from servo_app.inputs.serial_sensor.binary import BinaryFrameParser, FrameLayout
from servo_app.inputs.serial_sensor.checksums import CHECKSUMS
from servo_app.inputs.serial_sensor.line import LineParser
from servo_app.inputs.serial_sensor.parsing import Bad, ParseResult
from servo_app.inputs.validate import ValueRejected


class SerialConfig(AdapterConfig):
    port: str = Field(min_length=1)
    baudrate: PositiveInt = 115200
    bytesize: Literal[5, 6, 7, 8] = 8
    parity: Literal["N", "E", "O", "M", "S"] = "N"
    stopbits: Literal[1, 1.5, 2] = 1
    exclusive: bool = True  # lock the port so a second process cannot steal bytes
    stale_after_s: float = Field(0.25, gt=0.0)


class LineFieldConfig(FieldConfig):
    pattern: str

    @field_validator("pattern")
    @classmethod
    def _compiles(cls, v: str) -> str:
        try:
            p = re.compile(v)
        except re.error as exc:
            raise ValueError(f"not a regular expression: {exc}") from None
        if p.groups < 1:
            raise ValueError("needs a group around the number, e.g. 'D=([-+0-9.eE]+)'")
        return v


class SerialLineConfig(SerialConfig):
    type: Literal["serial_line"] = "serial_line"
    terminator: str = Field("\n", min_length=1)
    encoding: str = "ascii"
    max_line: PositiveInt = 256
    fields: dict[str, LineFieldConfig] = Field(min_length=1)


class SerialBinaryConfig(SerialConfig):
    type: Literal["serial_binary"] = "serial_binary"
    header: bytes
    format: str
    fields: list[str] = Field(min_length=1)
    checksum: Literal["none", "sum8", "xor8", "crc16_modbus"] = "none"
    checksum_covers_header: bool = False
    trailer: bytes = b""
    length: PositiveInt | None = None  # optional cross-check of the whole frame length
    field_options: dict[str, FieldConfig] = Field(default_factory=dict)

    @field_validator("header", "trailer", mode="before")
    @classmethod
    def _hex(cls, v: Any) -> Any:
        if isinstance(v, str):
            try:
                return bytes.fromhex(v)
            except ValueError:
                raise ValueError("must be hex bytes, e.g. 'AA 55'") from None
        return v

    @model_validator(mode="after")
    def _layout(self) -> SerialBinaryConfig:
        try:
            layout = self.layout()
        except (ValueError, struct.error) as exc:
            raise KeyedError("format", self.format, f"{exc} (fields {self.fields})") from None
        if self.length is not None and self.length != layout.length:
            raise KeyedError("length", self.length, f"does not match the layout's {layout.length} bytes")
        unknown = set(self.field_options) - set(self.fields)
        if unknown:
            raise KeyedError("field_options", sorted(unknown), "options for fields that are not in `fields`")
        return self

    def layout(self) -> FrameLayout:
        assert self.checksum in CHECKSUMS
        return FrameLayout(self.header, self.format, tuple(self.fields), self.checksum,
                           self.checksum_covers_header, self.trailer)


class _SerialAdapter(InputAdapter):
    config: SerialConfig

    def __init__(self, config: SerialConfig, *, clock: Clock = time.monotonic) -> None:
        super().__init__(config, clock=clock)
        self._ser: serial.Serial | None = None
        self._parser = self._new_parser()

    def _new_parser(self) -> Any:
        raise NotImplementedError

    def _field(self, name: str) -> FieldConfig:
        return DEFAULT_FIELD

    def _open(self) -> None:
        c = self.config
        self._ser = serial.Serial(c.port, c.baudrate, bytesize=c.bytesize, parity=c.parity, stopbits=c.stopbits,
                                  timeout=c.poll_timeout_s, exclusive=c.exclusive)
        self._parser = self._new_parser()

    def explain_open_failure(self, exc: BaseException) -> DeviceFailure:
        return serial_failure(self.name, self.config.port, exc)

    def _close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            ser.close()

    def _poll(self) -> None:
        assert self._ser is not None
        data = self._ser.read(max(1, self._ser.in_waiting))  # waits up to poll_timeout_s for the first byte
        if data:
            self.process(data, self.clock())

    def process(self, data: bytes, now: float) -> None:
        """Parse received bytes and publish every good sample (all stamped with the receive time)."""
        for result in self._parser.feed(data):
            self._handle(result, now)

    def _handle(self, result: ParseResult, now: float) -> None:
        if isinstance(result, Bad):
            self.problems.record(result.kind, result.message, result.raw)
            return
        try:
            values = {k: self._condition(k, self._field(k).convert(k, v)) for k, v in result.values.items()}
        except ValueRejected as exc:
            self.problems.record("rejected", str(exc), result.raw)
            return
        self._publish(Measurement(values, now, self.name))


class SerialLineAdapter(_SerialAdapter):
    config_model = SerialLineConfig
    config: SerialLineConfig

    def _new_parser(self) -> LineParser:
        c = self.config
        return LineParser({k: f.pattern for k, f in c.fields.items()}, terminator=c.terminator.encode(),
                          encoding=c.encoding, max_line=c.max_line)

    def _field(self, name: str) -> FieldConfig:
        return self.config.fields[name]


class SerialBinaryAdapter(_SerialAdapter):
    config_model = SerialBinaryConfig
    config: SerialBinaryConfig

    def _new_parser(self) -> BinaryFrameParser:
        return BinaryFrameParser(self.config.layout())

    def _field(self, name: str) -> FieldConfig:
        return self.config.field_options.get(name, DEFAULT_FIELD)
