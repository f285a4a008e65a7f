"""Checksums of the Livox control frames.

SDK 1: CRC-16/MCRF4XX (reflected poly 0x1021, no final xor) seeded 0x4C49 over the 7 preamble bytes, and CRC-32
(zlib's) seeded 0x564F580A over the whole frame before it. SDK 2: CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF,
not reflected) over the first 18 header bytes, and plain CRC-32 over the payload.
"""

from __future__ import annotations

import binascii
import zlib

__all__ = ["crc16_ccitt_false", "crc16_mcrf4xx", "crc32"]


def _mcrf4xx_table() -> list[int]:
    out = []
    for b in range(256):
        c = b
        for _ in range(8):
            c = (c >> 1) ^ 0x8408 if c & 1 else c >> 1
        out.append(c)
    return out


_T16 = _mcrf4xx_table()


def crc16_mcrf4xx(data: bytes, seed: int = 0x4C49) -> int:
    c = seed
    for b in data:
        c = (c >> 8) ^ _T16[(c ^ b) & 0xFF]
    return c


def crc16_ccitt_false(data: bytes) -> int:
    return binascii.crc_hqx(data, 0xFFFF)


def crc32(data: bytes, seed: int = 0) -> int:
    """zlib CRC-32; ``seed`` is the starting value as the FastCRC ``crc32_calc(seed)`` of the Livox SDK uses it."""
    return zlib.crc32(data, seed) & 0xFFFFFFFF
