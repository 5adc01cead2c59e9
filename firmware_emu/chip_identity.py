"""The board's identity record in the MIK32 EEPROM: where the firmware finds the chip serial.

A MemriCore board has one chip; hosts key what they know about it (its layout) by the board id
INFO reports, so the firmware must be able to name the chip. The board carries its serial in
the MCU's EEPROM (8 KB at 0x0100_0000, ``shared/reference/mik32.md``), written once when the
board is made (ASSUMPTION: this project's convention, not the vendor's; a lab writes it with the
vendor's EEPROM programmer, see ``docs/firmware.md``). The record is the last
:data:`RECORD_SIZE` bytes of the EEPROM:

=========  ======  ===========================================================================
offset     size    content
=========  ======  ===========================================================================
0          4       magic ``b"SNID"``
4          1       length ``n`` of the serial, 1..:data:`MAX_SERIAL`
5          n       the serial, ASCII letters, digits, ``-``, ``_``, ``.``
=========  ======  ===========================================================================

Erased EEPROM (0xFF) or anything else: no serial, INFO reports the board id alone.
The C firmware reads the record at boot (``hal_chip_serial``; the address and magic come into
its header from here, ``firmware/gen_constants.py``) and reports ``MC-<board id>/<serial>``
(:func:`firmware_board_id_text`); the emulator writes the chip's serial there
(:func:`eeprom_image`).
"""

from __future__ import annotations

import re

EEPROM_BASE = 0x0100_0000
EEPROM_SIZE = 8 * 1024
RECORD_SIZE = 32
RECORD_ADDR = EEPROM_BASE + EEPROM_SIZE - RECORD_SIZE
MAGIC = b"SNID"
MAX_SERIAL = RECORD_SIZE - len(MAGIC) - 1
SERIAL_RE = re.compile(r"[A-Za-z0-9._-]{1,%d}" % MAX_SERIAL)
ERASED = 0xFF


def encode_record(serial: str) -> bytes:
    """The :data:`RECORD_SIZE`-byte record naming ``serial`` (ValueError if it cannot)."""
    if not SERIAL_RE.fullmatch(serial):
        raise ValueError(f"chip serial {serial!r} is not 1..{MAX_SERIAL} characters of "
                         "letters, digits, '-', '_', '.'")
    raw = MAGIC + bytes((len(serial),)) + serial.encode("ascii")
    return raw + bytes((ERASED,)) * (RECORD_SIZE - len(raw))


def eeprom_image(serial: str | None) -> bytes:
    """The whole EEPROM (:data:`EEPROM_SIZE` bytes): erased, with the record when ``serial``."""
    image = bytearray((ERASED,)) * EEPROM_SIZE
    if serial:
        image[-RECORD_SIZE:] = encode_record(serial)
    return bytes(image)


def firmware_board_id_text(board_id: int, serial: str | None = None) -> str:
    """What the C firmware's INFO reports: ``MC-<board id, 8 hex digits>``, then
    ``/<serial>`` when its EEPROM holds one (docs/protocol.md, "Board identity")."""
    text = f"MC-{board_id:08X}"
    return f"{text}/{serial}" if serial else text
