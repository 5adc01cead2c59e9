"""CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor) via crcmod.

Check value: ``crc16(b"123456789") == 0x29B1``.
"""

from __future__ import annotations

import crcmod.predefined

_crc16 = crcmod.predefined.mkCrcFun("crc-ccitt-false")

CHECK_INPUT = b"123456789"
CHECK_VALUE = 0x29B1


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (pass a previous result as ``crc`` to continue)."""
    return _crc16(bytes(data), crc)


assert crc16(CHECK_INPUT) == CHECK_VALUE, "crcmod does not give the CCITT-FALSE check value"
