"""The chip's identity reaches INFO through the EEPROM record (docs/firmware.md): the record's
format, and the C firmware reporting each chip's serial as the Python model does (two chips,
two layouts)."""

from __future__ import annotations

import pytest

from snan_hil.firmware_emu import chip_identity
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.protocol import messages as m


def test_identity_record_round_trips_and_rejects_bad_serials():
    image = chip_identity.eeprom_image("8B297CA46845")
    assert len(image) == chip_identity.EEPROM_SIZE
    rec = image[-chip_identity.RECORD_SIZE:]
    assert rec[:4] == b"SNID" and rec[4] == 12 and rec[5:17] == b"8B297CA46845"
    assert chip_identity.eeprom_image(None) == b"\xff" * chip_identity.EEPROM_SIZE
    for bad in ("", "a/b", "x" * (chip_identity.MAX_SERIAL + 1)):
        with pytest.raises(ValueError):
            chip_identity.encode_record(bad)


def test_firmware_reports_the_chip_serial_like_the_model(tmp_path, firmware_mcu):
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.firmware_emu.inprocess import open_inprocess_transport
    from snan_hil.protocol.link import LinkClient
    from snan_hil.board.files import BoardFiles
    from snan_hil.board.identity import BoardIdentity

    def board_layout_path(info, port):
        return BoardFiles.of_board(BoardIdentity.from_info(info), port).layout

    ids = {}
    for chip in ("a", "b"):
        for mcu in ("model", "firmware"):
            t = open_inprocess_transport(tmp_path / f"{chip}.npz", seed=0, mcu=mcu)
            client = LinkClient(t)
            try:
                client.hello()
                ids[chip, mcu] = client.info
            finally:
                client.close()
    for chip in ("a", "b"):
        model, fw = ids[chip, "model"], ids[chip, "firmware"]
        assert fw.chip_id and fw.chip_id == model.chip_id
        assert fw.board_id == f"MC-4D430001/{model.chip_id}"
    # two chips served by the firmware have two layouts (not one shared MC-4D430001.json)
    assert ids["a", "firmware"].chip_id != ids["b", "firmware"].chip_id
    assert board_layout_path(ids["a", "firmware"], "socket://x:1") != \
        board_layout_path(ids["b", "firmware"], "socket://x:1")
    # no state file: no serial in the EEPROM, no chip part (as the model)
    emu = Emulator(None, 0, mcu="firmware")
    assert emu.backend.mcu.cpu.mem_read(chip_identity.RECORD_ADDR, 4) == b"\xff" * 4


def test_firmware_names_a_serial_only_from_a_valid_record(firmware_mcu):
    """Every identity record of the corpus on the firmware's EEPROM, then a reboot: INFO names
    the serial of a valid record and no serial for an erased or invalid one."""
    from snan_hil.firmware_emu.differential import raw_frame, wire
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.protocol.conformance import frames_of
    emu = Emulator(None, 3, mcu="firmware")
    try:
        mcu = emu.backend.mcu
        corpus = chip_identity.record_corpus()
        assert sum(s is None for _, _, s in corpus) >= 8
        for what, record, serial in corpus:
            mcu.write_identity_record(record)
            mcu.press_reset()
            out = emu.feed(b"\x00" + wire(raw_frame(m.Hello.TYPE, 1, m.Hello().encode(), 0)))
            ids = [f.message().board_id for f in frames_of(out)
                   if getattr(f, "type", None) == m.Info.TYPE]
            want = chip_identity.firmware_board_id_text(BoardConfig().board_id, serial)
            assert ids == [want], what
        with pytest.raises(ValueError, match="32 bytes"):
            mcu.write_identity_record(b"SNID")
    finally:
        emu.close()
