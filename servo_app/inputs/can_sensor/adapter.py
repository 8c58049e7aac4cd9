"""CAN sensor adapter: python-can bus by interface name -> decoder -> one merged Measurement.

A sensor often spreads one reading over several frames (forces in one, torques in the next). The
adapter merges the newest values of all its messages into one Measurement stamped with the OLDEST
contributing frame's receive time: if one message stops arriving, the merged reading ages and goes
stale instead of pairing fresh forces with old torques. With `require_all` nothing is published
until every message has been seen.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Literal

import can
from pydantic import Field, PrivateAttr, ValidationInfo, field_validator, model_validator

from servo_app.inputs.adapter import AdapterConfig, Clock, InputAdapter
from servo_app.inputs.can_sensor.decoders import CanMessageLayout, DbcDecoder, FrameDecoder, FrameProblem, LayoutDecoder
from servo_app.inputs.can_sensor.slcan import SlcanBus
from servo_app.inputs.device_failure import DeviceFailure, can_failure
from servo_app.inputs.errors import KeyedError
from servo_app.inputs.fields import FieldConfig
from servo_app.inputs.samples import Measurement
from servo_app.inputs.validate import ValueRejected


class CanConfig(AdapterConfig):
    type: Literal["can"] = "can"
    interface: str = Field(min_length=1)  # any python-can interface: socketcan, virtual, slcan, pcan...
    channel: str | int | None = None
    bitrate: int | None = Field(None, gt=0)
    bus_options: dict[str, Any] = Field(default_factory=dict)  # passed to can.Bus as keywords
    dbc: Path | None = None  # relative to the configuration file
    messages: list[str] | None = None  # DBC messages to use (default: all)
    layout: list[CanMessageLayout] | None = None
    field_options: dict[str, FieldConfig] = Field(default_factory=dict)
    require_all: bool = True
    max_frames_per_poll: int = Field(256, gt=0)
    stale_after_s: float = Field(0.1, gt=0.0)
    _decoder: FrameDecoder | None = PrivateAttr(None)

    @field_validator("dbc")
    @classmethod
    def _resolve(cls, v: Path | None, info: ValidationInfo) -> Path | None:
        base = (info.context or {}).get("base_dir")
        if v is not None and not v.is_absolute() and base is not None:
            v = Path(base) / v
        if v is not None and not v.is_file():
            raise ValueError(f"DBC file {str(v)!r} not found")
        return v

    @model_validator(mode="after")
    def _decoder_ok(self) -> CanConfig:
        if (self.dbc is None) == (self.layout is None):
            raise KeyedError("dbc", None if self.dbc is None else str(self.dbc), "give exactly one of dbc or layout")
        if self.layout is not None:
            self._decoder = LayoutDecoder(self.layout)
            return self
        try:
            self._decoder = DbcDecoder.from_file(str(self.dbc), self.messages, self.field_options)
        except KeyError as exc:
            raise KeyedError("messages", self.messages, f"message {exc} is not in {self.dbc}") from None
        except Exception as exc:
            raise KeyedError("dbc", str(self.dbc), f"cannot load the DBC file: {exc}") from None
        return self

    def decoder(self) -> FrameDecoder:
        assert self._decoder is not None
        return self._decoder


class CanSensorAdapter(InputAdapter):
    config_model = CanConfig
    config: CanConfig
    io_errors = (OSError, can.CanError)

    def __init__(self, config: CanConfig, *, clock: Clock = time.monotonic) -> None:
        super().__init__(config, clock=clock)
        self.decoder = config.decoder()
        self._expected = set(self.decoder.message_names())
        self._bus: can.BusABC | None = None
        self._latest: dict[str, tuple[float, dict[str, float]]] = {}

    def _open(self) -> None:
        c = self.config
        kwargs: dict[str, Any] = dict(c.bus_options)
        if c.bitrate is not None:
            kwargs["bitrate"] = c.bitrate
        if c.interface == "slcan":  # python-can's protocol, with a reader that takes what has arrived at once
            self._bus = SlcanBus(channel=str(c.channel), can_filters=self.decoder.can_filters(), **kwargs)
        else:
            self._bus = can.Bus(interface=c.interface, channel=c.channel, can_filters=self.decoder.can_filters(),
                                **kwargs)
        self._latest.clear()  # values from before a reconnect must not merge with new ones

    def explain_open_failure(self, exc: BaseException) -> DeviceFailure:
        return can_failure(self.name, self.config.interface, self.config.channel, exc)

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()

    def _recv(self, timeout: float) -> can.Message | None:
        assert self._bus is not None
        try:
            return self._bus.recv(timeout)
        except FrameProblem as exc:  # a garbled line from a serial CAN adapter (slcan): the bus stays open
            self.problems.record("malformed", str(exc), exc.data)
            return None

    def _poll(self) -> None:
        msg = self._recv(self.config.poll_timeout_s)
        n = 0
        fresh = False
        # Take everything already queued, then publish once: the newest values (a sensor's force and
        # torque frames arrive together; one sample for both halves the work downstream).
        while msg is not None and n < self.config.max_frames_per_poll:
            fresh |= self._take(msg, self.clock())
            n += 1
            msg = self._recv(0.0)
        if msg is not None:
            fresh |= self._take(msg, self.clock())
        if fresh:
            self._publish_latest()

    def process(self, msg: can.Message, now: float) -> None:
        """One frame: decoded, and the sample published if it completes one."""
        if self._take(msg, now):
            self._publish_latest()

    def _take(self, msg: can.Message, now: float) -> bool:
        """Decode one frame into the newest values per message; True if it was one of ours."""
        if msg.is_error_frame:
            self.problems.record("bus_error", f"error frame id 0x{msg.arbitration_id:X}", bytes(msg.data))
            return False
        if msg.is_remote_frame:
            return False
        try:
            decoded = self.decoder.decode(msg.arbitration_id, msg.is_extended_id, bytes(msg.data))
            if decoded is None:
                return False  # not ours (filters are only a hint on some interfaces)
            name, values = decoded
            conditioned = {k: self._condition(k, v) for k, v in values.items()}
        except FrameProblem as exc:
            self.problems.record("malformed", str(exc), exc.data)
            return False
        except ValueRejected as exc:
            self.problems.record("rejected", f"0x{msg.arbitration_id:X}: {exc}", bytes(msg.data))
            return False
        self._latest[name] = (now, conditioned)
        return True

    def _publish_latest(self) -> None:
        if self.config.require_all and not self._expected <= self._latest.keys():
            return
        merged: dict[str, float] = {}
        for _, vals in self._latest.values():
            merged.update(vals)
        stamp = min(s for s, _ in self._latest.values())
        self._publish(Measurement(merged, stamp, self.name))
