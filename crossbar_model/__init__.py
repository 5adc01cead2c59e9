"""Memristor device and crossbar array physics.

* :mod:`.vteam` — the paper's VTEAM model (Table tab_2), exact waveform integration.
* :mod:`.vteam_stdp` — memristive STDP windows (Fig. 2B/D procedure) and a dw(w, dt) lookup.
* :mod:`.config` — the sourced device YAML (``configs/device-ysz.yaml``) and its dataclasses.
* :mod:`.device` — YSZ 1T1R cell physics (state, pulse response, device-to-device spread).
* :mod:`.noise` — programming (cycle-to-cycle) error, read noise, drift.
* :mod:`.array` — :class:`CrossbarArray`, the 32x8 chip used by the firmware emulator.
* :mod:`.characterize` — mean pulse-response table of a chip model (docs, bench, calibration).

Imports nothing else of the project except the base modules :mod:`snan_hil.common.errors`,
:mod:`snan_hil.files.atomicio` and :mod:`snan_hil.common.polarity` (write pulses take a ``Polarity``).
"""

from snan_hil.crossbar_model.array import ChipStateError, CrossbarArray
from snan_hil.crossbar_model.config import ArrayConfig, DeviceConfigError
from snan_hil.crossbar_model.device import POLARITIES
from snan_hil.crossbar_model.vteam import VTEAM, VTEAMParams
from snan_hil.crossbar_model.vteam_stdp import BiTriangularSpike, StdpLookup, default_stdp_lookup, stdp_window

__all__ = [
    "ArrayConfig",
    "BiTriangularSpike",
    "ChipStateError",
    "CrossbarArray",
    "DeviceConfigError",
    "POLARITIES",
    "StdpLookup",
    "VTEAM",
    "VTEAMParams",
    "default_stdp_lookup",
    "stdp_window",
]
