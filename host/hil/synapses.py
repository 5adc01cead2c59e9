"""Which hardware back-end reads the synapses, by mode, and what each mode needs of the board.

* ``batch``: :class:`~snan_hil.host.hil.backend.CrossbarSynapses`, one SPIKE_BATCH per
  decision window; needs the framed firmware (SPIKE_BATCH);
* ``per_spike``: a fresh read per input spike and synapse: ``CrossbarSynapses`` with
  READ_COLUMN where the board has it, else
  :class:`~snan_hil.host.hil.cell_backend.CellReadSynapses` (cell reads, legacy mode 9);
* ``per_window``: ``CellReadSynapses``, one cell read per synapse and window; any board.

The default (:func:`default_mode`) is ``batch`` where the board has SPIKE_BATCH, else
``per_window`` — chosen for its line cost (81 B and ~7 ms per decision at 115200 baud against
per_spike's ~12 kB and ~1.1 s); measured over the legacy protocol it is not less faithful than
per_spike, but not more either (docs/hil.md, "Hardware scenarios over the legacy protocol").
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from snan_hil.calibration.layout import Layout
from snan_hil.common.errors import UserError
from snan_hil.host.hil.backend import CrossbarSynapses
from snan_hil.host.hil.cell_backend import CellReadSynapses
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import Capability

HwMode = Literal["batch", "per_spike", "per_window"]
HW_MODES: tuple[str, ...] = ("batch", "per_spike", "per_window")


def _has(client: BoardClient, capability: Capability) -> bool:
    info = getattr(client, "info", None)
    return bool(info is not None and info.has(capability))


def default_mode(client: BoardClient) -> HwMode:
    """``batch`` on a board with SPIKE_BATCH and READ_COLUMN, else ``per_window``."""
    if _has(client, Capability.SPIKE_BATCH) and _has(client, Capability.READ_COLUMN):
        return "batch"
    return "per_window"


def check_mode(client: BoardClient, mode: str | None) -> HwMode:
    """The mode to run (``None``: :func:`default_mode`); UserError if the board cannot."""
    if mode is None:
        return default_mode(client)
    if mode not in HW_MODES:
        raise UserError(f"unknown hardware mode {mode!r}; use one of "
                        + ", ".join(m.replace("_", "-") for m in HW_MODES))
    if mode == "batch" and not (_has(client, Capability.SPIKE_BATCH)
                                and _has(client, Capability.READ_COLUMN)):
        raise UserError(f"the board on {getattr(client, 'name', '?')} has no SPIKE_BATCH "
                        "(legacy protocol?): --mode batch needs --protocol framed; over the "
                        "legacy protocol use --mode per-window or --mode per-spike")
    return mode  # type: ignore[return-value]  # checked against HW_MODES above


def check_mode_for_protocol(protocol: str, mode: str | None) -> None:
    """UserError (one line) when ``mode`` cannot run over ``protocol`` on any board, so a
    command refuses it before any work: the legacy line protocol (the existing firmware,
    docs/protocol.md section 9) has no SPIKE_BATCH, so no ``batch``. ``mode`` as given on the
    command line (``per-window``) or internally (``per_window``); None = the board's default."""
    if mode is not None and mode.replace("-", "_") == "batch" and protocol == "legacy":
        raise UserError("--mode batch needs SPIKE_BATCH, which the legacy protocol does not have "
                        "(--protocol legacy); use --mode per-window or --mode per-spike, or a "
                        "board with this project's firmware (--protocol framed)")


def read_path(client: BoardClient, mode: HwMode | str) -> str:
    """``column`` (READ_COLUMN / SPIKE_BATCH) or ``cell`` (READ_CELL, legacy mode 9)."""
    if mode == "batch" or (mode == "per_spike" and _has(client, Capability.READ_COLUMN)):
        return "column"
    return "cell"


def make_synapses(client: BoardClient, layout: Layout, nbr: np.ndarray,
                  mode: HwMode | str) -> CrossbarSynapses | CellReadSynapses:
    """The back-end of ``mode`` on ``client`` (see the module table)."""
    if read_path(client, mode) == "column":
        return CrossbarSynapses(client, layout, nbr,
                                mode="batch" if mode == "batch" else "per_spike")
    return CellReadSynapses(client, layout, nbr,
                            mode="per_spike" if mode == "per_spike" else "per_window")
