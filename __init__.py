"""snan-hil: spiking neuron-astrocyte navigation agent on memristor hardware.

Sub-packages: ``host`` (agent, environments, experiments, HIL runs), ``protocol`` (frames,
messages, link, transports), ``crossbar_model`` (device and array physics), ``firmware_emu``
(board emulator), ``calibration`` (weight mapping, write-and-verify), ``board`` (the board
session), ``lab`` (the opener and the notebook API), ``tools`` (the CLI).

``snan_hil.open_board("emu://?state=chip.npz&seed=3")`` opens a board for a notebook session
(:func:`snan_hil.lab.notebook.open_board`, docs/notebook.md); it is imported on first use, so
``import snan_hil`` stays cheap (loads no sub-package). ``snan_hil.__version__`` is
:data:`snan_hil.common.version.__version__`, read on first use too.
"""

import importlib
from typing import Any


__all__ = ["open_board", "__version__"]


def __dir__() -> list[str]:
    """The module's names with :func:`open_board` (imported on first use) among them."""
    return sorted({*globals(), "open_board"})


def __getattr__(name: str) -> Any:
    if name == "open_board":            # imported on first use (a module the layers put on top)
        return importlib.import_module("snan_hil.lab.notebook").open_board
    if name == "__version__":           # defined once, in the base module common/version.py
        return importlib.import_module("snan_hil.common.version").__version__
    raise AttributeError(f"module 'snan_hil' has no attribute {name!r}")
