"""Helpers for tests and benchmarks of the emulator (no test framework imports).

``ideal_array()`` is a chip without noise, variability or stuck cells, so read-chain results
can be compared with closed-form expectations; ``make_firmware()`` wires a board around it;
``lossy_inprocess_client()`` opens a framed client on an in-process emulator, through a lossy
line if asked.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.protocol.link import LinkClient

from snan_hil.crossbar_model import ArrayConfig, CrossbarArray
from snan_hil.firmware_emu.board import Board
from snan_hil.firmware_emu.config import BoardConfig, TimingConfig
from snan_hil.firmware_emu.firmware import Firmware
from snan_hil.firmware_emu.inprocess import emulator_of, open_inprocess_transport
from snan_hil.protocol.errors import LinkTimeoutError
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.testing import LossyTransport
from snan_hil.protocol.transport import DEFAULT_BAUD, Transport


def ideal_array(seed: int = 0):
    """A crossbar with the default YSZ config minus every random effect."""
    return CrossbarArray(ArrayConfig.default().ideal(), seed=seed)


def default_array(seed: int = 0):
    """The default chip (noise, variability, stuck cells), as ``snan-hil emu`` creates it."""
    return CrossbarArray.from_yaml(None, seed=seed)


def make_firmware(array=None, *, adc_noise_lsb: float = 0.0, seed: int = 0,
                  config: BoardConfig | None = None, fast: bool = True,
                  **timing: Any) -> Firmware:
    """A booted firmware on a new board; ``timing`` overrides :class:`TimingConfig` fields;
    ``fast=False`` reads the ADC frame by frame (the reference path)."""
    config = config or BoardConfig()
    if timing:
        config = dataclasses.replace(config, timing=dataclasses.replace(TimingConfig(), **timing))
    board = Board(ideal_array(seed) if array is None else array, config, seed=seed,
                  adc_noise_lsb=adc_noise_lsb)
    return Firmware(board, fast=fast)


def lossy_inprocess_client(state_file: str | Path, *, seed: int = 0, baud: int = DEFAULT_BAUD,
                           mcu: str = "model", drop: float = 0.0, corrupt: float = 0.0,
                           loss_seed: int = 0, hello_attempts: int = 10,
                           device: str | Path | None = None
                           ) -> tuple[LinkClient, Emulator]:
    """``(client, emulator)``: a framed :class:`~snan_hil.protocol.link.LinkClient` on an
    in-process emulator with chip file ``state_file`` (chip ``seed``, line ``baud``, ``mcu``),
    through a :class:`~snan_hil.protocol.testing.LossyTransport` dropping / corrupting those
    fractions of frames (``loss_seed``) when either is > 0, after a HELLO (up to
    ``hello_attempts`` tries on a lossy line; the last LinkTimeoutError is raised); ``device``:
    a fitted device model file whose twin the chip is."""
    inner = open_inprocess_transport(state_file=str(state_file), seed=seed, baud=baud, mcu=mcu,
                                     device=device)
    emu = emulator_of(inner)
    transport: Transport = inner
    if drop or corrupt:
        transport = LossyTransport(inner, drop=drop, corrupt=corrupt, seed=loss_seed)
    client = LinkClient(transport)
    for attempt in range(hello_attempts):
        try:
            client.hello()
            break
        except LinkTimeoutError:
            if attempt == hello_attempts - 1:
                raise
    return client, emu


def learning_client(seed: int = 0, *, learning: bool = True) -> LinkClient:
    """A LinkClient (HELLO sent) to an in-process emulator of a fresh default chip
    (``default_array(seed)``) whose Python MCU learns on the board (``BoardConfig.
    on_board_learning``; issue 34): two calls give copies of one chip."""
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.protocol.transport import CallbackTransport
    emu = Emulator(None, seed, array=default_array(seed),
                   config=BoardConfig(on_board_learning=learning))
    client = LinkClient(CallbackTransport(emu.feed, name="emu"))
    client.hello()
    return client
