"""Helpers for tests and benchmarks of the emulator (no test framework imports).

``ideal_array()`` is a chip without noise, variability or stuck cells, so read-chain results
can be compared with closed-form expectations; ``make_firmware()`` wires a board around it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from snan_hil.firmware_emu.board import Board
from snan_hil.firmware_emu.config import BoardConfig, TimingConfig
from snan_hil.firmware_emu.firmware import Firmware


def ideal_array(seed: int = 0):
    """A crossbar with the default YSZ config minus every random effect."""
    from snan_hil.crossbar_model import ArrayConfig, CrossbarArray
    return CrossbarArray(ArrayConfig.default().ideal(), seed=seed)


def default_array(seed: int = 0):
    """The default chip (noise, variability, stuck cells), as ``snan-hil emu`` creates it."""
    from snan_hil.crossbar_model import CrossbarArray
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
