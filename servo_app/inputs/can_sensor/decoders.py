"""CAN frame -> named physical values, through a DBC database (cantools) or a configured byte layout.

A decoder returns (message name, values) for frames it knows, None for frames that are not its
own, and raises FrameProblem (with the bytes) for a frame it knows but cannot decode. Values are
checked against limits here, so a rejection names the signal and its value.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, model_validator

from servo_app.inputs.errors import KeyedError
from servo_app.inputs.fields import DEFAULT_FIELD, FieldConfig
from servo_app.inputs.validate import check_range

STD_MASK, EXT_MASK = 0x7FF, 0x1FFFFFFF


class FrameProblem(ValueError):
    def __init__(self, message: str, data: bytes) -> None:
        super().__init__(message)
        self.data = data


class FrameDecoder(Protocol):
    def message_names(self) -> list[str]: ...
    def can_filters(self) -> list[dict[str, Any]]: ...
    def decode(self, arbitration_id: int, is_extended: bool, data: bytes) -> tuple[str, dict[str, float]] | None: ...


class CanSignalLayout(FieldConfig):
    start: int = Field(ge=0, le=63)  # byte offset in the data field
    size: Literal[1, 2, 4, 8] = 2
    signed: bool = True
    byte_order: Literal["little", "big"] = "little"


class CanMessageLayout(BaseModel):
    model_config = ConfigDict(extra="forbid")

    id: int = Field(ge=0, le=EXT_MASK)
    extended: bool = False
    name: str | None = None
    signals: dict[str, CanSignalLayout] = Field(min_length=1)

    @model_validator(mode="after")
    def _fits(self) -> CanMessageLayout:
        if not self.extended and self.id > STD_MASK:
            raise KeyedError("id", self.id, f"0x{self.id:X} needs extended = true (standard ids end at 0x7FF)")
        for name, s in self.signals.items():
            if s.start + s.size > 64:
                raise KeyedError(f"signals.{name}.start", s.start, f"the signal ends after byte 64 ({s.size} bytes)")
        return self

    @property
    def label(self) -> str:
        return self.name or f"0x{self.id:X}"

    @property
    def length(self) -> int:
        return max(s.start + s.size for s in self.signals.values())


class LayoutDecoder:
    def __init__(self, messages: Iterable[CanMessageLayout]) -> None:
        self._by_id = {(m.id, m.extended): m for m in messages}

    def message_names(self) -> list[str]:
        return [m.label for m in self._by_id.values()]

    def can_filters(self) -> list[dict[str, Any]]:
        return [{"can_id": i, "can_mask": EXT_MASK if ext else STD_MASK, "extended": ext} for i, ext in self._by_id]

    def decode(self, arbitration_id: int, is_extended: bool, data: bytes) -> tuple[str, dict[str, float]] | None:
        m = self._by_id.get((arbitration_id, is_extended))
        if m is None:
            return None
        if len(data) < m.length:
            raise FrameProblem(f"{m.label}: {len(data)} data bytes, layout needs {m.length}", data)
        values = {}
        for name, s in m.signals.items():
            raw = int.from_bytes(data[s.start:s.start + s.size], s.byte_order, signed=s.signed)
            values[name] = s.convert(name, raw)
        return m.label, values


class DbcDecoder:
    def __init__(self, db: Any, messages: Iterable[str] | None = None,
                 field_options: Mapping[str, FieldConfig] | None = None) -> None:
        wanted = list(messages) if messages else [m.name for m in db.messages]
        self._msgs = {}
        for name in wanted:
            m = db.get_message_by_name(name)  # KeyError for a name not in the database
            self._msgs[(m.frame_id, bool(m.is_extended_frame))] = m
        self._opts = dict(field_options or {})
        self._limits = {s.name: (s.minimum, s.maximum) for m in self._msgs.values() for s in m.signals}

    @classmethod
    def from_file(cls, path: str, messages: Iterable[str] | None = None,
                  field_options: Mapping[str, FieldConfig] | None = None) -> DbcDecoder:
        import cantools

        return cls(cantools.database.load_file(path, database_format="dbc"), messages, field_options)

    def message_names(self) -> list[str]:
        return [m.name for m in self._msgs.values()]

    def can_filters(self) -> list[dict[str, Any]]:
        return [{"can_id": i, "can_mask": EXT_MASK if ext else STD_MASK, "extended": ext} for i, ext in self._msgs]

    def decode(self, arbitration_id: int, is_extended: bool, data: bytes) -> tuple[str, dict[str, float]] | None:
        m = self._msgs.get((arbitration_id, is_extended))
        if m is None:
            return None
        try:
            decoded = m.decode(bytes(data), decode_choices=False)
        except Exception as exc:  # cantools raises DecodeError and friends
            raise FrameProblem(f"{m.name}: {exc}", bytes(data)) from None
        values = {}
        for name, v in decoded.items():
            opt = self._opts.get(name, DEFAULT_FIELD)
            lo, hi = self._limits.get(name, (None, None))
            # DBC limits apply to the physical value; configured options may convert and narrow further.
            physical = check_range(name, v, lo, hi)
            values[name] = opt.convert(name, physical)
        return m.name, values
