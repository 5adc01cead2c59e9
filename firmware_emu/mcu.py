"""Which MCU runs the emulated board: the Python model or the built firmware on an ISA-level CPU.

``--mcu model`` (default): :class:`~snan_hil.firmware_emu.firmware.Firmware` behind the Python
protocol endpoint. ``--mcu firmware``: the C firmware ELF (``firmware/``) executed instruction
by instruction by :class:`~snan_hil.firmware_emu.mcu_isa.IsaMcu` against the same board
models (:class:`FirmwareBackend`). :func:`check_mcu` checks the choice; the emulator
(:class:`~snan_hil.firmware_emu.emulator.Emulator`) makes the backend.
"""

from __future__ import annotations

import random
from collections.abc import Callable

from snan_hil.common.errors import UserError

MCU_KINDS = ("model", "firmware")


def check_mcu(kind: str) -> str:
    if kind not in MCU_KINDS:
        raise UserError(f"unknown MCU {kind!r}; use one of {', '.join(MCU_KINDS)}")
    return kind


class FirmwareBackend:
    """The C firmware on :class:`IsaMcu`; pulses are noticed to mark the chip state dirty."""

    def __init__(self, board, *, baud: int, seed: int, elf=None,
                 on_state_change: Callable[[], None] | None = None,
                 nonce_rng: random.Random | None = None,
                 entropy: Callable[[], int] | None = None, chip_serial: str | None = None):
        # the ISA-level MCU (unicorn: the firmware extra; ~0.25 s of imports) only when the
        # C firmware is the back-end
        from snan_hil.firmware_emu.mcu_isa import IsaMcu
        self.board = board
        self.on_state_change = on_state_change
        self._pulses = board.front_end.pulses_applied
        self.mcu = IsaMcu(board, elf, baud=baud, seed=seed, nonce_rng=nonce_rng,
                          entropy=entropy, chip_serial=chip_serial)

    def feed(self, data: bytes) -> bytes:
        return self._noticed(self.mcu.feed(data))

    def post(self, data: bytes) -> None:
        """:meth:`IsaMcu.post`: host bytes that wait on the line for :meth:`pump`."""
        self.mcu.post(data)

    def pump(self) -> bytes:
        """:meth:`IsaMcu.pump`: run until one frame was sent; its bytes."""
        return self._noticed(self.mcu.pump())

    def _noticed(self, out: bytes) -> bytes:
        pulses = self.board.front_end.pulses_applied
        if pulses != self._pulses:
            self._pulses = pulses
            if self.on_state_change is not None:
                self.on_state_change()
        return out

    @property
    def boot_nonce(self) -> int:
        """Not readable from outside a real board; the host learns it from HELLO."""
        raise AttributeError("the firmware's boot nonce is learnt from HELLO")
