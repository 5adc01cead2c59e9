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


def record_corpus() -> list[tuple[str, bytes, str | None]]:
    """Identity records a board may carry, for the firmware's record check (issue 37 point 4):
    ``(what, the RECORD_SIZE bytes, the serial INFO must name or None)``. Valid records with
    every character class and the longest serial; invalid ones: a wrong magic, length 0, a
    length over :data:`MAX_SERIAL`, and a character just outside each class (``/`` ``:`` ``@``
    ``[`` ``` ` ``` ``{`` and a space) - the firmware must report no serial for those."""
    def raw(magic: bytes, n: int, body: bytes) -> bytes:
        rec = magic + bytes((n,)) + body
        return rec + bytes((ERASED,)) * (RECORD_SIZE - len(rec))
    out: list[tuple[str, bytes, str | None]] = [
        (f"valid {s!r}", encode_record(s), s)
        for s in ("09AZaz-_.", "Z" * MAX_SERIAL, "a", "0")]
    out += [("erased", bytes((ERASED,)) * RECORD_SIZE, None),
            ("magic SNIE", raw(b"SNIE", 3, b"ABC"), None),
            ("length 0", raw(MAGIC, 0, b"ABC"), None),
            (f"length {MAX_SERIAL + 1}", raw(MAGIC, MAX_SERIAL + 1, b"A" * MAX_SERIAL), None)]
    out += [(f"character {c!r}", raw(MAGIC, 3, b"A" + c.encode() + b"B"), None)
            for c in "/:@[`{ "]
    return out
