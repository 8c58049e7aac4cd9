"""Frame checksums: name -> (size in bytes, function over the covered bytes returning those bytes)."""

from __future__ import annotations

from collections.abc import Callable


def sum8(data: bytes) -> int:
    return sum(data) & 0xFF


def xor8(data: bytes) -> int:
    x = 0
    for b in data:
        x ^= b
    return x


def crc16_modbus(data: bytes) -> int:
    """CRC-16/MODBUS: reflected polynomial 0xA001, initial 0xFFFF, no final XOR."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


CHECKSUMS: dict[str, tuple[int, Callable[[bytes], bytes]]] = {
    "none": (0, lambda data: b""),
    "sum8": (1, lambda data: bytes([sum8(data)])),
    "xor8": (1, lambda data: bytes([xor8(data)])),
    # Modbus sends the CRC low byte first.
    "crc16_modbus": (2, lambda data: crc16_modbus(data).to_bytes(2, "little")),
}
