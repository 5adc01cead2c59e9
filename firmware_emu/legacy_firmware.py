"""The board's existing firmware, as the emulator's legacy protocol runs it.

:class:`LegacyFirmware` is the MCU model of :mod:`~snan_hil.firmware_emu.firmware` (the same
SPI sequences, timing and analog chain) with the existing firmware's rules instead of this
project's interlocks (facts: shared/reference/memricore-board.md and the board's public
Raspberry-Pi driver; the line-level clamps live in
:class:`~snan_hil.protocol.legacy_device.LegacyDevice`):

* no read limit of its own beyond the clamp: reads up to ``legacy_read_code`` (246 = 0.3004 V,
  the old firmware's "0.3 V") are executed; the read after a pulse is at that code;
* no write limit and no compliance check: any write-DAC code up to the DAC's full scale is
  applied (the RESET clamp at 3.0 V is done on the line), with any width (the 16-bit
  ``t_ms``/``t_us`` fields reach 65.6 s; a width of 0 is the shortest gate the MCU can make);
  what such pulses do to a cell is the device model's business (switching speed and
  breakdown, configs/device-ysz.yaml);
* the mean of the averaged conversions is truncated (C integer division, as the driver).

Anything outside the board (a cell not in the array, a code above the DAC's full scale) is an
:class:`~snan_hil.protocol.errors.OutOfRangeError`, which the legacy line handler answers with
silence (or ``-CODE,id`` with the opt-in extension).
"""

from __future__ import annotations

import random

from snan_hil.firmware_emu.board import Board
from snan_hil.firmware_emu.config import FIRMWARE_VERSION
from snan_hil.firmware_emu.firmware import Firmware
from snan_hil.protocol.errors import OutOfRangeError

__all__ = ["LegacyFirmware", "LEGACY_FIRMWARE_NAME"]

LEGACY_FIRMWARE_NAME = "memricore-emu-legacy"
"""How the emulated existing firmware names itself in its mode-100 reply."""


class LegacyFirmware(Firmware):
    """:class:`Firmware` with the existing firmware's behaviour (module docstring)."""

    def __init__(self, board: Board, nonce_rng: random.Random | None = None, *,
                 fast: bool = True):
        super().__init__(board, nonce_rng, fast=fast)
        self.round_average = False

    def _read_code(self, read_code: int) -> int:
        return self.config.legacy_read_code if read_code == 0 else read_code

    def _check_read_code(self, code: int) -> None:
        top = self.config.legacy_read_code
        if not 0 <= code <= top:
            self._refuse(OutOfRangeError(f"read DAC code {code} outside 0..{top} (the existing "
                                         "firmware clamps reads to it)", detail=max(code, 0)))

    def _check_write(self, row: int, col: int, amp_code: int, width_us: float,
                     read_code: int) -> None:
        full = self.config.write_dac_full_scale_code
        if not 0 <= amp_code <= full:
            self._refuse(OutOfRangeError(f"amplitude code {amp_code} outside 0..{full}",
                                         detail=max(amp_code, 0)))
        if not width_us >= 0:
            self._refuse(OutOfRangeError(f"pulse width {width_us} us is negative",
                                         detail=0))

    def info(self) -> dict:
        """The board description, with the firmware named as the existing one."""
        return {**super().info(), "firmware_version": f"{LEGACY_FIRMWARE_NAME} "
                + ".".join(map(str, FIRMWARE_VERSION))}
