"""CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0; check("123456789") = 0x29B1).

``binascii.crc_hqx`` is exactly this polynomial with a caller-chosen initial value, implemented in C.
"""

from __future__ import annotations

import binascii

CRC_INIT = 0xFFFF


def crc16_ccitt_false(data: bytes, value: int = CRC_INIT) -> int:
    """CRC of ``data`` continuing from ``value`` (pass the previous result to checksum in pieces)."""
    return binascii.crc_hqx(data, value)
