"""Simulated controller I/O for the command packet's read/write fields (manual table 3, 61.7).

Each assigned type has points 1..N. A read or write names a start index and covers the 16 points
from it; if any of those 16 points lies outside 1..N, or the type is not assigned at all (by
default SI/SO/WI/WO/WSI/WSO), the controller posts PRIO-023 "There is no I/O for this type"
(61.7: "If you try to read or write I/O that contains an index that has not been assigned, an
alarm will occur"). The check covers all 16 points whatever the mask, as that wording suggests.
Inputs are writable too (as simulated inputs are on a real controller), so tests can drive DI.
"""

from __future__ import annotations

from collections.abc import Mapping

from servo_app.fanuc.packets import IoType

IO_SPAN = 16

DEFAULT_IO_POINTS: dict[int, int] = {
    IoType.DI: 512,
    IoType.DO: 512,
    IoType.RI: 8,
    IoType.RO: 8,
    IoType.UI: 24,
    IoType.UO: 24,
    IoType.F: 1024,
    IoType.M: 1024,
}


class IoError(LookupError):
    """An I/O access the controller rejects with PRIO-023."""


class IoTable:
    """Boolean points per I/O type; ``points`` maps type code -> number of assigned points."""

    def __init__(self, points: Mapping[int, int] | None = None) -> None:
        self.points = dict(DEFAULT_IO_POINTS if points is None else points)
        # Bit i of _bits[type] is point i + 1: a Python int is an arbitrary-length bit array.
        self._bits: dict[int, int] = {t: 0 for t in self.points}

    def _check(self, io_type: int, index: int) -> None:
        n = self.points.get(io_type)
        if n is None:
            raise IoError(f"I/O type {io_type} is not assigned")
        if index < 1 or index + IO_SPAN - 1 > n:
            raise IoError(f"I/O type {io_type} points {index}..{index + IO_SPAN - 1} are not all in 1..{n}")

    def read(self, io_type: int, index: int, mask: int) -> int:
        """16 points from ``index`` (LSB = ``index``), masked. Type 0: nothing to read, 0."""
        if io_type == IoType.NONE:
            return 0
        self._check(io_type, index)
        return (self._bits[io_type] >> (index - 1)) & 0xFFFF & mask

    def write(self, io_type: int, index: int, mask: int, value: int) -> None:
        """Set the masked points of the 16 from ``index`` to the bits of ``value``. Type 0: no-op."""
        if io_type == IoType.NONE:
            return
        self._check(io_type, index)
        shift = index - 1
        m = (mask & 0xFFFF) << shift
        self._bits[io_type] = (self._bits[io_type] & ~m) | (((value & 0xFFFF) << shift) & m)

    def check(self, io_type: int, index: int) -> None:
        """Raise IoError unless a 16-point access at ``index`` is assigned (type 0 always passes)."""
        if io_type != IoType.NONE:
            self._check(io_type, index)

    def get(self, io_type: int, point: int) -> bool:
        """One point (1-based), for tests and the CLI."""
        if io_type not in self._bits or not 1 <= point <= self.points[io_type]:
            raise IoError(f"I/O type {io_type} point {point} is not assigned")
        return bool(self._bits[io_type] >> (point - 1) & 1)

    def set(self, io_type: int, point: int, on: bool) -> None:
        if io_type not in self._bits or not 1 <= point <= self.points[io_type]:
            raise IoError(f"I/O type {io_type} point {point} is not assigned")
        bit = 1 << (point - 1)
        self._bits[io_type] = self._bits[io_type] | bit if on else self._bits[io_type] & ~bit
