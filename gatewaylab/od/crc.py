"""CRC-16 of SDO block transfers (CiA 301 7.2.4.3.16: x^16 + x^12 + x^5 + 1, initial value 0)."""

from __future__ import annotations

__all__ = ["CRC16_TABLE", "crc16_ccitt"]


def _table() -> tuple[int, ...]:
    out = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        out.append(crc & 0xFFFF)
    return tuple(out)


CRC16_TABLE: tuple[int, ...] = _table()


def crc16_ccitt(data: bytes, crc: int = 0) -> int:
    """CRC-16/XMODEM of ``data``, continuing from ``crc``; crc16_ccitt(b"123456789") == 0x31C3."""
    table = CRC16_TABLE
    for b in data:
        crc = ((crc << 8) & 0xFF00) ^ table[((crc >> 8) ^ b) & 0xFF]
    return crc
