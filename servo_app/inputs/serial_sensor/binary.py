"""Fixed-length binary frames: header bytes, a struct-described payload, a checksum, optional trailer.

The parser finds the header, waits for the whole frame, checks checksum and trailer, and unpacks the
payload into named fields. Bytes before a header are garbage; a frame that fails its checksum is
reported with its bytes and the search restarts just after its first byte (the real header may be
inside it). Fields named "_" are padding and are not published.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from servo_app.inputs.serial_sensor.checksums import CHECKSUMS
from servo_app.inputs.serial_sensor.parsing import Bad, Decoded, ParseResult


@dataclass(frozen=True)
class FrameLayout:
    header: bytes
    payload_format: str  # struct format with explicit byte order, e.g. "<hhh"
    fields: tuple[str, ...]
    checksum: str = "none"
    checksum_covers_header: bool = False
    trailer: bytes = b""

    def __post_init__(self) -> None:
        if not self.header:
            raise ValueError("a frame needs at least one header byte to resynchronise on")
        if self.checksum not in CHECKSUMS:
            raise ValueError(f"unknown checksum {self.checksum!r}; known: {sorted(CHECKSUMS)}")
        if self.payload_format[:1] not in ("<", ">", "!", "="):
            raise ValueError("payload_format must start with a byte order: < > ! or =")
        zeros = struct.Struct(self.payload_format).unpack(bytes(self.payload_size))
        if any(isinstance(v, bytes) for v in zeros):
            raise ValueError("payload_format may only hold numbers (no s or p codes)")
        n = len(zeros)
        if n != len(self.fields):
            raise ValueError(f"payload_format has {n} values but {len(self.fields)} fields are named")

    @property
    def payload_size(self) -> int:
        return struct.calcsize(self.payload_format)

    @property
    def checksum_size(self) -> int:
        return CHECKSUMS[self.checksum][0]

    @property
    def length(self) -> int:
        return len(self.header) + self.payload_size + self.checksum_size + len(self.trailer)

    def encode(self, values: Sequence[float]) -> bytes:
        """A valid frame for these values (tests and simulators)."""
        payload = struct.pack(self.payload_format, *values)
        covered = (self.header + payload) if self.checksum_covers_header else payload
        return self.header + payload + CHECKSUMS[self.checksum][1](covered) + self.trailer


class BinaryFrameParser:
    def __init__(self, layout: FrameLayout) -> None:
        self.layout = layout
        self._struct = struct.Struct(layout.payload_format)
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[ParseResult]:
        lay = self.layout
        self._buf.extend(data)
        out: list[ParseResult] = []
        while True:
            i = self._buf.find(lay.header)
            if i < 0:
                # Keep a tail that could be the start of a header split across reads.
                keep = len(lay.header) - 1
                cut = max(0, len(self._buf) - keep)
                if cut:
                    out.append(Bad("garbage", f"{cut} bytes without a header", bytes(self._buf[:cut])))
                    del self._buf[:cut]
                return out
            if i:
                out.append(Bad("garbage", f"{i} bytes before a header", bytes(self._buf[:i])))
                del self._buf[:i]
            if len(self._buf) < lay.length:
                return out  # partial frame: wait for the rest
            frame = bytes(self._buf[:lay.length])
            problem = self._check(frame)
            if problem is None:
                del self._buf[:lay.length]
                out.append(self._decode(frame))
                continue
            out.append(Bad(problem[0], problem[1], frame))
            j = frame.find(lay.header, 1)
            del self._buf[:j if j > 0 else lay.length]

    def _check(self, frame: bytes) -> tuple[str, str] | None:
        lay = self.layout
        h, p = len(lay.header), lay.payload_size
        payload_end = h + p
        covered = frame[:payload_end] if lay.checksum_covers_header else frame[h:payload_end]
        got = frame[payload_end:payload_end + lay.checksum_size]
        want = CHECKSUMS[lay.checksum][1](covered)
        if got != want:
            return "checksum", f"{lay.checksum} mismatch: got {got.hex()}, computed {want.hex()}"
        if lay.trailer and not frame.endswith(lay.trailer):
            return "malformed", f"trailer {frame[-len(lay.trailer):].hex()} is not {lay.trailer.hex()}"
        return None

    def _decode(self, frame: bytes) -> Decoded:
        h = len(self.layout.header)
        values = self._struct.unpack_from(frame, h)
        return Decoded({k: float(v) for k, v in zip(self.layout.fields, values, strict=True) if k != "_"}, frame)
