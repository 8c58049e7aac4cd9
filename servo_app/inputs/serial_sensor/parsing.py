"""What a stream parser yields: decoded raw values, or a problem with the bytes that caused it."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Decoded:
    values: dict[str, float]  # raw values by field name, before scaling and limits
    raw: bytes


@dataclass(frozen=True, slots=True)
class Bad:
    kind: str  # "garbage", "checksum", "malformed", "overflow"
    message: str
    raw: bytes


ParseResult = Decoded | Bad
