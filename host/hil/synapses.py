"""Which hardware back-end reads the synapses, by mode, and what each mode needs of the board.

* ``on_board``: :class:`~snan_hil.host.hil.board_window.OnBoardMotorNeurons`, one
  DECISION_WINDOW per decision window: the board reads the synapses and runs the candidates'
  motor neurons itself (issue 23); needs the framed firmware's DECISION_WINDOW and
  ``neuron.reset_each_window = true``;
* ``batch``: :class:`~snan_hil.host.hil.backend.CrossbarSynapses`, one SPIKE_BATCH per
  decision window; needs the framed firmware (SPIKE_BATCH);
* ``per_spike``: a fresh read per input spike and synapse: ``CrossbarSynapses`` with
  READ_COLUMN where the board has it, else
  :class:`~snan_hil.host.hil.cell_backend.CellReadSynapses` (cell reads, legacy mode 9);
* ``per_window``: ``CellReadSynapses``, one cell read per synapse and window; any board.

The default (:func:`default_mode`) is ``on_board`` where the board has DECISION_WINDOW
(and the model starts every window at rest), else ``batch`` where it has SPIKE_BATCH, else
``per_window`` — chosen for its line cost (81 B and ~7 ms per decision at 115200 baud against
per_spike's ~12 kB and ~1.1 s); measured over the legacy protocol it is not less faithful than
per_spike, but not more either (docs/hil.md, "Hardware scenarios over the legacy protocol").
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np

from snan_hil.calibration.layout import Layout
from snan_hil.common.errors import UserError
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.backend import CrossbarSynapses
from snan_hil.host.hil.board_window import OnBoardMotorNeurons
from snan_hil.host.hil.cell_backend import CellReadSynapses
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import Capability

HwMode = Literal["on_board", "batch", "per_spike", "per_window"]
HW_MODES: tuple[str, ...] = ("on_board", "batch", "per_spike", "per_window")


def _has(client: BoardClient, capability: Capability) -> bool:
    info = getattr(client, "info", None)
    return bool(info is not None and info.has(capability))


def _on_board_ok(cfg: SnanConfig | None) -> bool:
    return cfg is None or bool(cfg.neuron.reset_each_window)


def default_mode(client: BoardClient, cfg: SnanConfig | None = None) -> HwMode:
    """``on_board`` on a board with DECISION_WINDOW (when ``cfg`` starts every window at
    rest), else ``batch`` on one with SPIKE_BATCH and READ_COLUMN, else ``per_window``."""
    if _has(client, Capability.DECISION_WINDOW) and _on_board_ok(cfg):
        return "on_board"
    if _has(client, Capability.SPIKE_BATCH) and _has(client, Capability.READ_COLUMN):
        return "batch"
    return "per_window"


def check_mode(client: BoardClient, mode: str | None,
               cfg: SnanConfig | None = None) -> HwMode:
    """The mode to run (``None``: :func:`default_mode`); UserError if the board (or the
    model ``cfg``) cannot."""
    if mode is None:
        return default_mode(client, cfg)
    if mode not in HW_MODES:
        raise UserError(f"unknown hardware mode {mode!r}; use one of "
                        + ", ".join(m.replace("_", "-") for m in HW_MODES))
    name = getattr(client, "name", "?")
    if mode == "on_board":
        if not _has(client, Capability.DECISION_WINDOW):
            raise UserError(f"the board on {name} has no DECISION_WINDOW (older firmware or "
                            "the legacy protocol): --mode on-board needs this project's current "
                            "framed firmware; use --mode batch (framed) or --mode per-window")
        if not _on_board_ok(cfg):
            raise UserError("--mode on-board needs neuron.reset_each_window=true (the board "
                            "starts every window's motor neurons at rest); use --mode batch")
    if mode == "batch" and not (_has(client, Capability.SPIKE_BATCH)
                                and _has(client, Capability.READ_COLUMN)):
        raise UserError(f"the board on {name} has no SPIKE_BATCH "
                        "(legacy protocol?): --mode batch needs --protocol framed; over the "
                        "legacy protocol use --mode per-window or --mode per-spike")
    return mode  # type: ignore[return-value]  # checked against HW_MODES above


def check_mode_for_config(mode: str | None, cfg: SnanConfig) -> None:
    """UserError (the line :func:`check_mode` gives) when ``mode`` (as given on the command
    line or internally; None = the board's default) cannot run the model ``cfg`` on any
    board: ``on-board`` needs ``neuron.reset_each_window=true``. A command checks it before
    its long work (a demo before its software half)."""
    if mode is not None and mode.replace("-", "_") == "on_board" and not _on_board_ok(cfg):
        raise UserError("--mode on-board needs neuron.reset_each_window=true (the board "
                        "starts every window's motor neurons at rest); use --mode batch")


def check_mode_for_protocol(protocol: str, mode: str | None) -> None:
    """UserError (one line) when ``mode`` cannot run over ``protocol`` on any board, so a
    command refuses it before any work: the legacy line protocol (the existing firmware,
    docs/protocol.md section 9) has no SPIKE_BATCH, so no ``batch``. ``mode`` as given on the
    command line (``per-window``) or internally (``per_window``); None = the board's default."""
    if mode is None or protocol != "legacy":
        return
    name = mode.replace("-", "_")
    if name in ("batch", "on_board"):
        need = "SPIKE_BATCH" if name == "batch" else "DECISION_WINDOW"
        raise UserError(f"--mode {mode.replace('_', '-')} needs {need}, which the legacy "
                        "protocol does not have (--protocol legacy); use --mode per-window or "
                        "--mode per-spike, or a board with this project's firmware "
                        "(--protocol framed)")


def check_mode_for_scenarios(scenarios: Sequence[str], mode: str | None) -> None:
    """UserError (one line) when ``mode`` (how the hardware scenarios read the synapses) is
    given but none of ``scenarios`` reads from the board (``sw_*`` only): it would be ignored
    silently. ``mode`` as given on the command line; None = not given."""
    if mode is None or any(s.startswith("hw_") for s in scenarios):
        return
    names = ", ".join(scenarios)
    raise UserError(f"--mode {mode.replace('_', '-')} chooses how the hardware scenarios read "
                    f"the synapses from the board; {names} runs in software (no board): leave "
                    "--mode out, or give a hardware scenario (hw_noastro, hw_astro)")


def read_path(client: BoardClient, mode: HwMode | str) -> str:
    """``column`` (READ_COLUMN / SPIKE_BATCH) or ``cell`` (READ_CELL, legacy mode 9)."""
    if mode in ("batch", "on_board") or (mode == "per_spike"
                                         and _has(client, Capability.READ_COLUMN)):
        return "column"
    return "cell"


def make_synapses(client: BoardClient, layout: Layout, nbr: np.ndarray, mode: HwMode | str,
                  cfg: SnanConfig | None = None, *, conversions: int | None = None
                  ) -> OnBoardMotorNeurons | CrossbarSynapses | CellReadSynapses:
    """The back-end of ``mode`` on ``client`` (see the module table); ``cfg`` (the launch
    config) is needed for ``on_board``, whose board runs the model's motor neurons, with
    ``conversions`` ADC conversions a read (None: the board's default read plan,
    :func:`~snan_hil.host.hil.board_window.read_plan`)."""
    if mode == "on_board":
        if cfg is None:
            raise ValueError("the on_board back-end needs the launch config")
        return OnBoardMotorNeurons(client, layout, nbr, cfg, conversions=conversions)
    if read_path(client, mode) == "column":
        return CrossbarSynapses(client, layout, nbr,
                                mode="batch" if mode == "batch" else "per_spike")
    return CellReadSynapses(client, layout, nbr,
                            mode="per_spike" if mode == "per_spike" else "per_window")
