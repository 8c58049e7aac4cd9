"""SpaceMouse HID input reports.

hidapi returns a report with its report ID as the first byte. Older models send translation in
report 1 (X Y Z as int16 little-endian), rotation in report 2 (RX RY RZ) and buttons in report 3 (a
little-endian bit mask, bit n = button n). Newer models send all six axes in report 1 (12 bytes of
payload). Other report IDs (battery, LEDs on wireless models) are not ours and are ignored.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

_AXES3 = struct.Struct("<3h")
_AXES6 = struct.Struct("<6h")


class MalformedReport(ValueError):
    def __init__(self, message: str, data: bytes) -> None:
        super().__init__(message)
        self.data = data


@dataclass(frozen=True, slots=True)
class AxesReport:
    translation: tuple[int, int, int] | None
    rotation: tuple[int, int, int] | None


@dataclass(frozen=True, slots=True)
class ButtonsReport:
    mask: int


def decode_report(data: bytes | Sequence[int]) -> AxesReport | ButtonsReport | None:
    """Decode one report (report ID first); None for report IDs that carry no axes or buttons."""
    raw = bytes(data)
    if not raw:
        raise MalformedReport("empty report", raw)
    rid, payload = raw[0], raw[1:]
    if rid == 1:
        if len(payload) >= _AXES6.size:
            v = _AXES6.unpack_from(payload)
            return AxesReport(v[:3], v[3:])
        if len(payload) >= _AXES3.size:
            return AxesReport(_AXES3.unpack_from(payload), None)
        raise MalformedReport(f"report 1 has {len(payload)} payload bytes, need 6 or 12", raw)
    if rid == 2:
        if len(payload) >= _AXES3.size:
            return AxesReport(None, _AXES3.unpack_from(payload))
        raise MalformedReport(f"report 2 has {len(payload)} payload bytes, need 6", raw)
    if rid == 3:
        if not payload:
            raise MalformedReport("report 3 has no button bytes", raw)
        return ButtonsReport(int.from_bytes(payload, "little"))
    return None


def encode_axes(translation: Sequence[int] | None = None, rotation: Sequence[int] | None = None,
                six_axis: bool = False) -> list[bytes]:
    """The reports a device would send for these axes (used by tests and simulators)."""
    t = tuple(translation or (0, 0, 0))
    r = tuple(rotation or (0, 0, 0))
    if six_axis:
        return [b"\x01" + _AXES6.pack(*t, *r)]
    return [b"\x01" + _AXES3.pack(*t), b"\x02" + _AXES3.pack(*r)]


def encode_buttons(mask: int, nbytes: int = 2) -> bytes:
    return b"\x03" + mask.to_bytes(nbytes, "little")
